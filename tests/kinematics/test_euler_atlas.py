"""Euler-angle kinematics in a two-chart atlas (THEORY §4; `rigidjax.kinematics.euler_atlas`):
from the identity and through every gimbal-lock attitude, against quaternion kinematics."""

from typing import Any

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import RK4, RigidBody, darboux, euler, simulate, so3
from rigidjax.kinematics import EulerAngles
from rigidjax.kinematics.euler_atlas import lock_axes, margin, partner

TIGHT: dict[str, Any] = dict(rtol=1e-12, atol=1e-12)
SWITCH = 0.5  # EulerAngles' default


def _lock_attitudes(seq):
    """Rotations exactly at the gimbal lock of `seq` (P e_v = ±e_u), and some near it."""
    u, v = lock_axes(seq)
    to_u = Rotation.align_vectors([np.eye(3)[u]], [np.eye(3)[v]])[0]
    spins = Rotation.from_rotvec(np.outer([0.0, 0.7, -2.0], np.eye(3)[u]))
    flip = Rotation.from_rotvec(np.pi * np.eye(3)[(u + 1) % 3])
    near = Rotation.from_rotvec(np.outer([1e-9, -1e-5, 1e-3], np.eye(3)[(u + 2) % 3]))
    locked = [s * to_u for s in spins] + [flip * s * to_u for s in spins]
    return np.stack([r.as_matrix() for r in locked] + [(n * to_u).as_matrix() for n in near])


def test_partner_charts_never_lock_together(rng):
    """For all 24 sequences: the partner is an involution of the other kind (proper ↔ Tait–Bryan,
    same case); `margin` is |det J|; and m² + m'² ≥ 1 at every attitude (`euler_atlas`),
    checked on random rotations and on the lock attitudes of both charts."""
    random = Rotation.random(300, rng).as_matrix()
    for seq in euler.SEQUENCES:
        other = partner(seq)
        assert partner(other) == seq and other.isupper() == seq.isupper()
        assert (seq[0] == seq[2]) != (other[0] == other[2])
        P = np.concatenate([random, _lock_attitudes(seq), _lock_attitudes(other)])
        a, b = euler.from_matrix(P, seq), euler.from_matrix(P, other)
        m, m_other = margin(a, seq), margin(b, other)
        det = jnp.linalg.det(euler.jacobian(a, seq, "body"))
        np.testing.assert_allclose(m, jnp.abs(det), atol=1e-12)
        assert np.all(m**2 + m_other**2 >= 1 - 1e-12)
        np.testing.assert_allclose(margin(a[300:306], seq), 0, atol=1e-12)  # exactly locked
    with pytest.raises(ValueError, match="seq must be"):
        partner("ZZX")


@pytest.mark.parametrize("seq", ["ZXZ", "XYZ", "zxz", "xyz"])
def test_state_maps(seq, rng):
    """`from_matrix` starts in `seq` unless it is within `switch` of lock; `to_matrix`,
    `to_quat` and `angles` reproduce P; `step_end` changes chart only below `switch`, keeps the
    quaternion (with its sign), and wraps the first/third angles by 4π beyond ±3π."""
    kin = EulerAngles(seq=seq)
    P = np.concatenate([Rotation.random(20, rng).as_matrix(), _lock_attitudes(seq)])
    y = kin.from_matrix(P)
    in_partner = y[:, 3] == 1
    np.testing.assert_array_equal(in_partner, margin(euler.from_matrix(P, seq), seq) < SWITCH)
    assert np.all(in_partner[-9:]) and np.all(y[:, 3] * (1 - y[:, 3]) == 0)
    np.testing.assert_allclose(kin.to_matrix(y), P, atol=1e-12)
    np.testing.assert_allclose(so3.orthogonality_error(kin.to_matrix(y)), 0, atol=1e-13)
    # (1e-9 from lock, within euler.gimbal_tol, the lock convention is off by ~1e-9)
    np.testing.assert_allclose(euler.to_matrix(kin.angles(y), seq), P, atol=1e-8)

    # a state in the primary chart 0.1 from lock switches; the partner's margin is then large
    beta = 0.1 if seq[0].lower() == seq[2].lower() else np.pi / 2 - 0.1
    y0 = jnp.array([[0.4, beta, -2.5, 0.0], [0.4, 1.0, -2.5, 0.0], [10.0, 1.0, -12.0, 0.0]])
    y1, changed = jax.vmap(kin.step_end)(y0)
    np.testing.assert_array_equal(changed, [True, False, False])
    np.testing.assert_array_equal(y1[:, 3], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(kin.to_quat(y1), kin.to_quat(y0), atol=1e-13)  # same sign
    assert margin(y1[0, :3], kin.partner) >= np.sqrt(1 - SWITCH**2)
    np.testing.assert_array_equal(y1[1], y0[1])
    np.testing.assert_allclose(y1[2], [10.0 - 4 * np.pi, 1.0, -12.0 + 4 * np.pi, 0.0], atol=1e-14)
    np.testing.assert_allclose(kin.angles(y1), euler.from_quat(kin.to_quat(y0), seq), atol=1e-12)
    y2, changed = kin.step_end(y1[0])  # no chatter
    assert not changed and np.all(y2 == y1[0])


def test_bad_arguments():
    with pytest.raises(ValueError, match="seq must be"):
        EulerAngles(seq="ZXX")
    with pytest.raises(ValueError, match=r"switch .* must be in \[0, 1/√2\)"):
        EulerAngles(switch=0.8)
    with pytest.raises(ValueError, match="frame must be"):
        EulerAngles(frame="world")  # pyright: ignore[reportArgumentType]


def _about_axis(k):
    e = jnp.zeros(3).at[k].set(1.0)
    return e, lambda t: e + 0 * t


# Rotation about a fixed axis from the identity runs through exact locks of both charts:
# e.g. "ZXZ" (locked where P e_z = ±e_z) at t = 0, π, 2π and its partner "ZXY" (P e_y = ±e_z)
# at t = π/2, 3π/2.
@pytest.mark.parametrize(
    ("seq", "frame", "axis"),
    [("ZXZ", "space", 0)]
    + [  # ~20 s each (a compile per sequence and frame): the other three with the slow tests
        pytest.param(*c, marks=pytest.mark.slow)
        for c in [("XYZ", "body", 1), ("zxz", "body", 0), ("xyz", "space", 1)]
    ],
)
def test_darboux_through_exact_gimbal_locks(seq, frame, axis):
    ts = jnp.linspace(0.0, 2 * np.pi, 13)
    e, w = _about_axis(axis)
    P, ys = darboux(w, ts, frame=frame, method="euler", seq=seq, return_state=True, **TIGHT)
    P_quat = darboux(w, ts, frame=frame, method="quat", **TIGHT)
    exact = jax.vmap(so3.exp)(ts[:, None] * e)
    np.testing.assert_allclose(P, P_quat, atol=1e-10)
    np.testing.assert_allclose(P, exact, atol=1e-10)
    # the chart switched back and forth; every saved state is well inside its chart
    chart = np.asarray(ys[:, 3])
    assert chart[0] == (seq[0] == seq[2])  # the identity is a lock of proper sequences only
    assert np.count_nonzero(np.diff(chart)) >= 4
    kin = EulerAngles(seq=seq, frame=frame)
    m = np.where(chart == 1, margin(ys[:, :3], kin.partner), margin(ys[:, :3], seq))
    assert np.all(m >= SWITCH)
    # angles in the user's sequence everywhere, equal to the integrated ones in the primary chart
    angles = kin.angles(ys)
    np.testing.assert_allclose(euler.to_matrix(angles, seq), exact, atol=1e-10)
    primary = chart == 0
    diff = angles[primary] - euler.from_matrix(exact, seq)[primary]
    np.testing.assert_allclose(np.angle(np.exp(1j * diff)), 0, atol=1e-9)  # modulo 2π
    q = kin.to_quat(ys)  # sign continuous along the motion (no canonicalisation)
    assert np.all(np.sum(q[1:] * q[:-1], -1) > 0)


@pytest.mark.slow  # ~25 s (two compiled solves)
def test_darboux_from_the_identity_and_near_miss():
    """The default start (P0 = None, the lock of "ZXZ") and a path passing 1e-9 from it
    (formerly a gimbal-lock error) agree with quaternion kinematics; `switch=0` (one chart)
    still raises the clear gimbal-lock error."""
    ts = jnp.linspace(0.0, 6.0, 7)

    def w(t):
        return jnp.stack([jnp.cos(0.3 * t), 0.5 * jnp.sin(t), 0.2 + 0 * t])

    np.testing.assert_allclose(
        darboux(w, ts, method="euler", **TIGHT), darboux(w, ts, method="quat", **TIGHT), atol=1e-9
    )
    P0 = so3.exp(jnp.array([-0.5, 0.0, 0.0])) @ so3.exp(jnp.array([0.0, 1e-9, 0.0]))
    exact = jax.vmap(lambda t: so3.exp(jnp.array([t, 0.0, 0.0])))(ts) @ P0
    _, ex = _about_axis(0)
    np.testing.assert_allclose(darboux(ex, ts, P0=P0, method="euler", **TIGHT), exact, atol=1e-10)
    with pytest.raises(Exception, match="gimbal lock"):
        darboux(ex, ts, method=EulerAngles(switch=0.0))


@pytest.mark.parametrize(
    ("kinematics", "seq", "axis"),
    [  # ~40 s each (simulate compiled with the chart atlas): with the slow tests
        pytest.param("euler", "ZXZ", 0, marks=pytest.mark.slow),
        pytest.param(EulerAngles(seq="XYZ", frame="body"), "XYZ", 1, marks=pytest.mark.slow),
    ],
)
def test_simulate_tumbling_through_gimbal_lock(kinematics, seq, axis):
    """A spin about a principal axis from the identity, through exact locks of both charts at
    saved times, and a body tumbling about its unstable middle axis (Dzhanibekov flips). Ω and
    the attitude agree with quaternion kinematics; the primary chart's margin falls below
    `switch` and rises above it again along the saved attitudes (so the chart switched: a saved
    state in `seq` has margin ≥ `switch`)."""
    body = RigidBody(jnp.array([1.0, 2.0, 3.0]))
    ts = jnp.linspace(0.0, 12.0, 25)
    for k, omega0 in enumerate([np.pi / 2 * np.eye(3)[axis], np.array([0.02, 1.5, 0.03])]):
        traj = simulate(body, omega0, None, ts, kinematics=kinematics, **TIGHT)
        ref = simulate(body, omega0, None, ts, kinematics="quat", **TIGHT)
        np.testing.assert_allclose(traj.omega, ref.omega, atol=1e-9)
        np.testing.assert_allclose(traj.matrix, ref.matrix, atol=1e-9)
        np.testing.assert_allclose(traj.quat, ref.quat, atol=1e-9)
        m = margin(euler.from_quat(ref.quat, seq), seq)
        below = np.asarray(m < SWITCH)
        assert below.any() and (~below).any() and np.count_nonzero(np.diff(below)) >= 2
        if k == 0:
            assert np.count_nonzero(m < 1e-9) >= 6  # the spin is exactly locked every 2 s


@pytest.mark.slow  # ~40 s: reverse mode through the solve with chart switches
def test_jit_and_grad_through_chart_switches():
    """Reverse-mode gradient through a fixed-step simulate from the identity with chart
    switches: finite and equal to that of quaternion kinematics to the discretisation error."""
    body = RigidBody(jnp.array([1.0, 2.0, 3.0]))
    ts = jnp.array([0.0, 1.0, 2.5])
    weights = jnp.array([0.3, -0.2, 0.5, 0.7, -1.1, 0.4, 0.9])

    def loss(w0, kinematics):
        traj = simulate(
            body,
            w0,
            None,
            ts,
            kinematics=kinematics,
            solver=RK4(),
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=0.01,
        )
        return jnp.sum(jnp.concatenate([traj.omega[-1], traj.quat[-1]]) * weights)

    w0 = jnp.array([1.2, 0.1, -0.2])
    value, grad = jax.jit(jax.value_and_grad(lambda w: loss(w, "euler")))(w0)
    assert np.all(np.isfinite(grad))
    # against central differences of the quaternion kinematics (smooth, no chart switches)
    loss_q = jax.jit(lambda w: loss(w, "quat"))
    h = 1e-5
    fd = [(loss_q(w0 + h * e) - loss_q(w0 - h * e)) / (2 * h) for e in jnp.eye(3)]
    np.testing.assert_allclose(value, loss_q(w0), atol=1e-8)
    np.testing.assert_allclose(grad, fd, atol=1e-6)
