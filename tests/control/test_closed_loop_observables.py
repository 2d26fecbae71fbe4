"""The closed-loop observables (`pointing_error`, `settling_time`, `peak_wheel_speed`,
`saturation_count`) against SciPy's rotation magnitudes and loops written in NumPy, on a
batched slew with saturated wheels; and finite gradients of the pointing error at zero."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax import observables as obs

AXES = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.6], [0.0, 0.0, 1.0, 0.52915026]])
Q_T = np.array([np.cos(0.6), np.sin(0.6) * 0.6, np.sin(0.6) * 0.8, 0.0])
TS = jnp.linspace(0.0, 12.0, 49)
UMAX = 0.05


@pytest.fixture(scope="module")
def loop():
    """Three spacecraft (their own initial rates) slewing to Q_T on saturated wheels."""
    g = rj.Gyrostat(
        np.array([1.0, 1.5, 2.0]), wheel_axes=AXES, wheel_inertia=[0.01] * 4, wheel_torque_max=UMAX
    )
    law = rj.control.quaternion_pd(0.4, 0.9, Q_T, wheel_axes=AXES)
    w0 = np.array([[0.0, 0.0, 0.0], [0.02, -0.01, 0.0], [0.0, 0.03, 0.01]])
    return rj.simulate(
        g, w0, None, TS, controller=law, control_period=0.25, solver=rj.RK4(),
        stepsize_controller=diffrax.ConstantStepSize(), dt0=0.05,
    )  # fmt: skip


def test_pointing_error_matches_scipy(loop):
    got = np.asarray(obs.pointing_error(loop, Q_T))
    q = np.asarray(loop.quat).reshape(-1, 4)
    target = Rotation.from_quat(np.r_[Q_T[1:], Q_T[0]])
    want = (target.inv() * Rotation.from_quat(q[:, [1, 2, 3, 0]])).magnitude()
    np.testing.assert_allclose(got.ravel(), want, rtol=0, atol=1e-12)
    assert got.shape == (3, TS.shape[0])
    # a non-unit target is normalised; a zero one is refused (its error quaternion was 0 and
    # the pointing perfect)
    np.testing.assert_allclose(obs.pointing_error(loop, 3 * Q_T), got, rtol=0, atol=1e-15)
    for f in (obs.pointing_error, lambda tr, q: obs.settling_time(tr, q, 0.01)):
        with pytest.raises(ValueError, match="q_target is a zero quaternion"):
            f(loop, np.zeros(4))


@pytest.mark.parametrize("tolerance", [np.radians(0.5), np.radians(5.0), 1e-9])
def test_settling_time_is_a_numpy_loop(loop, tolerance):
    err = np.asarray(obs.pointing_error(loop, Q_T))
    got = np.asarray(obs.settling_time(loop, Q_T, tolerance))
    for b in range(3):
        want = np.inf
        for i in range(len(TS) - 1, -1, -1):  # walk back while inside the tolerance
            if err[b, i] > tolerance:
                break
            want = float(TS[i])
        assert got[b] == want


@pytest.mark.parametrize("tolerance", [np.radians(0.5), np.radians(5.0), np.pi])
def test_settling_bracket_is_the_last_sample_outside_and_the_next(loop, tolerance):
    err = np.asarray(obs.pointing_error(loop, Q_T))
    before, after = (np.asarray(x) for x in obs.settling_bracket(loop, Q_T, tolerance))
    ts = np.asarray(TS)
    for b in range(3):
        outside = np.flatnonzero(err[b] > tolerance)
        if outside.size == 0:  # never outside: settled at the first sample
            assert before[b] == -np.inf and after[b] == ts[0]
        else:
            i = outside[-1]
            assert before[b] == ts[i]
            assert after[b] == (ts[i + 1] if i + 1 < ts.size else np.inf)
    np.testing.assert_array_equal(after, obs.settling_time(loop, Q_T, tolerance))


def test_wheel_observables_are_numpy_maxima_and_counts(loop):
    np.testing.assert_array_equal(
        obs.peak_wheel_speed(loop), np.abs(np.asarray(loop.wheel_speed)).max(axis=(1, 2))
    )
    cmd = np.asarray(loop.command)
    want = [sum(np.any(np.abs(u) >= UMAX * (1 - 1e-12)) for u in cmd[b]) for b in range(3)]
    got = np.asarray(obs.saturation_count(loop, UMAX))
    np.testing.assert_array_equal(got, want)
    assert min(want) > 0  # the slew saturates the wheels at first


def test_pointing_error_gradient_finite_at_zero(loop):
    """`pointing_error` of `q_T ∘ exp(θ)` is `|θ|`: gradient `θ/|θ|` away from 0, finite (0)
    at 0."""

    def error(theta):
        q = rj.quat.mul(jnp.asarray(Q_T), rj.quat.from_rotvec(theta))
        tr = eqx.tree_at(lambda t: t.quat, loop, jnp.broadcast_to(q, loop.quat.shape))
        return obs.pointing_error(tr, Q_T)[0, 0]

    theta = jnp.array([0.1, -0.2, 0.05])
    np.testing.assert_allclose(error(theta), jnp.linalg.norm(theta), rtol=1e-13)
    np.testing.assert_allclose(jax.grad(error)(theta), theta / jnp.linalg.norm(theta), rtol=1e-12)
    g0 = jax.grad(error)(jnp.zeros(3))
    assert np.all(np.isfinite(g0))


def test_wheel_observables_need_wheels_and_a_controller():
    tr = rj.simulate(rj.RigidBody([1.0, 2.0, 3.0]), [0.1, 0.0, 0.0], None, TS[:3])
    with pytest.raises(ValueError, match="gyrostat with wheels"):
        obs.peak_wheel_speed(tr)
    with pytest.raises(ValueError, match="with a controller"):
        obs.saturation_count(tr, UMAX)


def test_a_negative_settling_tolerance_is_named(loop):
    """A negative tolerance is never met: `settling_time` gave `inf` without a word."""
    for f in (obs.settling_time, lambda tr, q, tol: obs.settling_bracket(tr, q, tol)[0]):
        with pytest.raises(ValueError, match=r"tolerance must be non-negative .*radians.*-0.01"):
            f(loop, Q_T, -0.01)
    with pytest.raises(ValueError, match=r"tolerance must be non-negative"):
        rj.events.settling_event(Q_T, -0.01)
    with pytest.raises(Exception, match="tolerance must be non-negative"):
        jax.block_until_ready(jax.jit(lambda tol: obs.settling_time(loop, Q_T, tol))(-0.01))
    # zero is a tolerance (exact pointing), and the traced call keeps its value
    assert np.all(np.asarray(jax.jit(lambda tol: obs.settling_time(loop, Q_T, tol))(0.01)) > 0)
