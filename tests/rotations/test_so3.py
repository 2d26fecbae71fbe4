"""so3: rotation tensor ↔ rotation vector and Zhilin's Z, against SciPy and THEORY §1–2."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rigidjax import so3

ANGLES = np.array([0.0, 1e-12, 1e-8, 1e-4, 0.05, 0.5, 2.0, np.pi - 1e-6, np.pi - 1e-9, np.pi])


def _axes(n, rng):
    a = rng.normal(size=(n, 3))
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


@pytest.fixture
def rotvecs(rng):
    """Random rotation vectors plus adversarial ones (tiny angles, π and just below π)."""
    rand = _axes(200, rng) * rng.uniform(0, np.pi, size=(200, 1))
    adv = (ANGLES[:, None, None] * _axes(6, rng)[None]).reshape(-1, 3)
    axis_aligned = np.pi * np.vstack([np.eye(3), -np.eye(3)])
    return np.vstack([rand, adv, axis_aligned])


def test_hat_vee(rng):
    a, b = rng.normal(size=(2, 50, 3))
    np.testing.assert_allclose(so3.hat(a) @ b[..., None], np.cross(a, b)[..., None], atol=1e-14)
    np.testing.assert_allclose(so3.vee(so3.hat(a)), a, atol=1e-15)
    # Zhilin's vector invariant: (a × E)_× = −2a, i.e. vee = −½ (·)_×
    A = rng.normal(size=(3, 3))
    np.testing.assert_allclose(so3.vee(A), so3.vee((A - A.T) / 2), atol=1e-15)


def test_exp_matches_scipy_and_euler_theorem(rotvecs):
    P = so3.exp(rotvecs)
    np.testing.assert_allclose(P, Rotation.from_rotvec(rotvecs).as_matrix(), atol=2e-15)
    # Euler's theorem: P = (1 − cos θ) m m + cos θ E + sin θ m × E
    th = np.linalg.norm(rotvecs, axis=-1)
    keep = th > 0
    m = rotvecs[keep] / th[keep, None]
    c, s = np.cos(th[keep])[:, None, None], np.sin(th[keep])[:, None, None]
    euler = (1 - c) * m[:, :, None] * m[:, None, :] + c * np.eye(3) + s * np.asarray(so3.hat(m))
    np.testing.assert_allclose(P[keep], euler, atol=2e-15)


def test_log_matches_scipy_and_inverts_exp(rotvecs):
    P = Rotation.from_rotvec(rotvecs).as_matrix()
    th = np.asarray(so3.log(P))
    assert np.all(np.linalg.norm(th, axis=-1) <= np.pi + 1e-15)
    np.testing.assert_allclose(so3.exp(th), P, atol=2e-15)
    ref = Rotation.from_matrix(P).as_rotvec()
    # At exactly π both ±θ are valid: compare rotations there, vectors elsewhere.
    interior = np.linalg.norm(ref, axis=-1) < np.pi - 1e-7
    np.testing.assert_allclose(th[interior], ref[interior], atol=1e-14)
    np.testing.assert_allclose(so3.log(np.eye(3)), np.zeros(3), atol=0)


def test_log_near_pi_accuracy():
    """pytorch3d#188/#413: log loses all accuracy near π when it goes through acos(trace)."""
    m = np.array([1.0, 2.0, 2.0]) / 3
    for eps in [1e-3, 1e-6, 1e-9, 1e-12, 0.0]:
        th = (np.pi - eps) * m
        np.testing.assert_allclose(so3.log(Rotation.from_rotvec(th).as_matrix()), th, atol=1e-14)


def test_rotate_and_rotate_tensor(rotvecs, rng):
    a = rng.normal(size=(len(rotvecs), 3))
    P = Rotation.from_rotvec(rotvecs).as_matrix()
    np.testing.assert_allclose(so3.rotate(rotvecs, a), np.einsum("nij,nj->ni", P, a), atol=1e-14)
    T = rng.normal(size=(3, 3))
    Tp = so3.rotate_tensor(P, T)
    np.testing.assert_allclose(Tp, P @ T @ np.swapaxes(P, -1, -2), atol=1e-14)
    # invariants of a tensor are unchanged by the rotation
    np.testing.assert_allclose(np.trace(Tp, axis1=-2, axis2=-1), np.trace(T), atol=1e-13)


def _Z_reference(theta):
    """Z as the inverse of Z⁻¹ written with NumPy from Zhilin (3.14.13)."""
    t = np.linalg.norm(theta)
    R = np.asarray(so3.hat(theta))
    Zi = np.eye(3) + (1 - np.cos(t)) / t**2 * R + (t - np.sin(t)) / t**3 * R @ R
    return np.linalg.inv(Zi), Zi


def test_Z_identities(rng):
    thetas = _axes(20, rng) * rng.uniform(0.01, 2 * np.pi - 0.05, size=(20, 1))
    Z, Zi, P = so3.Z(thetas), so3.Z_inv(thetas), so3.exp(thetas)
    for k, th in enumerate(thetas):
        Zr, Zir = _Z_reference(th)
        np.testing.assert_allclose(Zi[k], Zir, atol=1e-13)
        np.testing.assert_allclose(Z[k], Zr, rtol=1e-10, atol=1e-10)
        t = np.linalg.norm(th)
        np.testing.assert_allclose(np.linalg.det(Z[k]), t**2 / (2 * (1 - np.cos(t))), rtol=1e-10)
    np.testing.assert_allclose(Z @ P, P @ Z, atol=1e-12)  # Z P = P Z
    np.testing.assert_allclose(np.swapaxes(Z, -1, -2), P @ Z, atol=1e-12)  # Zᵀ = P Z
    # Z(Sθ) = S Z(θ) Sᵀ for rotations S; θ is axial, so an improper S also flips it: (det S) S θ
    S = Rotation.random(20, random_state=1).as_matrix()
    S[10:] *= np.array([1, 1, -1])[:, None]
    Sth = np.linalg.det(S)[:, None] * np.einsum("nij,nj->ni", S, thetas)
    np.testing.assert_allclose(so3.Z(Sth), S @ Z @ np.swapaxes(S, -1, -2), atol=1e-11)
    # θ is an eigenvector: Z θ = θ
    np.testing.assert_allclose(np.einsum("nij,nj->ni", Z, thetas), thetas, atol=1e-12)


def test_Z_is_derivative_of_exp(rng):
    """ω = Z⁻¹ θ̇ with ω = vee(Ṗ Pᵀ), Ṗ from forward-mode differentiation of exp (Zhilin 3.14.12)."""
    th = rng.normal(size=3)
    thdot = rng.normal(size=3)
    P, Pdot = jax.jvp(so3.exp, (th,), (thdot,))
    omega = so3.angular_velocity(P, Pdot, frame="space")
    np.testing.assert_allclose(omega, so3.Z_inv(th) @ thdot, atol=1e-13)
    np.testing.assert_allclose(so3.Z(th) @ omega, thdot, atol=1e-13)
    Omega = so3.angular_velocity(P, Pdot, frame="body")
    np.testing.assert_allclose(Omega, P.T @ omega, atol=1e-13)
    # right problem: θ̇ = Zᵀ Ω (3.14.22); and θ·θ̇ = θ·ω (3.14.7)
    np.testing.assert_allclose(so3.Z(th).T @ Omega, thdot, atol=1e-13)
    np.testing.assert_allclose(th @ thdot, th @ omega, atol=1e-13)
    # Zhilin (3.14.4): ω = θ̇ m + sin θ ṁ + (1 − cos θ) m × ṁ
    t = np.linalg.norm(th)
    m = th / t
    tdot = m @ thdot
    mdot = (thdot - tdot * m) / t
    np.testing.assert_allclose(
        omega, tdot * m + np.sin(t) * mdot + (1 - np.cos(t)) * np.cross(m, mdot), atol=1e-13
    )


def test_angular_velocity_frame_error():
    with pytest.raises(ValueError, match="frame"):
        so3.angular_velocity(np.eye(3), np.zeros((3, 3)), frame="left")


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-10, 10, allow_nan=False), min_size=3, max_size=3),
    st.lists(st.floats(-10, 10, allow_nan=False), min_size=3, max_size=3),
)
def test_compose_and_shadow(phi, psi):
    phi, psi = np.asarray(phi), np.asarray(psi)
    c = np.asarray(so3.compose(phi, psi))
    assert np.linalg.norm(c) <= np.pi + 1e-12
    ref = Rotation.from_rotvec(phi) * Rotation.from_rotvec(psi)
    np.testing.assert_allclose(so3.exp(c), ref.as_matrix(), atol=1e-12)
    s = np.asarray(so3.shadow(phi))
    assert np.linalg.norm(s) <= np.pi + 1e-12
    np.testing.assert_allclose(so3.exp(s), so3.exp(phi), atol=1e-12)


def test_shadow_keeps_small_vectors_and_flips_large():
    th = np.array([[0.0, 0, 0], [3.0, 0, 0], [4.0, 0, 0], [0, 0, 2 * np.pi + 0.1], [0, 0, -13.0]])
    s = np.asarray(so3.shadow(th))
    np.testing.assert_allclose(s[:2], th[:2])
    np.testing.assert_allclose(s[2], [4.0 - 2 * np.pi, 0, 0], atol=1e-15)
    np.testing.assert_allclose(s[3], [0, 0, 0.1], atol=1e-14)
    np.testing.assert_allclose(s[4], [0, 0, -13.0 + 4 * np.pi], atol=1e-14)


def test_quasi_commutativity(rng):
    """Q(φm) Q(θn) = Q(θn') Q(φm), n' = Q(φm) n (article 003)."""
    phi, theta = rng.normal(size=(2, 10, 3))
    Qphi = so3.exp(phi)
    n_prime = np.einsum("nij,nj->ni", Qphi, theta)
    np.testing.assert_allclose(Qphi @ so3.exp(theta), so3.exp(n_prime) @ Qphi, atol=1e-13)


def test_project_distance_check_random():
    key = jax.random.PRNGKey(0)
    P = so3.random(key, (1000,))
    np.testing.assert_allclose(so3.orthogonality_error(P), 0, atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(P), 1, atol=1e-14)
    # uniform on SO(3): the mean of P over Haar measure is 0; cos of the angle has mean −1/3... use
    # E[tr P] = 0 and E[θ] = π/2 + 2/π (density (1 − cos θ)/π on [0, π]).
    ang = np.asarray(so3.distance(np.eye(3), P))
    assert abs(ang.mean() - (np.pi / 2 + 2 / np.pi)) < 0.05
    assert abs(np.trace(P, axis1=-2, axis2=-1).mean()) < 0.1
    noisy = P + 1e-3 * jax.random.normal(jax.random.PRNGKey(1), P.shape)
    Pp = so3.project(noisy)
    np.testing.assert_allclose(so3.orthogonality_error(Pp), 0, atol=1e-13)
    assert float(so3.distance(Pp, P).max()) < 5e-3
    # a reflection projects to a rotation
    assert np.isclose(np.linalg.det(so3.project(np.diag([1.0, 1.0, -1.0]))), 1.0)
    d = so3.distance(so3.exp(np.array([0.3, 0, 0])), so3.exp(np.array([0, 0.4, 0])))
    ref = (Rotation.from_rotvec([0.3, 0, 0]).inv() * Rotation.from_rotvec([0, 0.4, 0])).magnitude()
    np.testing.assert_allclose(d, ref, atol=1e-15)


def test_check_rotation_raises():
    so3.check_rotation(np.eye(3))
    with pytest.raises(Exception, match="not a rotation matrix"):
        so3.check_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(Exception, match="not a rotation matrix"):
        jax.jit(so3.check_rotation)(1.01 * np.eye(3))


def test_shape_errors():
    with pytest.raises(ValueError, match=r"theta must have shape \(\.\.\., 3\)"):
        so3.exp(np.zeros(4))
    with pytest.raises(ValueError, match="P must have shape"):
        so3.log(np.zeros((3, 4)))


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-5, np.pi / 2, np.pi - 1e-7, np.pi])
def test_gradients_finite_and_match_finite_differences(angle):
    """jaxlie#9 / kornia#4404: NaN gradients of exp/log at the identity; here also at π."""
    m = np.array([2.0, -1.0, 2.0]) / 3
    th = angle * m
    fns = {
        "exp": lambda t: jnp.sum(so3.exp(t) * jnp.arange(9.0).reshape(3, 3)),
        "Z": lambda t: jnp.sum(so3.Z(t) * jnp.arange(9.0).reshape(3, 3)),
        "Z_inv": lambda t: jnp.sum(so3.Z_inv(t) * jnp.arange(9.0).reshape(3, 3)),
        "rotate": lambda t: jnp.sum(so3.rotate(t, jnp.array([0.3, -0.2, 0.9]))),
    }
    h = 1e-6
    for name, f in fns.items():
        g = np.asarray(jax.grad(f)(jnp.asarray(th)))
        assert np.all(np.isfinite(g)), name
        fd = np.array([(f(th + h * e) - f(th - h * e)) / (2 * h) for e in np.eye(3)])
        np.testing.assert_allclose(g, fd, atol=1e-7, err_msg=name)
    # log: gradient of log∘exp is the identity map for |θ| < π
    J = np.asarray(jax.jacfwd(lambda t: so3.log(so3.exp(t)))(jnp.asarray(th)))
    assert np.all(np.isfinite(J))
    if angle < np.pi - 1e-6:
        np.testing.assert_allclose(J, np.eye(3), atol=1e-8)
    Jr = np.asarray(jax.jacrev(so3.log)(so3.exp(jnp.asarray(th))))
    assert np.all(np.isfinite(Jr))


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_float32_and_batch_dims(rng):
    th = rng.normal(size=(2, 5, 3)).astype(np.float32)
    P = so3.exp(th)
    assert P.dtype == jnp.float32 and P.shape == (2, 5, 3, 3)
    np.testing.assert_allclose(
        P, Rotation.from_rotvec(th.reshape(-1, 3)).as_matrix().reshape(P.shape), atol=2e-6
    )
    back = so3.log(P)
    assert back.dtype == jnp.float32
    np.testing.assert_allclose(so3.exp(back), P, atol=3e-6)
    g = jax.grad(lambda t: so3.log(so3.exp(t)).sum())(jnp.zeros(3, jnp.float32))
    np.testing.assert_allclose(g, np.ones(3), atol=1e-6)
    assert so3.Z(th).dtype == jnp.float32


def test_vmap_jit():
    th = jnp.linspace(-3, 3, 12).reshape(4, 3)
    np.testing.assert_allclose(jax.jit(jax.vmap(so3.exp))(th), so3.exp(th), atol=1e-15)
    np.testing.assert_allclose(jax.vmap(so3.Z)(th), so3.Z(th), atol=1e-15)
