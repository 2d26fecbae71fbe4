"""Events with jump maps and at fixed steps: a closed loop (a gyrostat with wheels under a sampled
PD law) and a gyrostat stopped at an event, on the per-body kernel and the Diffrax path; the
settling event against the sample grid and the pointing error at the event; fixed-step events
against the closed-form flip time."""

import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rigidjax as rj
from rigidjax import observables as obs
from rigidjax.events import flip_event, settling_event

AXES = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.6], [0.0, 0.0, 1.0, 0.52915026]])
Q_T = np.array([np.cos(0.6), np.sin(0.6) * 0.6, np.sin(0.6) * 0.8, 0.0])
TS = jnp.linspace(0.0, 12.0, 49)
W0 = np.array([[0.0, 0.0, 0.0], [0.02, -0.01, 0.0], [0.0, 0.03, 0.01]])
TOL = np.radians(20.0)
SAT = rj.Gyrostat(
    np.array([1.0, 1.5, 2.0]), wheel_axes=AXES, wheel_inertia=[0.01] * 4, wheel_torque_max=0.05
)
LAW = rj.control.quaternion_pd(0.4, 0.9, Q_T, wheel_axes=AXES)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.05)


def _loop(solver, event=None, **kw):
    """The three spacecraft under the law; `kw` the solver's options (fixed RK4 steps by
    default)."""
    return rj.simulate(
        SAT, W0, None, TS, controller=LAW, control_period=0.25, solver=solver, event=event,
        **(kw or FIXED),
    )  # fmt: skip


@pytest.fixture(scope="module")
def plain():
    return _loop(rj.RK4())


@pytest.fixture(scope="module")
def last_outside(plain):
    """The last sample of each spacecraft outside the tolerance (the grid's bracket)."""
    err = np.asarray(obs.pointing_error(plain, Q_T))
    last = np.array([np.flatnonzero(e > TOL)[-1] for e in err])
    assert (last < TS.shape[0] - 1).all()  # each settles within TS
    return last


@pytest.fixture(scope="module")
def stopped(last_outside):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no fallback: the per-body kernel takes it
        return _loop(rj.RK4(), settling_event(Q_T, TOL, TS[last_outside]))


def test_settling_event_lies_in_the_grid_bracket_at_the_tolerance(stopped, last_outside, plain):
    t = np.asarray(stopped.event_t)
    ts = np.asarray(TS)
    assert t.shape == (3,)
    assert (ts[last_outside] < t).all() and (t <= ts[last_outside + 1]).all()
    np.testing.assert_array_equal(obs.settling_time(plain, Q_T, TOL), ts[last_outside + 1])
    for b in range(3):
        k = last_outside[b] + 1  # the first output after the event holds the state there
        held = stopped.quat[b, k:]
        np.testing.assert_array_equal(held, np.broadcast_to(held[0], held.shape))
        ws = stopped.wheel_speed[b, k:]
        np.testing.assert_array_equal(ws, np.broadcast_to(ws[0], ws.shape))
        at = obs.pointing_error(stopped, Q_T)[b, k]
        np.testing.assert_allclose(at, TOL, rtol=0, atol=1e-9)  # located at the crossing
        # before the event: the motion without it
        np.testing.assert_allclose(stopped.quat[b, :k], plain.quat[b, :k], rtol=0, atol=1e-14)
        # the commands after the event repeat the held one
        after = np.asarray(stopped.control_ts) > t[b]
        cmds = np.asarray(stopped.command[b])[after]
        np.testing.assert_array_equal(cmds, np.broadcast_to(cmds[0], cmds.shape))


@pytest.mark.slow
def test_a_body_alone_is_as_in_the_batch(stopped, last_outside):
    alone = rj.simulate(
        SAT, W0[1], None, TS, controller=LAW, control_period=0.25, solver=rj.RK4(),
        event=settling_event(Q_T, TOL, TS[last_outside[1]]), **FIXED,
    )  # fmt: skip
    np.testing.assert_array_equal(alone.event_t, stopped.event_t[1])
    np.testing.assert_array_equal(alone.quat, stopped.quat[1])


@pytest.mark.slow
def test_not_terminating_keeps_the_motion(plain, last_outside, stopped):
    event = settling_event(Q_T, TOL, TS[last_outside], terminate=False)
    going = _loop(rj.RK4(), event)
    np.testing.assert_array_equal(going.event_t, stopped.event_t)
    np.testing.assert_allclose(going.quat, plain.quat, rtol=0, atol=1e-14)
    np.testing.assert_allclose(going.command, plain.command, rtol=0, atol=1e-14)


@pytest.mark.slow
def test_kernel_equals_the_diffrax_path(stopped, last_outside):
    """Fixed steps with jumps: the per-body kernel (Illinois on the step) and Diffrax's event
    (Newton on the interpolant) locate the same crossing; adaptive steps too."""
    event = settling_event(Q_T, TOL, TS[last_outside])
    through = _loop(rj.ExplicitRK(rj.RK4()), event)
    np.testing.assert_allclose(through.event_t, stopped.event_t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(through.quat, stopped.quat, rtol=0, atol=1e-9)
    for b in range(3):  # before the event: the same steps, the same numbers
        k = last_outside[b] + 1
        np.testing.assert_allclose(through.quat[b, :k], stopped.quat[b, :k], rtol=0, atol=1e-13)
        np.testing.assert_allclose(
            through.wheel_speed[b, :k], stopped.wheel_speed[b, :k], rtol=0, atol=1e-13
        )
    tight = dict(rtol=1e-10, atol=1e-10)
    kernel = _loop(None, event, **tight)
    diffrax_path = _loop(rj.ExplicitRK(diffrax.Tsit5()), event, **tight)
    np.testing.assert_allclose(kernel.event_t, diffrax_path.event_t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(kernel.event_t, stopped.event_t, rtol=0, atol=1e-6)  # RK4's error


@pytest.mark.slow
def test_event_time_gradient_is_central_differences(last_outside):
    """d event_t / d Ω0 of the closed loop on the per-body kernel (its derivatives through the
    Diffrax path's events), reverse and forward mode, against central differences."""
    event = settling_event(Q_T, TOL, TS[last_outside[1]])

    def t_event(w):
        tr = rj.simulate(
            SAT, w, None, TS, controller=LAW, control_period=0.25, solver=rj.RK4(),
            event=event, **FIXED,
        )  # fmt: skip
        return tr.event_t

    w = jnp.asarray(W0[1])
    grad = jax.jit(jax.grad(t_event))(w)
    eps, f = 1e-6, jax.jit(t_event)  # one compile for the six differences' solves
    fd = [(f(w + eps * e) - f(w - eps * e)) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(jax.jit(jax.jacfwd(t_event))(w), grad, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_flip_event_on_the_kernel_in_every_mode():
    """`jax.jacfwd` and `jax.jacrev` of a flip time located on the adaptive kernel agree with
    each other and with the closed form's gradient (`analytic.time_of_first_flip`)."""
    w0 = jnp.array([0.05, 1.0, 0.02])

    def t_event(w):
        tight = dict(rtol=1e-12, atol=1e-12)
        return rj.simulate(BODY, w, ts=FLIP_TS, event=flip_event(w), **tight).event_t

    rev, fwd = jax.jacrev(t_event)(w0), jax.jacfwd(t_event)(w0)
    exact = jax.grad(lambda w: rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), w))(w0)
    np.testing.assert_allclose(fwd, rev, rtol=1e-9)
    np.testing.assert_allclose(rev, exact, rtol=1e-6)


@pytest.mark.slow
def test_a_controller_the_kernel_refuses_falls_back_with_one_warning(stopped, last_outside):
    """A law with a data-dependent `while` runs on the Diffrax path (one warning naming it):
    the same states before the event (1e-13) and the same event (to the root finders')."""

    def law(t, w, q, p):
        n = jax.lax.while_loop(lambda c: c < 1 + (w[0] > 10.0), lambda c: c + 1, 0)
        return LAW(t, w, q, p) * n

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = rj.simulate(
            SAT, W0, None, TS, controller=law, control_period=0.25, solver=rj.RK4(),
            event=settling_event(Q_T, TOL, TS[last_outside]), **FIXED,
        )  # fmt: skip
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(messages) == 1 and "`while`" in messages[0], messages
    np.testing.assert_allclose(got.event_t, stopped.event_t, rtol=0, atol=1e-9)
    for b in range(3):
        k = last_outside[b] + 1
        np.testing.assert_allclose(got.quat[b, :k], stopped.quat[b, :k], rtol=0, atol=1e-13)


BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
W = jnp.array([[0.05, 1.0, 0.02], [0.1, 1.2, -0.03], [0.02, -0.9, 0.1]])
FLIP_TS = jnp.linspace(0.0, 12.0, 4)


def test_fixed_step_flip_on_the_kernel_is_the_closed_form():
    options = dict(solver=diffrax.Dopri5(), stepsize_controller=diffrax.ConstantStepSize())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        traj = rj.simulate(BODY, W, ts=FLIP_TS, event=flip_event(W), dt0=0.005, **options)
    exact = rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), W)
    np.testing.assert_allclose(traj.event_t, exact, rtol=0, atol=1e-8)
    assert traj.stats["num_steps"].shape == (3,)
    plain = rj.simulate(BODY, W, ts=FLIP_TS, dt0=0.005, **options)
    for b in range(3):
        k = int(np.argmax(np.asarray(FLIP_TS) > float(traj.event_t[b])))
        np.testing.assert_allclose(traj.omega[b, :k], plain.omega[b, :k], rtol=0, atol=1e-14)
        np.testing.assert_array_equal(
            traj.omega[b, k:], np.broadcast_to(traj.omega[b, k], (4 - k, 3))
        )


@pytest.mark.slow
def test_fixed_step_event_fails_a_body_past_max_steps():
    """max_steps per body: the per-body kernel stops where Diffrax would, with its error."""
    options = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.001)
    with pytest.raises(rj.IntegrationError, match="max_steps"):
        rj.simulate(BODY, W, ts=FLIP_TS, event=flip_event(W), max_steps=100, **options)


@pytest.mark.slow
def test_gyrostat_without_controller_stops_at_its_event():
    """A Zhukovsky–Volterra gyrostat (constant h) at its flip: the quaternion kernel against
    SciPy's DOP853 with its own event location on `I Ω̇ + Ω × (IΩ + h) = 0`, and the
    rotation-vector path (another formulation, the same motion), to the tolerance."""
    g = rj.Gyrostat(jnp.array([1.0, 2.0, 3.0]), h=jnp.array([0.0, 0.01, 0.0]))
    w0 = jnp.array([0.05, 1.0, 0.02])
    tight = dict(rtol=1e-12, atol=1e-12)
    quat = rj.simulate(g, w0, None, FLIP_TS, event=flip_event(w0), **tight)
    rotvec = rj.simulate(g, w0, None, FLIP_TS, kinematics="rotvec", event=flip_event(w0), **tight)
    assert np.isfinite(quat.event_t) and 0 < float(quat.event_t) < 12
    np.testing.assert_allclose(quat.event_t, rotvec.event_t, rtol=0, atol=1e-8)
    k = int(np.argmax(np.asarray(FLIP_TS) > float(quat.event_t)))
    np.testing.assert_allclose(quat.omega[k, 1], 0.0, atol=1e-10)
    I, h = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.01, 0.0])

    def euler(t, w):
        return -np.cross(w, I * w + h) / I

    def flip(t, w):
        return w[1]

    flip.terminal = True
    ref = solve_ivp(euler, (0.0, 12.0), np.asarray(w0), "DOP853", rtol=1e-13, atol=1e-13,
                    events=flip)  # fmt: skip
    np.testing.assert_allclose(quat.event_t, ref.t_events[0][0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(quat.omega[k], ref.y_events[0][0], rtol=0, atol=1e-8)


def test_settling_event_refuses_a_batch_of_targets():
    with pytest.raises(ValueError, match=r"q_target \(4,\)"):
        settling_event(np.tile(Q_T, (2, 1)), TOL)
    with pytest.raises(ValueError, match="scalar tolerance"):
        settling_event(Q_T, [TOL, TOL])
    with pytest.raises(ValueError, match="q_target is a zero quaternion"):
        settling_event(np.zeros(4), TOL)
