"""Heavy top about a fixed point: Euler–Poisson equations, integrals, Lagrange and Kovalevskaya
cases, sleeping top; against SciPy solve_ivp (DOP853)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from rigidjax import quat
from rigidjax.mechanics import heavy_top as ht

# one time grid, one tolerance and always the attitude: all long runs share one compilation
TS = jnp.linspace(0.0, 100.0, 201)
TIGHT = dict(rtol=1e-12, atol=1e-12)
Q0 = np.asarray(quat.normalize(jnp.array([0.9, 0.2, -0.3, 0.1])))
W0 = np.array([0.5, -1.0, 2.0])

GENERIC = ht.HeavyTop([1.0, 1.4, 1.9], 1.0, [0.1, -0.05, 0.2])
LAGRANGE = ht.HeavyTop([1.0, 1.0, 0.6], 1.0, [0.0, 0.0, 0.1])
KOVALEVSKAYA = ht.HeavyTop([2.0, 2.0, 1.0], 1.0, [0.1, 0.0, 0.0])
NEAR_KOVALEVSKAYA = ht.HeavyTop([2.0, 2.0, 1.2], 1.0, [0.1, 0.0, 0.0])


def _run(top, w0=W0, q0=Q0):
    return ht.simulate_heavy_top(top, w0, ts=TS, q0=q0, **TIGHT)


@pytest.fixture(scope="module")
def generic():
    return _run(GENERIC)


def scipy_reference(I, m, g, rc, w0, gamma0, ts):
    """Euler–Poisson equations written independently in NumPy: torque = r_c × (−m g γ)."""
    I_inv = np.linalg.inv(I)

    def rhs(t, y):
        w, ga = y[:3], y[3:]
        K = np.cross(rc, -m * g * ga)
        return np.concatenate([I_inv @ (K - np.cross(w, I @ w)), np.cross(ga, w)])

    sol = solve_ivp(
        rhs,
        (ts[0], ts[-1]),
        np.concatenate([w0, gamma0]),
        method="DOP853",
        t_eval=np.asarray(ts),
        rtol=1e-13,
        atol=1e-13,
    )
    return sol.y[:3].T, sol.y[3:].T


def test_integrals_conserved_long_run(generic):
    d = {k: float(v) for k, v in ht.drift(GENERIC, generic).items()}
    assert set(d) == {"energy", "area", "geometric"}
    assert d["energy"] < 1e-10 and d["area"] < 1e-10 and d["geometric"] < 1e-8
    # plain relative drift of E and M·γ, and |γ| = 1
    E = ht.energy(GENERIC, generic.omega, generic.gamma)
    A = ht.area_integral(GENERIC, generic.omega, generic.gamma)
    assert float(jnp.max(jnp.abs(E / E[0] - 1))) < 1e-8
    assert float(jnp.max(jnp.abs(A / A[0] - 1))) < 1e-8
    # the motion is not trivial: the body tumbles
    assert float(jnp.ptp(generic.gamma[:, 2])) > 0.5


def test_gamma_from_quaternion_matches_poisson(generic):
    err = jnp.max(jnp.abs(generic.gamma_from_quat - generic.gamma))
    assert float(err) < 1e-9
    np.testing.assert_allclose(generic.gamma[0], ht.vertical_from_quat(Q0), atol=1e-15)
    # γ is the third row of P
    np.testing.assert_allclose(generic.matrix[:, 2, :], generic.gamma_from_quat, atol=1e-14)


def test_against_scipy_dop853(generic):
    n = 11  # t ∈ [0, 5]
    w, ga = scipy_reference(
        np.diag([1.0, 1.4, 1.9]),
        1.0,
        9.81,
        [0.1, -0.05, 0.2],
        W0,
        np.asarray(generic.gamma[0]),
        TS[:n],
    )
    np.testing.assert_allclose(generic.omega[:n], w, atol=1e-9)
    np.testing.assert_allclose(generic.gamma[:n], ga, atol=1e-9)


def test_full_tensor_against_scipy_and_rotated_frame():
    """A non-diagonal tensor (the generic body in turned body axes), no attitude: equals the
    SciPy solution and the diagonal body's trajectory turned by the same rotation."""
    R = Rotation.from_rotvec([0.4, -0.2, 0.7]).as_matrix()
    I = R @ np.diag([1.0, 1.4, 1.9]) @ R.T
    rc = R @ np.array([0.1, -0.05, 0.2])
    top = ht.HeavyTop(I, 1.0, rc)
    ts = TS[:11]
    gamma0 = np.asarray(ht.vertical_from_quat(Q0))
    traj = ht.simulate_heavy_top(top, R @ W0, R @ gamma0, ts, **TIGHT)
    assert traj.quat is None
    w, ga = scipy_reference(I, 1.0, 9.81, rc, R @ W0, R @ gamma0, ts)
    np.testing.assert_allclose(traj.omega, w, atol=1e-9)
    np.testing.assert_allclose(traj.gamma, ga, atol=1e-9)
    diag = scipy_reference(np.diag([1.0, 1.4, 1.9]), 1.0, 9.81, [0.1, -0.05, 0.2], W0, gamma0, ts)
    np.testing.assert_allclose(traj.omega, diag[0] @ R.T, atol=1e-9)


def test_lagrange_top_M3_constant(generic):
    traj = _run(LAGRANGE)
    d = ht.drift(LAGRANGE, traj)
    assert float(d["lagrange"]) < 1e-10 and float(d["energy"]) < 1e-10
    M3 = ht.lagrange_integral(LAGRANGE, traj.omega)
    np.testing.assert_allclose(M3, 0.6 * W0[2], rtol=1e-10)
    # ... and M3 is NOT constant for the asymmetric body
    M3g = ht.lagrange_integral(GENERIC, generic.omega, check=False)
    assert float(jnp.ptp(M3g)) > 0.1
    with pytest.raises(ValueError, match="not a Lagrange top"):
        ht.lagrange_integral(GENERIC, W0)


def _K_with(nu, traj):
    w, g = np.asarray(traj.omega), np.asarray(traj.gamma)
    return (w[:, 0] ** 2 - w[:, 1] ** 2 - nu * g[:, 0]) ** 2 + (
        2 * w[:, 0] * w[:, 1] - nu * g[:, 1]
    ) ** 2


def test_kovalevskaya_integral():
    traj = _run(KOVALEVSKAYA)
    K = np.asarray(ht.kovalevskaya_integral(KOVALEVSKAYA, traj.omega, traj.gamma))
    assert np.max(np.abs(K / K[0] - 1)) < 1e-9
    assert float(ht.drift(KOVALEVSKAYA, traj)["kovalevskaya"]) < 1e-10
    # the normalisation matters: ν = m g x0 / I3 (what the function uses) is conserved,
    # ν = m g x0 / I1 or the opposite sign is not
    nu = 1.0 * 9.81 * 0.1 / 1.0
    np.testing.assert_allclose(_K_with(nu, traj), K, rtol=1e-12)
    for wrong in (nu / 2, -nu):
        Kw = _K_with(wrong, traj)
        assert np.max(np.abs(Kw / Kw[0] - 1)) > 0.1
    # a general equatorial centre of mass (the same body turned about e3)
    phi = 0.7
    Rz = Rotation.from_rotvec([0, 0, phi]).as_matrix()
    top = ht.HeavyTop([2.0, 2.0, 1.0], 1.0, Rz @ [0.1, 0.0, 0.0])
    K_turned = ht.kovalevskaya_integral(top, traj.omega @ Rz.T, traj.gamma @ Rz.T)
    np.testing.assert_allclose(K_turned, K, rtol=1e-12)
    # ... and the same expression is not conserved when I3 ≠ I1/2 (so this test can fail)
    near = _run(NEAR_KOVALEVSKAYA)
    Kn = np.asarray(
        ht.kovalevskaya_integral(NEAR_KOVALEVSKAYA, near.omega, near.gamma, check=False)
    )
    assert np.max(np.abs(Kn / Kn[0] - 1)) > 0.1
    assert float(ht.drift(NEAR_KOVALEVSKAYA, near)["energy"]) < 1e-10
    with pytest.raises(ValueError, match="not a Kovalevskaya top"):
        ht.kovalevskaya_integral(NEAR_KOVALEVSKAYA, W0, [0.0, 0.0, 1.0])


def test_sleeping_top_maievskii():
    """Upright Lagrange top (I1 = 1, I3 = 0.5, m g l = 0.981), tilted by 1e-3: above the
    critical spin 2√(I1 m g l)/I3 it stays up, below it falls."""
    top = ht.HeavyTop([1.0, 1.0, 0.5], 1.0, [0.0, 0.0, 0.1])
    crit = float(ht.sleeping_top_critical_spin(top))
    assert crit == pytest.approx(2 * np.sqrt(1.0 * 9.81 * 0.1) / 0.5, rel=1e-14)
    q_tilt = np.asarray(quat.from_rotvec(jnp.array([1e-3, 0.0, 0.0])))
    for factor, stays_up in ((1.5, True), (1.1, True), (0.9, False), (0.5, False)):
        traj = _run(top, [0.0, 0.0, factor * crit], q_tilt)
        low = float(jnp.min(traj.gamma[:, 2]))
        if stays_up:  # nutation of the axis stays ~1e-3 rad (1 - cos ~ 1e-6)
            assert low > 1 - 1e-4, factor
        else:  # falls: 0.9 crit reaches ~52°, 0.5 crit past the horizontal
            assert low < (0.9 if factor > 0.5 else 0.0), factor
        d = ht.drift(top, traj)
        assert float(d["energy"]) < 1e-10 and float(d["lagrange"]) < 1e-10


def test_integrals_batch_jit_and_signs():
    # E = ½ Ω·IΩ + m g r_c·γ: a body at rest with the centre of mass straight up has E = m g l
    top = ht.HeavyTop([1.0, 1.0, 0.5], 2.0, [0.0, 0.0, 0.3], g=10.0)
    assert float(ht.energy(top, [0, 0, 0], [0, 0, 1])) == pytest.approx(6.0)
    # gravity pulls the top down: tilted about e1, Ω̇1 has the sign that increases the tilt
    tilt = [0.0, np.sin(0.1), np.cos(0.1)]  # γ = Pᵀ e_Z for P = Rx(0.1) (turned about +X)
    dw, dg = ht.euler_poisson_rhs(top, [0.0, 0.0, 0.0], tilt)
    np.testing.assert_allclose(dg, 0.0)
    assert float(dw[0]) > 0  # rotating further about +e1 increases the tilt angle
    # batched tops broadcast against (B, T, 3) trajectories; jit works
    tops = jax.vmap(lambda m: ht.HeavyTop([1.0, 1.4, 1.9], m, [0.1, -0.05, 0.2]))(
        jnp.array([1.0, 2.0])
    )
    om = jnp.ones((2, 5, 3))
    ga = jnp.broadcast_to(jnp.array([0.0, 0.6, 0.8]), (2, 5, 3))
    E = jax.jit(ht.energy)(tops, om, ga)
    assert E.shape == (2, 5)
    np.testing.assert_allclose(E[1] - E[0], 9.81 * (0.1 * 0 - 0.05 * 0.6 + 0.2 * 0.8))


def test_bad_inputs():
    with pytest.raises(ValueError, match=r"gamma0 must be a unit vector"):
        ht.simulate_heavy_top(GENERIC, W0, [0.0, 0.0, 2.0], TS)
    with pytest.raises(ValueError, match="gamma0 disagrees with q0"):
        ht.simulate_heavy_top(GENERIC, W0, [0.0, 0.0, 1.0], TS, q0=Q0)
    with pytest.raises(ValueError, match="give the initial vertical"):
        ht.simulate_heavy_top(GENERIC, W0, ts=TS)
    with pytest.raises(ValueError, match="q0 must be a unit quaternion"):
        ht.simulate_heavy_top(GENERIC, W0, ts=TS, q0=[1.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="com must have shape"):
        ht.HeavyTop([1.0, 1.0, 1.0], 1.0, [0.0, 1.0])
    with pytest.raises(ValueError, match="mass must be positive"):
        ht.HeavyTop([1.0, 1.0, 1.0], -1.0, [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="triangle inequality"):
        ht.HeavyTop([1.0, 1.0, 3.0], 1.0, [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="one top"):
        ht.simulate_heavy_top(ht.HeavyTop(jnp.ones((2, 3)), 1.0, [0, 0, 1.0]), W0, [0, 0, 1.0], TS)
    with pytest.raises(ValueError, match="strictly increasing"):
        ht.simulate_heavy_top(GENERIC, W0, [0.0, 0.0, 1.0], [0.0, 2.0, 1.0])
    xyz = jnp.zeros((TS.size, 3))
    no_attitude = ht.HeavyTopTrajectory(ts=TS, omega=xyz, gamma=xyz, quat=None, stats={})
    with pytest.raises(ValueError, match="no attitude"):
        _ = no_attitude.gamma_from_quat
