"""Euler / Tait–Bryan / Davenport angles and kinematic Euler formulas vs SciPy and closed forms.

SciPy's `Rotation` is the oracle for the angle conversions (same sequence strings, ranges and
gimbal-lock convention); finite differences of SciPy's matrices are the oracle for the kinematics.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rigidjax import euler
from tests.helpers import zxz_quaternion

pytestmark = pytest.mark.filterwarnings("ignore:Gimbal lock")

SEQS = euler.SEQUENCES
PI = np.pi
N = 96  # common batch size: JAX caches compiled ops per shape, so shared shapes keep this fast


def symmetric(seq):
    return seq[0].lower() == seq[2].lower()


def lock_values(seq):
    """Middle-angle values at gimbal lock."""
    return (0.0, PI) if symmetric(seq) else (PI / 2, -PI / 2)


def angdiff(a, b):
    """Difference of angles modulo 2π, in [−π, π)."""
    return (np.asarray(a) - np.asarray(b) + PI) % (2 * PI) - PI


def scipy_euler(P, seq):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return Rotation.from_matrix(P).as_euler(seq)


def s_first(q):
    """SciPy's scalar-last quaternion → ours (scalar-first)."""
    return np.roll(q, 1, axis=-1)


def sign_dist(a, b):
    """max |a − b| up to the global sign of each quaternion."""
    d1 = np.abs(a - b).max(-1)
    d2 = np.abs(a + b).max(-1)
    return np.minimum(d1, d2).max()


def random_angles(rng, n, seq):
    a = rng.uniform(-PI, PI, (n, 3))
    a[:, 1] = np.abs(a[:, 1]) if symmetric(seq) else a[:, 1] / 2
    return a


def adversarial_angles(seq):
    """Gimbal lock (exact and within 1e-9), angles at ±π, 2π, identity, large angles."""
    lo, hi = lock_values(seq)
    rows = [[0, 0, 0], [PI, 0.3, -PI], [-PI, 1.0, PI], [2 * PI, 0.4, -2 * PI], [10.0, -7.0, 25.0]]
    for mid in (lo, hi):
        for dm in (0.0, 1e-9, -1e-9):
            rows += [[0.3, mid + dm, 0.5], [PI, mid + dm, -PI / 2], [-2.0, mid + dm, 2.9]]
    return np.array(rows)


def adversarial_rotations(seq):
    """Matrices: identity, 180° turns about several axes, and the adversarial angle cases."""
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, -1], [1, 1, 1], [3, -1, 2]])
    axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    half_turns = Rotation.from_rotvec(PI * axes).as_matrix()
    near_half = Rotation.from_rotvec((PI - 1e-9) * axes).as_matrix()
    by_angles = Rotation.from_euler(seq, adversarial_angles(seq)).as_matrix()
    return np.concatenate([np.eye(3)[None], half_turns, near_half, by_angles])


# --------------------------------------------------------------------------- angles → rotation


@pytest.mark.parametrize("seq", SEQS)
def test_to_matrix_and_to_quat_match_scipy(seq, rng):
    adv = adversarial_angles(seq)
    a = np.concatenate([random_angles(rng, N - len(adv), seq), adv])
    r = Rotation.from_euler(seq, a)
    np.testing.assert_allclose(euler.to_matrix(a, seq), r.as_matrix(), atol=2e-15)
    q = np.asarray(euler.to_quat(a, seq))
    assert sign_dist(q, s_first(r.as_quat())) < 2e-15
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=2e-15)


def test_classical_angles_borisov_mamaev_quaternion(rng):
    """THEORY §3: λ from (ψ, θ, φ) exactly (no sign change), and P = Rz(ψ) Rx(θ) Rz(φ)."""
    psi, theta, phi = rng.uniform(-4, 4, (3, N))
    q = euler.to_quat(np.stack([psi, theta, phi], -1), "ZXZ")
    ref = zxz_quaternion(psi, theta, phi)
    np.testing.assert_allclose(q, ref, atol=2e-15)

    def rz(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    def rx(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    P = euler.to_matrix(np.array([psi[0], theta[0], phi[0]]))  # default seq is "ZXZ"
    np.testing.assert_allclose(P, rz(psi[0]) @ rx(theta[0]) @ rz(phi[0]), atol=2e-15)


# --------------------------------------------------------------------------- rotation → angles


@pytest.mark.parametrize("seq", SEQS)
def test_from_matrix_and_from_quat_match_scipy(seq, rng):
    adv = adversarial_rotations(seq)
    P = np.concatenate([Rotation.random(N - len(adv), random_state=rng).as_matrix(), adv])
    ref = scipy_euler(P, seq)
    ang = np.asarray(euler.from_matrix(P, seq))
    assert np.abs(angdiff(ang, ref)).max() < 1e-10
    # SciPy's ranges: first/third in [−π, π], middle [0, π] or [−π/2, π/2]
    assert np.all(np.abs(ang[:, [0, 2]]) <= PI)
    lo, hi = (0, PI) if symmetric(seq) else (-PI / 2, PI / 2)
    assert np.all((ang[:, 1] >= lo) & (ang[:, 1] <= hi))
    # gimbal lock: third angle zero, exactly where SciPy sets it
    locked = np.abs(ref[:, 2]) == 0
    assert locked.sum() >= 12
    np.testing.assert_array_equal(ang[locked, 2], 0.0)
    # the triple reproduces the rotation (to 1e-9 even at the 1e-9-from-lock cases)
    np.testing.assert_allclose(euler.to_matrix(ang, seq), P, atol=2e-9)
    # from_quat agrees, for either sign and any positive scale of q
    q = s_first(Rotation.from_matrix(P).as_quat())
    q = q * np.where(rng.uniform(size=(len(q), 1)) < 0.5, -2.5, 0.7)
    ang_q = np.asarray(euler.from_quat(q, seq))
    assert np.abs(angdiff(ang_q, ref)).max() < 1e-10


@settings(max_examples=50, deadline=None)
@given(
    seq=st.sampled_from(SEQS),
    u=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
)
def test_angle_round_trip(seq, u):
    """Angles in SciPy's range away from lock survive to_matrix → from_matrix."""
    margin = 1e-3
    if symmetric(seq):
        mid = margin + (PI - 2 * margin) * (u[1] + 1) / 2
    else:
        mid = (PI / 2 - margin) * u[1]
    a = np.array([PI * u[0], mid, PI * u[2]])
    back = euler.from_matrix(euler.to_matrix(a, seq), seq)
    assert np.abs(angdiff(back, a)).max() < 1e-10


@settings(max_examples=50, deadline=None)
@given(
    seq=st.sampled_from(SEQS),
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
)
def test_quaternion_round_trip(seq, q):
    """Any quaternion survives from_quat → to_quat up to sign. The tolerance allows for the
    rotation error of the gimbal-lock convention within gimbal_tol (1e-7) of lock."""
    q = np.asarray(q) / np.linalg.norm(q)
    back = np.asarray(euler.to_quat(euler.from_quat(q, seq), seq))
    assert sign_dist(back, q) < 1e-7


# --------------------------------------------------------------------------- gradients, jit, vmap


# one sequence of each kind (intrinsic or extrinsic, proper Euler or Tait–Bryan) with the
# quick tests; the other twenty (~1–2 s each, eager gradients) with the slow ones
LOCK_QUICK = ("ZXZ", "xyz", "YZX", "zyz")


@pytest.mark.parametrize(
    "seq",
    [s if s in LOCK_QUICK else pytest.param(s, marks=pytest.mark.slow) for s in SEQS],
)
def test_finite_gradients_at_gimbal_lock(seq):
    lo, hi = lock_values(seq)
    a = np.array([[0.3, m + dm, 0.5] for m in (lo, hi) for dm in (0.0, 1e-9, -1e-9)])
    a = np.concatenate([a, [[0.0, 0.0, 0.0], [PI, 0.0, 0.0]]])
    P = Rotation.from_euler(seq, a).as_matrix()
    q = s_first(Rotation.from_euler(seq, a).as_quat())
    gP = jax.grad(lambda x: euler.from_matrix(x, seq).sum())(P)
    gq = jax.grad(lambda x: euler.from_quat(x, seq).sum())(q)
    assert np.all(np.isfinite(gP)) and np.all(np.isfinite(gq))
    gP0 = jax.grad(lambda x: euler.from_matrix(x, seq)[..., 0].sum())(P[:1])
    assert np.all(np.isfinite(gP0)) and np.abs(gP0).max() > 0.1


@pytest.mark.parametrize("seq", ["ZXZ", "xyz", "YZX", "zyz"])
def test_gradient_matches_finite_differences(seq, rng):
    q0 = s_first(Rotation.random(random_state=rng).as_quat())
    dq = rng.normal(size=4)
    h = 1e-6
    fd = (np.asarray(euler.from_quat(q0 + h * dq, seq)) - euler.from_quat(q0 - h * dq, seq)) / (
        2 * h
    )
    _, jvp = jax.jvp(lambda x: euler.from_quat(x, seq), (q0,), (dq,))
    np.testing.assert_allclose(jvp, fd, atol=1e-7)


def test_jit_vmap_and_batch_shapes(rng):
    P = Rotation.random(N, random_state=rng).as_matrix().reshape(2, 3, 16, 3, 3)
    ref = scipy_euler(P.reshape(-1, 3, 3), "zyx").reshape(2, 3, 16, 3)
    f = jax.jit(euler.from_matrix, static_argnames="seq")
    np.testing.assert_allclose(f(P, seq="zyx"), ref, atol=1e-12)
    vf = jax.jit(jax.vmap(jax.vmap(lambda x: euler.from_matrix(x, "zyx"))))
    np.testing.assert_allclose(vf(P), ref, atol=1e-12)
    back = euler.to_matrix(ref, "zyx")
    np.testing.assert_allclose(back, P, atol=1e-12)
    assert euler.to_quat(ref, "zyx").shape == (2, 3, 16, 4)


def test_float32(rng):
    P = Rotation.random(4, random_state=rng).as_matrix()
    for seq in ("ZXZ", "xyz", "ZYX", "yzy"):
        lo, hi = lock_values(seq)
        a = [[0.3, lo, 0.5], [-2.0, hi, 1.0], [1.0, lo + 1e-9, 3.0], [-3.0, hi - 1e-9, -1.0]]
        P32 = np.concatenate([P, Rotation.from_euler(seq, a).as_matrix()]).astype(np.float32)
        ang = euler.from_matrix(P32, seq)
        assert ang.dtype == jnp.float32
        assert np.abs(angdiff(ang[:4], scipy_euler(P, seq))).max() < 1e-4
        np.testing.assert_array_equal(ang[4:, 2], 0.0)
        Pb = euler.to_matrix(ang, seq)
        assert Pb.dtype == jnp.float32
        np.testing.assert_allclose(Pb, P32, atol=3e-6)
    # one jitted gradient (compiling is cheaper than differentiating op by op in eager mode)
    g = jax.jit(jax.grad(lambda x: euler.from_matrix(x, seq).sum()))(P32)
    assert g.dtype == jnp.float32 and np.all(np.isfinite(g))
    rates = euler.omega_to_rates(np.float32([0.1, 0.5, 0.2]), np.float32([1, 2, 3]))
    assert rates.dtype == jnp.float32


# --------------------------------------------------------------------------- argument checks


@pytest.mark.parametrize("bad", ["ZZX", "ZX", "XYZW", "xYz", "abc", "xyy", "", 3, None])
def test_bad_seq_raises(bad):
    a = np.zeros(3)
    calls = [
        lambda: euler.to_matrix(a, bad),
        lambda: euler.to_quat(a, bad),
        lambda: euler.from_matrix(np.eye(3), bad),
        lambda: euler.from_quat(np.array([1.0, 0, 0, 0]), bad),
        lambda: euler.rates_to_omega(a, a, bad),
        lambda: euler.omega_to_rates(a, a, bad),
    ]
    for call in calls:
        with pytest.raises(ValueError, match="seq"):
            call()


def test_bad_shapes_and_frame_raise():
    with pytest.raises(ValueError, match="angles"):
        euler.to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match="P"):
        euler.from_matrix(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="q"):
        euler.from_quat(np.zeros(3))
    with pytest.raises(ValueError, match="rates"):
        euler.rates_to_omega(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="frame"):
        euler.rates_to_omega(np.zeros(3), np.zeros(3), frame="left")


# --------------------------------------------------------------------------- Davenport angles


def random_axes(rng):
    """Non-orthogonal m, n and e = m × n/|m × n| (not normalised m, n on purpose)."""
    m, n = rng.normal(size=(2, 3))
    e = np.cross(m, n)
    return m, e / np.linalg.norm(e), n


def test_davenport_matches_scipy(rng):
    for _ in range(3):
        m, e, n = random_axes(rng)
        axes = np.stack([m, e, n])
        unit = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
        a = rng.uniform(-PI, PI, (N, 3))
        r = Rotation.from_davenport(unit, "intrinsic", a)
        np.testing.assert_allclose(euler.davenport_to_matrix(a, axes), r.as_matrix(), atol=2e-15)
        np.testing.assert_allclose(
            euler.davenport_to_matrix(a, np.stack([m, n])), r.as_matrix(), atol=2e-15
        )
        # our fixed-axes product P = Q(ψm) Q(ϑe) Q(φn) is SciPy's extrinsic order (n, e, m)
        r_ext = Rotation.from_davenport(unit[::-1], "extrinsic", a[:, ::-1])
        np.testing.assert_allclose(r_ext.as_matrix(), r.as_matrix(), atol=2e-15)
        q = np.asarray(euler.davenport_to_quat(a, axes))
        assert sign_dist(q, s_first(r.as_quat())) < 2e-15

        P = np.concatenate(
            [Rotation.random(N // 2, random_state=rng).as_matrix(), r[: N // 2].as_matrix()]
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = Rotation.from_matrix(P).as_davenport(unit, "intrinsic")
        ang = np.asarray(euler.davenport_from_matrix(P, axes))
        assert np.abs(angdiff(ang, ref)).max() < 1e-9
        np.testing.assert_allclose(euler.davenport_to_matrix(ang, axes), P, atol=1e-12)
        ang2 = euler.davenport_from_matrix(P, np.stack([m, n]))
        np.testing.assert_allclose(ang2, ang, atol=1e-12)


def test_davenport_gimbal_lock(rng):
    """Lock where Q(ϑ e) n ∥ m: ϑ = −λ or π − λ, λ the angle from n to m about e."""
    m, e, n = random_axes(rng)
    mu, nu = m / np.linalg.norm(m), n / np.linalg.norm(n)
    lam = np.arctan2(np.dot(mu, np.cross(nu, e)), np.dot(mu, nu))
    assert lam > 0  # e = m × n/|m × n| makes λ ∈ (0, π) (no flip of e needed)
    axes = np.stack([m, e, n])
    a = np.array([[0.4, t + dt, -1.1] for t in (-lam, PI - lam) for dt in (0, 1e-9, -1e-9)])
    a = np.concatenate([a, [[PI, -lam, PI], [-3.0, PI - lam, 0.0]]])  # batch of 8, as above
    P = Rotation.from_davenport(axes / np.linalg.norm(axes, axis=-1)[:, None], "i", a).as_matrix()
    ang = np.asarray(euler.davenport_from_matrix(P, axes))
    np.testing.assert_array_equal(ang[:, 2], 0.0)
    np.testing.assert_allclose(euler.davenport_to_matrix(ang, axes), P, atol=2e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = Rotation.from_matrix(P).as_davenport(
            axes / np.linalg.norm(axes, axis=-1)[:, None], "i"
        )
    assert np.abs(angdiff(ang, ref)).max() < 1e-9
    g = jax.grad(lambda x: euler.davenport_from_matrix(x, axes).sum())(P)
    assert np.all(np.isfinite(g))


def test_davenport_classical_and_traced_axes(rng):
    """m = n = z with e = x are the classical angles "ZXZ"; traced axes work under jit."""
    axes = np.array([[0, 0, 2.0], [1, 0, 0], [0, 0, 1]])
    a = random_angles(rng, N, "ZXZ")
    P = euler.to_matrix(a, "ZXZ")
    np.testing.assert_allclose(euler.davenport_to_matrix(a, axes), P, atol=2e-15)
    np.testing.assert_allclose(euler.davenport_from_matrix(P, axes), a, atol=1e-12)
    f = jax.jit(euler.davenport_to_matrix)
    np.testing.assert_allclose(f(a, axes), P, atol=2e-15)
    # batched axes: one set of axes per rotation
    ax_b = np.stack([np.stack(random_axes(rng)) for _ in range(3)])
    ref = np.stack(
        [
            Rotation.from_davenport(x / np.linalg.norm(x, axis=-1)[:, None], "i", y).as_matrix()
            for x, y in zip(ax_b, a[:3], strict=True)
        ]
    )
    np.testing.assert_allclose(euler.davenport_to_matrix(a[:3], ax_b), ref, atol=2e-15)
    with pytest.raises(Exception, match="perpendicular"):
        jax.block_until_ready(f(a, np.array([[0, 0, 1.0], [1, 0, 1], [0, 0, 1]])))
    mn = np.array([[0, 1.0, 1.0], [1.0, 0, 0]])  # (m, n) form, traced: e = m × n/|m × n|
    ref = Rotation.from_davenport(
        np.array([[0, 1, 1] / np.sqrt(2), [0, 1, -1] / np.sqrt(2), [1, 0, 0]]), "i", a
    ).as_matrix()
    np.testing.assert_allclose(f(a, mn), ref, atol=2e-15)
    with pytest.raises(Exception, match="perpendicular"):  # m ∥ n, traced
        jax.block_until_ready(f(a, np.array([[0, 0, 1.0], [0, 0, -3.0]])))


def test_davenport_classical_about_any_axes_matches_scipy(rng):
    """m = n along a general direction (not a basis axis): sin λ = n · (m × e) is zero but for
    rounding, whose sign must not flip e (the middle angle left [0, π], unlike SciPy's)."""
    traced = jax.jit(euler.davenport_from_matrix)
    for _ in range(8):
        m = rng.normal(size=3)
        m /= np.linalg.norm(m)
        e = np.cross(m, rng.normal(size=3))
        axes = np.stack([m, e / np.linalg.norm(e), m])
        a = random_angles(rng, N, "ZXZ")  # the middle angle in [0, π]
        P = Rotation.from_davenport(axes, "intrinsic", a).as_matrix()
        for got in (euler.davenport_from_matrix(P, axes), traced(P, jnp.asarray(axes))):
            np.testing.assert_allclose(got, a, atol=1e-10)


def test_davenport_bad_axes_raise():
    z, x = [0, 0, 1.0], [1.0, 0, 0]
    with pytest.raises(ValueError, match="middle axis undefined"):
        euler.davenport_to_matrix(np.zeros(3), np.array([z, z]))  # m ∥ n: e undefined
    with pytest.raises(ValueError, match="perpendicular"):
        euler.davenport_to_matrix(np.zeros(3), np.array([z, [1.0, 0, 0.1], x]))
    with pytest.raises(ValueError, match="non-zero"):
        euler.davenport_from_matrix(np.eye(3), np.array([z, x, [0, 0, 0]]))
    with pytest.raises(ValueError, match="axes"):
        euler.davenport_to_matrix(np.zeros(3), np.eye(4)[:, :3])


# --------------------------------------------------------------------------- kinematics


def vee(A):
    return 0.5 * np.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0],
                           A[..., 1, 0] - A[..., 0, 1]], -1)  # fmt: skip


@pytest.mark.parametrize("frame", ["body", "space"])
@pytest.mark.parametrize("seq", SEQS)
def test_rates_to_omega_finite_differences(seq, frame, rng):
    """Ω = vee(Pᵀ Ṗ), ω = vee(Ṗ Pᵀ) with Ṗ from central differences of SciPy's matrices."""
    a = random_angles(rng, 16, seq)
    rates = rng.normal(size=(16, 3))
    h = 1e-5
    P = Rotation.from_euler(seq, a).as_matrix()
    Pd = (
        Rotation.from_euler(seq, a + h * rates).as_matrix()
        - Rotation.from_euler(seq, a - h * rates).as_matrix()
    ) / (2 * h)
    Pt = np.swapaxes(P, -1, -2)
    ref = vee(Pt @ Pd) if frame == "body" else vee(Pd @ Pt)
    omega = euler.rates_to_omega(a, rates, seq, frame)
    np.testing.assert_allclose(omega, ref, atol=1e-8)
    J = np.asarray(euler.jacobian(a, seq, frame))
    np.testing.assert_allclose(J @ rates[..., None], np.asarray(omega)[..., None], atol=1e-14)
    # |det J| = |sin β| (proper Euler) or |cos β| (Tait–Bryan)
    det = np.abs(np.linalg.det(J))
    np.testing.assert_allclose(
        det, np.abs(np.sin(a[:, 1]) if symmetric(seq) else np.cos(a[:, 1])), atol=1e-14
    )
    back = euler.omega_to_rates(a, omega, seq, frame, check=True)
    np.testing.assert_allclose(back, rates, atol=1e-11)


def test_kinematic_euler_formulas_theory():
    """THEORY §4 (Borisov–Mamaev 001): body Ω from (ψ̇, θ̇, φ̇) for "ZXZ", and ω = P Ω."""
    rng = np.random.default_rng(4)
    psi, th, phi = rng.uniform(-3, 3, (3, 16))
    dpsi, dth, dphi = rng.normal(size=(3, 16))
    a = np.stack([psi, th, phi], -1)
    rates = np.stack([dpsi, dth, dphi], -1)
    ref = np.stack(
        [
            dpsi * np.sin(th) * np.sin(phi) + dth * np.cos(phi),
            dpsi * np.sin(th) * np.cos(phi) - dth * np.sin(phi),
            dpsi * np.cos(th) + dphi,
        ],
        -1,
    )
    np.testing.assert_allclose(euler.rates_to_omega(a, rates), ref, atol=1e-14)
    P = Rotation.from_euler("ZXZ", a).as_matrix()
    np.testing.assert_allclose(
        euler.rates_to_omega(a, rates, frame="space"), np.einsum("nij,nj->ni", P, ref), atol=1e-14
    )


def test_aircraft_rates_002_148():
    """Roll φ1, pitch φ2, yaw φ3 = intrinsic "ZYX" with angles (φ3, φ2, φ1) (002 #148)."""
    rng = np.random.default_rng(5)
    f1, f3 = rng.uniform(-3, 3, (2, 16))
    f2 = rng.uniform(-1.4, 1.4, 16)
    w1, w2, w3 = rng.normal(size=(3, 16))
    d1 = w1 + np.sin(f1) * np.tan(f2) * w2 + np.cos(f1) * np.tan(f2) * w3
    d2 = np.cos(f1) * w2 - np.sin(f1) * w3
    d3 = (np.sin(f1) * w2 + np.cos(f1) * w3) / np.cos(f2)
    rates = euler.omega_to_rates(np.stack([f3, f2, f1], -1), np.stack([w1, w2, w3], -1), "ZYX")
    np.testing.assert_allclose(rates, np.stack([d3, d2, d1], -1), atol=1e-12)


def test_omega_to_rates_gimbal_check():
    w = np.array([0.3, -0.2, 1.0])
    for seq, lock in (("ZXZ", 0.0), ("zyz", PI - 1e-9), ("ZYX", PI / 2), ("xzy", -PI / 2 + 1e-9)):
        a = np.array([0.2, lock, -0.7])
        with pytest.raises(Exception, match="gimbal lock"):
            jax.block_until_ready(euler.omega_to_rates(a, w, seq, check=True))
        ok = euler.omega_to_rates(
            a + np.array([0, 1e-3, 0]) * np.sign(0.5 - lock), w, seq, check=True
        )
        assert np.all(np.isfinite(ok))
    f = jax.jit(lambda a: euler.omega_to_rates(a, w, "ZXZ", check=True))
    assert np.all(np.isfinite(f(np.array([0.1, 0.5, 0.2]))))
    with pytest.raises(Exception, match="gimbal lock"):
        jax.block_until_ready(f(np.array([0.1, 0.0, 0.2])))
