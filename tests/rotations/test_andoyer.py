"""Andoyer–Deprit variables (Borisov–Mamaev (001); THEORY §5)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads
from scipy.spatial.transform import Rotation

from rigidjax import andoyer, so3

to_andoyer = jax.jit(andoyer.to_andoyer)
from_andoyer = jax.jit(andoyer.from_andoyer)
to_momentum_attitude = jax.jit(andoyer.to_momentum_attitude)


def _sum_sin(M, P):
    return sum(jnp.sum(jnp.sin(v)) for v in andoyer.to_andoyer(M, P))


grad_state = jax.jit(jax.grad(_sum_sin, argnums=(0, 1)))
jac_attitude = jax.jit(jax.jacfwd(lambda x: andoyer.to_momentum_attitude(x)[1]))
grad_momentum = jax.jit(jax.grad(lambda x: jnp.sum(andoyer.to_momentum_attitude(x)[0])))


def wrap(a):
    """Angle difference folded into (−π, π]."""
    return np.angle(np.exp(1j * np.asarray(a)))


def random_andoyer(rng, shape, margin=1e-3):
    """Random non-degenerate variables: |L|, |H| < G (1 − margin), angles in (−π, π)."""
    G = rng.uniform(0.1, 5.0, shape)
    L = G * rng.uniform(-1 + margin, 1 - margin, shape)
    H = G * rng.uniform(-1 + margin, 1 - margin, shape)
    l, g, h = (rng.uniform(-np.pi, np.pi, shape) for _ in range(3))
    return andoyer.AndoyerVariables(L, G, H, l, g, h)


def random_state(rng, shape):
    M = rng.normal(size=(*shape, 3)) * rng.uniform(0.1, 5.0, (*shape, 1))
    P = Rotation.random(int(np.prod(shape)), random_state=rng).as_matrix().reshape(*shape, 3, 3)
    return M, P


def scipy_P(av):
    """Independent construction: SciPy intrinsic Euler angles, ZXZ (h, I, g) then XZ (J, l)."""
    I = np.arccos(np.asarray(av.H) / av.G)
    J = np.arccos(np.asarray(av.L) / av.G)
    angles1 = np.stack([av.h, I, av.g], -1).reshape(-1, 3)
    angles2 = np.stack([J, av.l], -1).reshape(-1, 2)
    R = Rotation.from_euler("ZXZ", angles1) * Rotation.from_euler("XZ", angles2)
    return R.as_matrix().reshape(*np.shape(av.G), 3, 3)


# --- construction ------------------------------------------------------------------------------


def test_construction_matches_scipy_and_is_rotation(rng):
    av = random_andoyer(rng, (4, 25))
    M, P = from_andoyer(*av)
    assert M.shape == (4, 25, 3) and P.shape == (4, 25, 3, 3)
    np.testing.assert_allclose(P, scipy_P(av), atol=1e-13)
    np.testing.assert_allclose(np.swapaxes(P, -1, -2) @ P, np.broadcast_to(np.eye(3), P.shape),
                               atol=1e-13)  # fmt: skip
    np.testing.assert_allclose(np.linalg.det(P), 1.0, atol=1e-13)
    # M_body = (√(G² − L²) sin l, √(G² − L²) cos l, L), |M| = G
    rho = np.sqrt(av.G**2 - av.L**2)
    np.testing.assert_allclose(M, np.stack([rho * np.sin(av.l), rho * np.cos(av.l), av.L], -1),
                               atol=1e-13)  # fmt: skip
    np.testing.assert_allclose(np.linalg.norm(M, axis=-1), av.G, rtol=1e-13)
    np.testing.assert_allclose(andoyer.momentum(av.L, av.G, av.l), M, atol=1e-13)


def test_space_momentum_and_gamma(rng):
    av = random_andoyer(rng, (100,))
    M, P = from_andoyer(*av)
    Ms = np.einsum("...ij,...j->...i", P, M)
    sI = np.sqrt(1 - (av.H / av.G) ** 2)
    expected = av.G[:, None] * np.stack([sI * np.sin(av.h), -sI * np.cos(av.h), av.H / av.G], -1)
    np.testing.assert_allclose(Ms, expected, atol=1e-12)
    np.testing.assert_allclose(andoyer.space_momentum(av.G, av.H, av.h), Ms, atol=1e-12)
    # γ = third row of P (space Z in body axes); M·γ = H
    gam = P[:, 2, :]
    np.testing.assert_allclose(np.sum(M * gam, -1), av.H, atol=1e-12)
    # seed's γ3 = sin ζ sin τ − cos τ cos ζ cos g, sin τ = L/G, sin ζ = H/G
    s_tau, s_zeta = av.L / av.G, av.H / av.G
    c_tau, c_zeta = np.sqrt(1 - s_tau**2), np.sqrt(1 - s_zeta**2)
    np.testing.assert_allclose(gam[:, 2], s_zeta * s_tau - c_tau * c_zeta * np.cos(av.g),
                               atol=1e-13)  # fmt: skip
    np.testing.assert_allclose(andoyer.gamma(av.L, av.G, av.H, av.l, av.g), gam, atol=1e-13)


def test_gamma_is_independent_of_h(rng):
    av = random_andoyer(rng, (20,))
    _, P0 = from_andoyer(*av)
    _, P1 = from_andoyer(*av._replace(h=av.h + 1.234))
    np.testing.assert_allclose(P0[:, 2, :], P1[:, 2, :], atol=1e-13)
    assert np.abs(P0[:, 0, :] - P1[:, 0, :]).max() > 0.1


# --- round trips ------------------------------------------------------------------------------


@settings(max_examples=50, deadline=None)
@given(
    m=st.lists(st.floats(-10, 10), min_size=3, max_size=3).filter(
        lambda v: np.linalg.norm(v) > 1e-3
    ),
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
)
def test_roundtrip_state(m, q):
    """(M, P) → Andoyer → (M, P) everywhere, degenerate sets included."""
    M = np.asarray(m)
    P = Rotation.from_quat(np.roll(q, -1)).as_matrix()
    av = to_andoyer(M, P)
    assert all(np.isfinite(v) for v in av)
    M2, P2 = from_andoyer(*av)
    # Near the body (space) z axis, (L, G) and (H, G) fix the in-plane component ρ only through
    # G² − L² with an absolute error ~eps G² (G, H are rounded): error ≈ √(ρ² + eps G²) − ρ,
    # up to √eps G at ρ ≲ √eps G, ~eps G²/ρ farther out, nothing where ρ is O(G).
    G = np.linalg.norm(M)
    pole = 0.0
    for v in (M, P @ M):
        rho = np.hypot(v[0], v[1])
        pole += 2 * (np.sqrt(rho**2 + 4 * 2.3e-16 * G**2) - rho)
    np.testing.assert_allclose(M2, M, atol=1e-12 * G + 1e-14 + pole)
    np.testing.assert_allclose(P2, P, atol=1e-11 + pole / G)
    assert av.G > 0 and abs(av.L) <= av.G and abs(av.H) <= av.G * (1 + 1e-15)


angle = st.floats(-np.pi, np.pi)
cosine = st.floats(-0.999, 0.999)


@settings(max_examples=50, deadline=None)
@given(G=st.floats(1e-2, 1e2), cJ=cosine, cI=cosine, l=angle, g=angle, h=angle)
def test_roundtrip_variables(G, cJ, cI, l, g, h):
    """Andoyer → (M, P) → Andoyer away from the singular sets (angles modulo 2π)."""
    M, P = from_andoyer(G * cJ, G, G * cI, l, g, h)
    av = to_andoyer(M, P)
    np.testing.assert_allclose([av.L, av.G, av.H], [G * cJ, G, G * cI], rtol=1e-12, atol=1e-12 * G)
    np.testing.assert_allclose(wrap(np.subtract([av.l, av.g, av.h], [l, g, h])), 0, atol=1e-9)


def test_batch_broadcast_vmap(rng):
    M, P = random_state(rng, (3, 7))
    av = to_andoyer(M, P)
    assert all(v.shape == (3, 7) for v in av)
    av_v = jax.jit(jax.vmap(jax.vmap(andoyer.to_andoyer)))(M, P)
    for a, b in zip(av, av_v, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-14)
    # one attitude for many momenta
    av_b = to_andoyer(M, P[0, 0])
    np.testing.assert_allclose(av_b.g[0, 0], av.g[0, 0], atol=1e-14)
    # stacked (..., 6) form
    x = av.as_array()
    assert x.shape == (3, 7, 6)
    M2, P2 = to_momentum_attitude(x)
    np.testing.assert_allclose(M2, M, atol=1e-12)
    np.testing.assert_allclose(P2, P, atol=1e-12)
    M3, _ = to_momentum_attitude(andoyer.AndoyerVariables.from_array(x))
    np.testing.assert_allclose(M3, M, atol=1e-12)
    # scalar broadcasting in from_andoyer
    M4, P4 = from_andoyer(0.5, 1.0, 0.2, np.linspace(-3, 3, 5), 0.3, 0.1)
    assert M4.shape == (5, 3) and P4.shape == (5, 3, 3)


def test_g_closed_form_and_seed_arcsin(rng):
    """g = atan2(G(γ1 M2 − γ2 M1), H L − G² γ3); the seed's arcsin argument is sin I sin g."""
    av = random_andoyer(rng, (100,))
    M, P = from_andoyer(*av)
    gam = P[:, 2, :]
    G = av.G
    g = np.arctan2(G * (gam[:, 0] * M[:, 1] - gam[:, 1] * M[:, 0]), av.H * av.L - G**2 * gam[:, 2])
    np.testing.assert_allclose(wrap(g - av.g), 0, atol=1e-10)
    seed = (M[:, 1] * gam[:, 0] - M[:, 0] * gam[:, 1]) / np.hypot(M[:, 0], M[:, 1])
    np.testing.assert_allclose(seed, np.sqrt(1 - (av.H / G) ** 2) * np.sin(av.g), atol=1e-12)


# --- degenerate sets ---------------------------------------------------------------------------


def degenerate_states():
    P = Rotation.random(4, random_state=7).as_matrix()
    Rz = Rotation.from_euler("z", 0.7).as_matrix()
    return [
        (np.array([0.0, 0.0, 2.0]), P[0]),  # M ∥ body z, J = 0
        (np.array([0.0, 0.0, -2.0]), P[1]),  # J = π
        (P[2].T @ np.array([0.0, 0.0, 1.5]), P[2]),  # M ∥ space Z, I = 0
        (P[3].T @ np.array([0.0, 0.0, -1.5]), P[3]),  # I = π
        (np.array([0.0, 0.0, 1.0]), Rz),  # I = J = 0: P = Rz(g)
        (np.array([0.0, 0.0, 1.0]), np.diag([1.0, -1.0, -1.0])),  # J = 0, I = π
        (np.array([0.0, 0.0, 1.0]), np.eye(3)),
        (np.array([1e-9, -2e-9, 1.0]), P[0]),  # near J = 0 (not at the rounding level)
        # I = J = 0 with P33 = 1 − 2⁻⁵² (rounded): H must come back as exactly G
        (np.array([0.0, 0.0, 1.0]), Rotation.from_quat([0.0, 0.0, 1.0, 1.0]).as_matrix()),
    ]


def test_degenerate_values_and_gradients():
    for case, (M, P) in enumerate(degenerate_states()):
        av = to_andoyer(M, P)
        assert all(np.isfinite(v) for v in av)
        M2, P2 = from_andoyer(*av)
        # case 7 lies within √eps of the pole, where (L, G) fix |(M1, M2)| only to ~√eps G
        tol = 2e-8 if case == 7 else 1e-12
        np.testing.assert_allclose(M2, M, atol=tol, err_msg=f"case {case}")
        np.testing.assert_allclose(P2, P, atol=tol, err_msg=f"case {case}")
        if case == 4:  # P = Rz(0.7): all of the rotation goes into g
            np.testing.assert_allclose([av.l, av.g, av.h], [0, 0.7, 0], atol=1e-14)
        gM, gP = grad_state(M, P)
        assert np.isfinite(gM).all() and np.isfinite(gP).all(), case
        assert np.isfinite(jac_attitude(av.as_array())).all(), case
        assert np.isfinite(grad_momentum(av.as_array())).all(), case


def test_from_andoyer_at_pole_has_finite_gradients():
    x = jnp.array(
        [[L, 1.0, H, 0.3, 0.4, 0.5] for L, H in [(1, 0.3), (-1, 0.3), (0.2, 1), (0.2, -1), (1, 1)]]
    )
    jac = jax.jit(jax.vmap(jax.jacrev(andoyer.to_momentum_attitude)))(x)
    assert all(np.isfinite(j).all() for j in jac)


def test_zero_momentum_raises():
    with pytest.raises(Exception, match="M_body"):
        andoyer.to_andoyer(np.zeros(3), np.eye(3))
    with pytest.raises(Exception, match="M_body"):
        jax.block_until_ready(eqx.filter_jit(andoyer.to_andoyer)(np.zeros((2, 3)), np.eye(3)))
    with pytest.raises(Exception, match="G"):
        andoyer.from_andoyer(0.0, 0.0, 0.0, 0.1, 0.2, 0.3)
    with pytest.raises(Exception, match="L"):
        andoyer.from_andoyer(1.5, 1.0, 0.0, 0.1, 0.2, 0.3)
    with pytest.raises(ValueError, match="M_body"):
        andoyer.to_andoyer(np.ones(4), np.eye(3))


# --- gradients, dtypes ---------------------------------------------------------------------------


def test_gradients_match_finite_differences(rng):
    M, P = random_state(rng, (2,))
    av = to_andoyer(M, P)

    @jax.jit
    def f(M, P, x):  # both directions in one function: one compilation per mode
        M2, P2 = andoyer.to_momentum_attitude(x)
        return andoyer.to_andoyer(M, P).as_array(), M2, P2

    check_grads(f, (M, P, av.as_array()), order=1, modes=["fwd", "rev"])


def test_float32(rng):
    M, P = random_state(rng, (50,))
    M32, P32 = M.astype(np.float32), P.astype(np.float32)
    av = to_andoyer(M32, P32)
    assert all(v.dtype == jnp.float32 for v in av)
    M2, P2 = from_andoyer(*av)
    assert M2.dtype == jnp.float32 and P2.dtype == jnp.float32
    np.testing.assert_allclose(M2, M, atol=5e-6 * np.abs(M).max())
    np.testing.assert_allclose(P2, P, atol=5e-6)
    # degenerate sets, batched (case 7 of degenerate_states is at the rounding level in float32)
    Md, Pd = (np.stack(a).astype(np.float32) for a in zip(*degenerate_states(), strict=True))
    av = to_andoyer(Md, Pd)
    assert all(v.dtype == jnp.float32 and np.isfinite(v).all() for v in av)
    M2, P2 = from_andoyer(*av)
    np.testing.assert_allclose(M2, Md, atol=1e-6)
    np.testing.assert_allclose(P2, Pd, atol=1e-6)
    gM, gP = grad_state(Md, Pd)
    assert gM.dtype == jnp.float32 and np.isfinite(gM).all() and np.isfinite(gP).all()


# --- dynamics -----------------------------------------------------------------------------------


def test_free_body_hamiltonian(rng):
    inertia = rng.uniform(0.5, 3.0, (100, 3))
    av = random_andoyer(rng, (100,))
    M, _ = from_andoyer(*av)
    T = andoyer.free_body_hamiltonian(inertia, av.L, av.G, av.l)
    np.testing.assert_allclose(T, 0.5 * np.sum(M * M / inertia, -1), rtol=1e-13)


def test_canonical_equations_give_euler_equations(rng):
    """(l, L), (g, G), (h, H) are canonical pairs: Hamilton's equations of the free-body T give
    Euler's equations Ṁ = M × Ω and the kinematics Ṗ = P (Ω × E), Ω = I⁻¹M."""
    inertia = jnp.asarray([1.0, 2.0, 3.5])
    av = random_andoyer(rng, (10,), margin=1e-2)

    def flow(x):
        L, G, H, l, g, h = x
        dT = jax.grad(lambda y: andoyer.free_body_hamiltonian(inertia, y[0], y[1], y[3]))(x)
        # ẋ for (L, G, H, l, g, h): L̇ = −∂T/∂l, Ġ = −∂T/∂g, Ḣ = −∂T/∂h, l̇ = ∂T/∂L, ...
        return jnp.stack([-dT[3], -dT[4], -dT[5], dT[0], dT[1], dT[2]])

    x = av.as_array()
    xdot = jax.jit(jax.vmap(flow))(x)
    (M, P), (Mdot, Pdot) = jax.jvp(to_momentum_attitude, (x,), (xdot,))
    Om = M / inertia
    np.testing.assert_allclose(Mdot, np.cross(M, Om), atol=1e-12)
    np.testing.assert_allclose(Pdot, P @ so3.hat(Om), atol=1e-12)
