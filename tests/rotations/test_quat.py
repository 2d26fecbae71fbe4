"""rigidjax.quat against SciPy `Rotation`/`Slerp` and the closed forms of THEORY §3."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from rigidjax import quat
from tests.helpers import scalar_first as sp
from tests.helpers import zxz_quaternion

SQ3 = np.sqrt(1 / 3)
AXES = np.array(
    [[1, 0, 0], [0, 1, 0], [0, 0, 1], [SQ3, SQ3, SQ3], [0.6, 0, -0.8], [2, -3, 6]], float
)
AXES /= np.linalg.norm(AXES, axis=-1, keepdims=True)


def assert_same_rotation(q1, q2, atol=1e-12):
    """q1 = ±q2 (as unit quaternions), element-wise over the batch."""
    q1 = np.asarray(q1) / np.linalg.norm(q1, axis=-1, keepdims=True)
    q2 = np.asarray(q2) / np.linalg.norm(q2, axis=-1, keepdims=True)
    err = np.minimum(np.abs(q1 - q2).max(-1), np.abs(q1 + q2).max(-1))
    assert err.max() <= atol, err.max()


def adversarial_rotvecs():
    """Identity, 1e-12 turns, exactly π, π − 1e-9, π/2 about several axes (incl. arbitrary)."""
    mags = np.array([0.0, 1e-12, 1e-6, np.pi / 2, np.pi - 1e-9, np.pi])
    return (mags[:, None, None] * AXES[None]).reshape(-1, 3)


def test_xyzw_matches_scipy(rng):
    r = Rotation.random(32, random_state=1)
    q = quat.from_xyzw(r.as_quat())
    np.testing.assert_array_equal(q, sp(r))
    np.testing.assert_array_equal(quat.to_xyzw(q), r.as_quat())


def test_to_matrix_and_mul_match_scipy(rng):
    ra, rb = Rotation.random(32, random_state=2), Rotation.random(32, random_state=3)
    a, b = sp(ra), sp(rb)
    np.testing.assert_allclose(quat.to_matrix(a), ra.as_matrix(), atol=1e-15)
    # non-unit quaternions are treated as q/|q|
    np.testing.assert_allclose(quat.to_matrix(3.5 * a), ra.as_matrix(), atol=1e-14)
    ab = quat.mul(a, b)
    np.testing.assert_allclose(quat.to_matrix(ab), (ra * rb).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(quat.to_matrix(ab), ra.as_matrix() @ rb.as_matrix(), atol=1e-14)
    # article 003 (68)-(69) written out
    a0, av, b0, bv = a[:, 0], a[:, 1:], b[:, 0], b[:, 1:]
    ref = np.concatenate(
        [
            (a0 * b0 - (av * bv).sum(-1))[:, None],
            a0[:, None] * bv + b0[:, None] * av + np.cross(av, bv),
        ],
        axis=-1,
    )
    np.testing.assert_allclose(ab, ref, atol=1e-15)


def test_conj_inv_identity(rng):
    q = rng.normal(size=(32, 4))
    e = quat.identity((32,))
    np.testing.assert_allclose(quat.mul(q, quat.inv(q)), e, atol=1e-14)
    np.testing.assert_allclose(quat.mul(quat.inv(q), q), e, atol=1e-14)
    u = q / np.linalg.norm(q, axis=-1, keepdims=True)
    np.testing.assert_allclose(quat.conj(u), quat.inv(u), atol=1e-15)
    np.testing.assert_allclose(
        quat.to_matrix(quat.conj(u)), np.swapaxes(quat.to_matrix(u), -1, -2), atol=1e-14
    )


def test_rotate_matches_scipy_and_broadcasts(rng):
    r = Rotation.random(32, random_state=4)
    v = rng.normal(size=(32, 3))
    np.testing.assert_allclose(quat.rotate(sp(r), v), r.apply(v), atol=1e-14)
    np.testing.assert_allclose(quat.rotate(-2 * sp(r), v), r.apply(v), atol=1e-14)
    # one rotation, many vectors; many rotations, one vector
    np.testing.assert_allclose(quat.rotate(sp(r[0]), v), r[0].apply(v), atol=1e-14)
    np.testing.assert_allclose(quat.rotate(sp(r), v[0]), r.apply(v[0]), atol=1e-14)


def test_rotvec_and_matrix_adversarial():
    theta = adversarial_rotvecs()
    r = Rotation.from_rotvec(theta)
    q = quat.from_rotvec(theta)
    assert_same_rotation(q, sp(r), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-15)
    np.testing.assert_allclose(quat.to_matrix(q), r.as_matrix(), atol=1e-15)

    # rotation vector back: exact, incl. relative accuracy at 1e-12 (no cancellation)
    back = np.asarray(quat.to_rotvec(q))
    n = np.linalg.norm(theta, axis=-1)
    below_pi = n < np.pi
    np.testing.assert_allclose(back[below_pi], theta[below_pi], rtol=1e-15, atol=1e-300)
    # at exactly π the vector is defined up to sign
    at_pi = ~below_pi
    err = np.minimum(
        np.abs(back[at_pi] - theta[at_pi]).max(-1), np.abs(back[at_pi] + theta[at_pi]).max(-1)
    )
    assert err.max() < 1e-14

    # matrix -> quaternion (largest component): robust at and near π
    qm = quat.from_matrix(r.as_matrix())
    assert_same_rotation(qm, sp(r), atol=1e-15)
    assert np.all(np.asarray(qm)[:, 0] >= 0)
    ang = np.asarray(quat.angle(qm))
    np.testing.assert_allclose(ang, n, rtol=1e-15, atol=2e-15)
    # the angle π − 1e-9 survives the matrix round trip
    near = np.isclose(n, np.pi - 1e-9, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ang[near], np.pi - 1e-9, rtol=0, atol=1e-14)


def test_from_matrix_180_about_random_axes(rng):
    axes = rng.normal(size=(64, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    P = 2 * axes[:, :, None] * axes[:, None, :] - np.eye(3)  # 180°: P = 2mm − E
    q = quat.from_matrix(P)
    assert_same_rotation(q, np.concatenate([np.zeros((64, 1)), axes], -1), atol=1e-15)
    np.testing.assert_allclose(quat.to_matrix(q), P, atol=1e-15)


SPECIAL_Q = np.array(
    [
        [1.0, 0, 0, 0],  # identity
        [0.0, 1, 0, 0],  # 180° about x
        [0.0, 0, 0, 1],  # 180° about z
        [0.0, 0.6, 0, -0.8],  # 180° about an arbitrary axis
        [np.cos(0.5), *np.sin(0.5) * AXES[5]],
    ]
)


@pytest.mark.parametrize(
    "f",
    [
        quat.to_rotvec,
        quat.to_matrix,
        quat.angle,
        lambda q: quat.from_matrix(quat.to_matrix(q)),
        lambda q: quat.rotate(q, jnp.array([0.3, -1.0, 2.0])),
        lambda q: quat.mul(q, q),
        lambda q: quat.slerp(q, q, 0.4),
        quat.to_cayley_klein,
        quat.normalize,
    ],
    ids=["to_rotvec", "to_matrix", "angle", "from_matrix", "rotate", "mul", "slerp", "ck", "norm"],
)
def test_gradients_finite_at_identity_and_180(f):
    jac = jax.jit(jax.vmap(jax.jacrev(lambda q: jnp.real(f(q)))))(jnp.asarray(SPECIAL_Q))
    assert np.all(np.isfinite(jac))


def test_gradient_values_at_identity():
    @jax.jit
    def run(e, z):
        return (
            jax.jacfwd(quat.to_rotvec)(e),
            jax.jacrev(quat.to_rotvec)(e),
            jax.jacfwd(quat.from_rotvec)(z),
            jax.jacrev(quat.from_rotvec)(z),
            jax.grad(quat.angle)(e),
        )

    Jf, Jr, Kf, Kr, ga = run(jnp.array([1.0, 0, 0, 0]), jnp.zeros(3))
    # θ = 2 λ + O(|λ|³): dθ/dq = [0 | 2E]
    np.testing.assert_allclose(Jf, np.c_[np.zeros(3), 2 * np.eye(3)], atol=1e-15)
    np.testing.assert_allclose(Jr, Jf, atol=1e-15)
    # q(θ) = (1, θ/2) + O(θ²)
    np.testing.assert_allclose(Kf, np.r_[np.zeros((1, 3)), 0.5 * np.eye(3)], atol=1e-15)
    np.testing.assert_allclose(Kr, Kf, atol=1e-15)
    np.testing.assert_array_equal(ga, 0)


def test_normalize_zero_raises():
    with pytest.raises(Exception, match="zero"):
        quat.normalize(jnp.zeros(4))
    with pytest.raises(Exception, match="zero"):
        jax.jit(quat.to_matrix)(jnp.zeros((2, 4)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        quat.mul(jnp.ones(3), jnp.ones(4))


# ---------------------------------------------------------------- slerp


def test_slerp_matches_scipy():
    r = Rotation.random(12, random_state=5)
    a, b = sp(r[:6]), sp(r[6:])
    b[::2] *= -1  # a·b < 0 for some pairs: the shortest path must still be taken
    b[1] = sp(r[0] * Rotation.from_rotvec([1e-9, 0, 0]))  # nearly equal
    b[3] = -a[3]  # same rotation, opposite sign
    ts = np.linspace(0, 1, 9)
    out = jax.jit(quat.slerp)(a, b, ts[:, None])  # (9, 6, 4)
    assert out.shape == (9, 6, 4)
    mats = jax.jit(quat.to_matrix)(out)
    out = np.asarray(out)
    for k in range(6):
        key = Rotation.from_quat(np.stack([a[k], b[k]])[:, [1, 2, 3, 0]])
        ref = Slerp([0, 1], key)(ts)
        np.testing.assert_allclose(mats[:, k], ref.as_matrix(), atol=1e-14)
    # exact at t = 0, ±b at t = 1
    # exact (up to the rounding of the normalisation) at the ends
    unit = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(out[0], unit(a), rtol=5e-16, atol=0)
    flipped = np.where((a * b).sum(-1, keepdims=True) < 0, -b, b)
    np.testing.assert_allclose(out[-1], unit(flipped), rtol=5e-16, atol=0)
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1, atol=1e-15)
    # constant angular speed along the arc
    ang = np.asarray(quat.angle(quat.mul(quat.conj(a[0]), out[:, 0])))
    np.testing.assert_allclose(ang, ts * ang[-1], atol=1e-14)


def test_slerp_gradients_at_equal_and_opposite():
    a = jnp.asarray(SPECIAL_Q[4])
    b = jnp.asarray(sp(Rotation.from_rotvec([0.2, -0.1, 0.4])))
    bs = jnp.stack([a, -a, 1.5 * a, quat.mul(a, b)])

    @jax.jit
    def run(a, bs):
        g = jax.vmap(
            jax.grad(lambda a, b, t: quat.slerp(a, b, t) @ jnp.arange(4.0), (0, 1, 2)),
            (None, 0, None),
        )(a, bs, 0.3)
        dq = jax.vmap(jax.jacfwd(lambda b, t: quat.slerp(a, b, t), 1), (0, None))(bs, 0.0)
        return g, dq

    (ga, gb, gt), dq = run(a, bs)
    assert np.all(np.isfinite(ga)) and np.all(np.isfinite(gb)) and np.all(np.isfinite(gt))
    # no motion when b = ±a; otherwise dq/dt(0) = a ∘ (0, θ/2) with θ the relative rotation vector
    np.testing.assert_allclose(dq[:3], 0, atol=1e-15)
    theta = Rotation.from_rotvec([0.2, -0.1, 0.4]).as_rotvec()
    np.testing.assert_allclose(dq[3], 0.5 * quat.mul(a, np.r_[0.0, theta]), atol=1e-14)
    np.testing.assert_allclose(gt[:3], 0, atol=1e-15)


# ---------------------------------------------------------------- mean


def test_mean_matches_scipy(rng):
    B, N = 4, 10
    centers = Rotation.random(B, random_state=6)
    noise = Rotation.from_rotvec(0.4 * rng.normal(size=(B, N, 3)).reshape(-1, 3))
    sets = np.stack([sp(centers[i] * noise[i * N : (i + 1) * N]) for i in range(B)])
    sets *= rng.choice([-1.0, 1.0], size=(B, N, 1))  # sign-invariant
    w = rng.uniform(0.1, 2.0, size=(B, N))
    m, mw = quat.mean(sets), quat.mean(sets, w)
    assert m.shape == (B, 4)
    for i in range(B):
        rs = Rotation.from_quat(sets[i][:, [1, 2, 3, 0]])
        assert_same_rotation(m[i], sp(rs.mean()), atol=1e-13)
        assert_same_rotation(mw[i], sp(rs.mean(weights=w[i])), atol=1e-13)
    assert np.all(np.asarray(m)[:, 0] >= 0)


def test_mean_gradient_when_all_equal():
    a = jnp.asarray(SPECIAL_Q[4])
    J = jax.jit(jax.jacrev(lambda a: quat.mean(jnp.stack([a, -a, 2 * a]))))(a)
    # mean = a/|a| with λ0 > 0: Jacobian is the tangent projector E − a aᵀ
    np.testing.assert_allclose(J, np.eye(4) - np.outer(a, a), atol=1e-12)
    with pytest.raises(ValueError):
        quat.mean(a)


# ---------------------------------------------------------------- Cayley–Klein and SU(2)


def euler_ck(psi, theta, phi):
    """Borisov–Mamaev (001): Cayley–Klein parameters from the classical Euler angles."""
    c, s = np.cos(theta / 2), np.sin(theta / 2)
    return np.stack(
        [
            np.stack([c * np.exp(0.5j * (psi + phi)), 1j * s * np.exp(0.5j * (psi - phi))], -1),
            np.stack([1j * s * np.exp(-0.5j * (psi - phi)), c * np.exp(-0.5j * (psi + phi))], -1),
        ],
        -2,
    )


def test_cayley_klein_from_euler_angles(rng):
    ang = rng.uniform([-np.pi, 0, -np.pi], [np.pi, np.pi, np.pi], size=(32, 3))
    r = Rotation.from_euler("ZXZ", ang)  # P = Rz(ψ) Rx(θ) Rz(φ)
    U = np.asarray(quat.to_cayley_klein(sp(r)))
    assert U.dtype == np.complex128
    ref = euler_ck(*ang.T)
    err = np.minimum(np.abs(U - ref).max((-1, -2)), np.abs(U + ref).max((-1, -2)))
    assert err.max() < 1e-14
    det = U[..., 0, 0] * U[..., 1, 1] - U[..., 0, 1] * U[..., 1, 0]
    np.testing.assert_allclose(det, 1, atol=1e-14)
    # back to the rotation
    np.testing.assert_allclose(
        quat.to_matrix(quat.from_cayley_klein(ref)), r.as_matrix(), atol=1e-14
    )
    # the Euler-angle quaternion of THEORY §3 maps to exactly these entries (sign included)
    psi, th, phi = ang.T
    lam = zxz_quaternion(psi, th, phi)
    np.testing.assert_allclose(quat.to_cayley_klein(lam), ref, atol=1e-15)
    np.testing.assert_allclose(quat.from_cayley_klein(ref), lam, atol=1e-15)


def test_from_cayley_klein_is_robust(rng):
    q = sp(Rotation.random(16, random_state=7))
    U = np.asarray(quat.to_cayley_klein(q))
    # a scaled matrix, and noise on the redundant entries, still give (nearly) q
    np.testing.assert_allclose(quat.from_cayley_klein(2.0 * U), q, atol=1e-15)
    noise = 1e-7 * (rng.normal(size=U.shape) + 1j * rng.normal(size=U.shape))
    np.testing.assert_allclose(quat.from_cayley_klein(U + noise), q, atol=1e-6)
    # a real-valued input is accepted (the real span of the CK basis)
    np.testing.assert_allclose(quat.from_cayley_klein(np.eye(2)), [1.0, 0, 0, 0], atol=0)


def test_su2_action_and_conventions(rng):
    r = Rotation.random(16, random_state=8)
    q = sp(r)
    v = rng.normal(size=(16, 3))
    s = np.asarray(quat.pauli())
    np.testing.assert_array_equal(s, [[[0, 1], [1, 0]], [[0, -1j], [1j, 0]], [[1, 0], [0, -1]]])
    # U_std = λ0 σ0 − i λ·σ, built here from the Pauli matrices
    U_ref = q[:, :1, None] * np.eye(2) - 1j * np.einsum("nk,kij->nij", q[:, 1:], s)
    U = np.asarray(quat.to_su2(q))
    np.testing.assert_allclose(U, U_ref, atol=1e-15)
    np.testing.assert_allclose(U, np.conj(quat.to_cayley_klein(q)), atol=0)
    np.testing.assert_allclose(
        U @ np.conj(np.swapaxes(U, -1, -2)), np.broadcast_to(np.eye(2), U.shape), atol=1e-15
    )
    # U (r·σ) Uᴴ = (P r)·σ
    rs = np.einsum("nk,kij->nij", v, s)
    np.testing.assert_allclose(quat.vec_to_sigma(v), rs, atol=0)
    lhs = U @ rs @ np.conj(np.swapaxes(U, -1, -2))
    np.testing.assert_allclose(lhs, np.einsum("nk,kij->nij", r.apply(v), s), atol=1e-14)
    np.testing.assert_allclose(quat.su2_act(U, v), r.apply(v), atol=1e-14)
    np.testing.assert_allclose(quat.sigma_to_vec(rs), v, atol=0)
    np.testing.assert_allclose(quat.from_su2(U), q, atol=1e-15)
    # exercise 002: U = cos φ σ0 + i sin φ (h·σ) turns by −2φ about h (passive rotation)
    phi = rng.uniform(0, np.pi, size=16)
    h = rng.normal(size=(16, 3))
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    U002 = np.cos(phi)[:, None, None] * np.eye(2) + 1j * np.sin(phi)[:, None, None] * np.einsum(
        "nk,kij->nij", h, s
    )
    inv_rot = Rotation.from_rotvec(-2 * phi[:, None] * h)
    np.testing.assert_allclose(quat.su2_act(U002, v), inv_rot.apply(v), atol=1e-14)
    assert_same_rotation(quat.from_su2(U002), sp(inv_rot), atol=1e-14)


# ---------------------------------------------------------------- round trips, float32

unit_q = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda x: sum(t * t for t in x) > 1e-2
)


@jax.jit
def _round_trips(q):
    P = quat.to_matrix(q)
    return {
        "P": P,
        "matrix": quat.from_matrix(P),
        "ck": quat.from_cayley_klein(quat.to_cayley_klein(q)),
        "su2": quat.from_su2(quat.to_su2(q)),
        "xyzw": quat.from_xyzw(quat.to_xyzw(q)),
        "rotvec": quat.from_rotvec(quat.to_rotvec(q)),
        "inv": quat.to_matrix(quat.inv(q)),
    }


@settings(max_examples=50, deadline=None)
@given(unit_q)
def test_round_trips(x):
    q = np.asarray(x) / np.linalg.norm(x)
    out = _round_trips(q)
    P_ref = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(out["P"], P_ref, atol=1e-14)
    assert_same_rotation(out["matrix"], q, atol=1e-14)
    assert_same_rotation(out["rotvec"], q, atol=1e-14)
    np.testing.assert_allclose(out["ck"], q, atol=1e-15)
    np.testing.assert_allclose(out["su2"], q, atol=1e-15)
    np.testing.assert_array_equal(out["xyzw"], q)
    np.testing.assert_allclose(out["inv"], P_ref.T, atol=1e-14)


def test_float32():
    r = Rotation.random(16, random_state=9)
    q = sp(r).astype(np.float32)
    theta = r.as_rotvec().astype(np.float32)
    P = r.as_matrix().astype(np.float32)
    v = np.ones((16, 3), np.float32)

    @jax.jit
    def run(q, theta, P, v):
        out = {
            "to_matrix": quat.to_matrix(q),
            "from_rotvec": quat.to_matrix(quat.from_rotvec(theta)),
            "to_rotvec": quat.to_rotvec(q),
            "from_matrix": quat.to_matrix(quat.from_matrix(P)),
            "rotate": quat.rotate(q, v),
            "slerp": quat.to_matrix(quat.slerp(q, q[::-1], 0.0)),
            "su2_act": quat.su2_act(quat.to_su2(q), v),
            "ck": quat.to_matrix(quat.from_cayley_klein(quat.to_cayley_klein(q))),
            "mean": quat.mean(q.reshape(4, 4, 4)),
        }
        # finite gradients at the identity and 180° in float32 (different series thresholds)
        special = jnp.asarray(SPECIAL_Q, jnp.float32)
        fs = (quat.to_rotvec, quat.to_matrix, quat.angle, lambda q: quat.slerp(q, q, 0.5))
        grads = [jax.vmap(jax.jacrev(f))(special) for f in fs]
        grads.append(jax.jacrev(quat.from_rotvec)(jnp.zeros(3, jnp.float32)))
        return out, grads, quat.to_cayley_klein(q)

    out, grads, U = run(q, theta, P, v)
    want = {
        "to_matrix": r.as_matrix(),
        "from_rotvec": r.as_matrix(),
        "to_rotvec": r.as_rotvec(),
        "from_matrix": r.as_matrix(),
        "rotate": r.apply(v),
        "slerp": r.as_matrix(),
        "su2_act": r.apply(v),
        "ck": r.as_matrix(),
    }
    for name, got in out.items():
        assert got.dtype == jnp.float32, name
        if name in want:
            np.testing.assert_allclose(got, want[name], atol=2e-6, err_msg=name)
    assert U.dtype == jnp.complex64
    for J in grads:
        assert J.dtype == jnp.float32 and np.all(np.isfinite(J))
    np.testing.assert_allclose(grads[-1], np.r_[np.zeros((1, 3)), 0.5 * np.eye(3)], atol=1e-7)
