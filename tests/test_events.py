"""Adaptive batches per body, and events (`rigidjax.Event`, `simulate(..., event=...)`)."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.events import flip_event
from tests.rotations.test_bad_input import raises_in_jit

BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
TIGHT = rj.SolveOptions(rtol=1e-12, atol=1e-12)
# near the intermediate axis: each flips, at different times
W = jnp.array([[0.05, 1.0, 0.02], [0.1, 1.2, -0.03], [0.02, -0.9, 0.1]])
TS = jnp.linspace(0.0, 12.0, 4)


def _event_t(traj: rj.Trajectory) -> np.ndarray:
    assert traj.event_t is not None
    return np.asarray(traj.event_t)


def _torque(t, w, q):
    return 0.1 * jnp.cross(w, jnp.array([0.0, 0.0, 1.0])) + 0.05 * q[1:]


def _sin_plus_half(t, w, q):
    """For a spin Ω = e_z at 1 rad/s from the identity: `sin t + ½`, zeros at 7π/6 (falling)
    and 11π/6 (rising)."""
    del t, w
    return rj.quat.rotate(q, jnp.array([1.0, 0.0, 0.0]))[1] + 0.5


@pytest.mark.slow
def test_flip_event_is_the_closed_form_and_holds_the_state():
    traj = rj.simulate(BODY, W, ts=TS, event=flip_event(W), options=TIGHT)
    exact = rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), W)
    np.testing.assert_allclose(_event_t(traj), exact, rtol=0, atol=1e-8)
    assert _event_t(traj).shape == (3,) and traj.stats["num_steps"].shape == (3,)
    for b in range(3):
        after = np.asarray(TS) > _event_t(traj)[b]
        assert after.sum() >= 1  # every body flips before the last output time
        k = int(np.argmax(after))  # the first output after the event: the state at it
        np.testing.assert_array_equal(
            traj.omega[b, k:], np.broadcast_to(traj.omega[b, k], (4 - k, 3))
        )
        np.testing.assert_array_equal(
            traj.quat[b, k:], np.broadcast_to(traj.quat[b, k], (4 - k, 4))
        )
        assert abs(float(traj.omega[b, k, 1])) < 1e-9  # Ω·e_d = 0 at the event
        np.testing.assert_allclose(np.linalg.norm(traj.quat[b, k]), 1.0, atol=1e-14)


@pytest.mark.parametrize(
    "kinematics",
    [
        "matrix",
        pytest.param("cayley_klein", marks=pytest.mark.slow),
        pytest.param("euler", marks=pytest.mark.slow),
        pytest.param("rotvec", marks=pytest.mark.slow),
    ],
)
def test_flip_event_of_a_batch_in_every_chart(kinematics):
    """The event reads each body's state in the chart's own components (a matrix `(3, 3)`,
    Cayley–Klein `(2, 2, 2)`); a batched solve also evaluates lanes it discards, with zero
    states, which must not trip the checks meant for user input."""
    traj = rj.simulate(BODY, W, ts=TS, kinematics=kinematics, event=flip_event(W), options=TIGHT)
    exact = rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), W)
    np.testing.assert_allclose(_event_t(traj), exact, rtol=0, atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(traj.quat, axis=-1), 1.0, atol=1e-13)


def test_direction_filters_the_crossings():
    w0 = jnp.array([0.0, 0.0, 1.0])
    ts = jnp.linspace(0.0, 7.0, 3)
    rising = rj.simulate(
        BODY, w0, ts=ts, event=rj.Event(_sin_plus_half, direction=1), options=TIGHT
    )
    np.testing.assert_allclose(_event_t(rising), 11 * np.pi / 6, atol=1e-9)
    # zero at t0 is on the ≤ 0 side (as Diffrax's events): leaving it upward is a rising
    # crossing at t0 (the docstring said it did not count); the kernel and Diffrax agree
    for kinematics in ("quat", "matrix"):
        at_start = rj.simulate(
            BODY, w0, ts=ts, event=rj.Event(lambda t, w, q: t, direction=1), kinematics=kinematics
        )
        np.testing.assert_allclose(_event_t(at_start), 0.0, atol=1e-12)
        np.testing.assert_array_equal(at_start.omega, jnp.broadcast_to(w0, (3, 3)))


def test_float32_event_on_the_diffrax_path():
    """float32 under x64 on the Diffrax path (another chart): Diffrax's root find selected the
    float32 condition against a float64 zero, a type error; now float32, as the kernel's."""
    f32 = jnp.float32
    body, w = rj.RigidBody(BODY.inertia.astype(f32)), W[0].astype(f32)
    traj = rj.simulate(body, w, ts=TS.astype(f32), kinematics="matrix", event=flip_event(w))
    exact = rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), W[0])
    assert traj.event_t.dtype == f32 and traj.omega.dtype == f32
    np.testing.assert_allclose(traj.event_t, exact, rtol=1e-5)


@pytest.mark.slow
def test_falling_and_either_direction():
    w0 = jnp.array([0.0, 0.0, 1.0])
    ts = jnp.linspace(0.0, 7.0, 3)
    for direction in (-1, None):
        ev = rj.Event(_sin_plus_half, direction=direction)
        traj = rj.simulate(BODY, w0, ts=ts, event=ev, options=TIGHT)
        np.testing.assert_allclose(_event_t(traj), 7 * np.pi / 6, atol=1e-9)


@pytest.mark.slow
def test_terminate_false_records_the_time_and_keeps_integrating():
    w0 = jnp.array([0.0, 0.0, 1.0])
    ts = jnp.linspace(0.0, 7.0, 3)
    plain = rj.simulate(BODY, w0, ts=ts, kinematics="rotvec", options=TIGHT)
    event = rj.Event(_sin_plus_half, terminate=False)
    going = rj.simulate(BODY, w0, ts=ts, kinematics="rotvec", event=event, options=TIGHT)
    np.testing.assert_allclose(_event_t(going), 7 * np.pi / 6, atol=1e-9)
    np.testing.assert_array_equal(going.quat, plain.quat)  # the same steps: the same states
    np.testing.assert_array_equal(going.omega, plain.omega)


@pytest.mark.slow
def test_event_on_the_geometric_path_holds_the_state():
    w0 = jnp.array([0.0, 0.0, 1.0])
    ts = jnp.linspace(0.0, 7.0, 3)
    traj = rj.simulate(
        BODY, w0, ts=ts, kinematics="geometric", event=rj.Event(_sin_plus_half), options=TIGHT
    )
    t = 7 * np.pi / 6
    np.testing.assert_allclose(_event_t(traj), t, atol=1e-9)
    held = jnp.array([np.cos(t / 2), 0.0, 0.0, np.sin(t / 2)])
    np.testing.assert_allclose(rj.quat.canonical(traj.quat[-1]), rj.quat.canonical(held), atol=1e-9)


def test_bad_events_are_clear_errors():
    for bad in (0, 2, "up", True):
        with pytest.raises(ValueError, match=r"direction must be None .*\+1 .*-1"):
            rj.Event(_sin_plus_half, direction=bad)
    with pytest.raises(TypeError, match="condition must be a callable"):
        rj.Event(1.0)
    with pytest.raises(TypeError, match="terminate must be True or False"):
        rj.Event(_sin_plus_half, terminate="yes")
    with pytest.raises(TypeError, match="event must be a rigidjax.Event"):
        rj.simulate(BODY, W[0], ts=TS, event=_sin_plus_half)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="events need a solver with an interpolant"):
        rj.simulate(BODY, W[0], ts=TS, event=flip_event(W[0]), solver=rj.ExactFreeBody())
    with pytest.raises(ValueError, match=r"lead with the batch shape \(2,\)"):
        rj.simulate(BODY, W[:2], ts=TS, event=flip_event(W))


def _nan_above(t, w, q):
    """NaN where |Ω₂| > 1.1: of the batch `W`, only the second body's start."""
    del t, q
    return jnp.sqrt(1.1 - jnp.abs(w[1]))


def test_a_condition_not_finite_at_the_start_is_named():
    """A NaN condition never changes sign: `event_t` came back `inf` without a word."""
    nan = rj.Event(_nan_above)
    with pytest.raises(ValueError, match=r"condition\(t, omega, q\) is not finite at the initial"):
        rj.simulate(BODY, W[1], ts=TS, event=nan)
    with pytest.raises(ValueError, match=r"initial state \(body 1 of 3: nan\); it would never"):
        rj.simulate(BODY, W, ts=TS, event=nan)
    gyrostat = rj.Gyrostat(BODY.inertia, jnp.zeros(3))
    with pytest.raises(ValueError, match=r"initial state \(body 1 of 3: nan\)"):
        rj.simulate(gyrostat, W, ts=TS, event=nan)
    with raises_in_jit("the Event's condition"):
        jax.block_until_ready(jax.jit(lambda w: rj.simulate(BODY, w, ts=TS, event=nan).omega)(W))
    # a condition that returns a Python constant (no array: `filter_vmap` left it unbatched,
    # and the check passed it over)
    constant = rj.Event(lambda t, w, q: float("nan"))
    for w0 in (W[0], W):
        with pytest.raises(ValueError, match=r"not finite at the initial state \((the )?body"):
            rj.simulate(BODY, w0, ts=TS, event=constant)


@pytest.mark.slow
def test_event_under_jit_vmap_and_grad():
    ts = jnp.linspace(0.0, 12.0, 3)

    def flip_time(w, inertia):
        body = rj.RigidBody(inertia)
        t = rj.simulate(body, w, ts=ts, event=flip_event(w), options=TIGHT).event_t
        assert t is not None
        return t

    inertia = BODY.inertia.diagonal()
    exact = rj.analytic.time_of_first_flip(inertia, W[:2])
    np.testing.assert_allclose(jax.jit(flip_time)(W[0], inertia), exact[0], atol=1e-8)
    np.testing.assert_allclose(jax.vmap(flip_time, (0, None))(W[:2], inertia), exact, atol=1e-8)
    grads = jax.grad(flip_time, argnums=(0, 1))(W[0], inertia)
    exact_grads = jax.grad(rj.analytic.time_of_first_flip, argnums=(1, 0))(inertia, W[0])
    for g, e in zip(grads, exact_grads, strict=True):
        np.testing.assert_allclose(g, e, rtol=1e-6, atol=1e-6)


def _batch_alone_vmap(atol: float, kinematics: str = "quat", solver=None):
    """A batch of two bodies (each its own moments) under a torque: the same as each alone and
    as `jax.vmap(simulate)`, with per-body step counts."""
    inertia = jnp.array([[1.0, 2.0, 3.0], [1.5, 1.0, 2.5]])
    w0 = jnp.array([[0.05, 1.0, 0.02], [3.0, -0.2, 0.5]])
    ts = jnp.linspace(0.0, 3.0, 4)

    def sim(inertia, w):
        body = rj.RigidBody(inertia)
        options = rj.SolveOptions(rtol=1e-9, atol=1e-9, solver=solver)
        return rj.simulate(body, w, ts=ts, torque=_torque, kinematics=kinematics, options=options)

    batch = sim(inertia, w0)
    mapped = jax.vmap(sim)(inertia, w0)
    np.testing.assert_allclose(batch.omega, mapped.omega, rtol=0, atol=1e-14)
    np.testing.assert_allclose(batch.quat, mapped.quat, rtol=0, atol=1e-14)
    for b in range(2):
        alone = sim(inertia[b], w0[b])
        np.testing.assert_allclose(batch.omega[b], alone.omega, rtol=0, atol=atol)
        np.testing.assert_allclose(batch.quat[b], alone.quat, rtol=0, atol=atol)
        for key in ("num_steps", "num_accepted_steps", "num_rejected_steps"):
            assert int(batch.stats[key][b]) == int(alone.stats[key]) == int(mapped.stats[key][b])
    assert batch.stats["num_steps"].shape == (2,)
    assert batch.stats["num_steps"][0] != batch.stats["num_steps"][1]  # their own steps
    assert batch.successful


@pytest.mark.slow  # ~50 s and ~70 s: the compiles of jacfwd, jacrev and the differences
@pytest.mark.parametrize("steps", ["fixed", "adaptive"])
def test_forward_mode_through_a_per_body_event_and_a_torque_gain(steps):
    """`jax.jacfwd` of the flip times of a per-body event (each body its own arrays, under the
    bodies' `jax.vmap`) w.r.t. a gain the torque closes over, on the per-body CPU kernel: the
    same as `jax.jacrev`, and (fixed steps) central differences. Forward mode used to trace
    the event's arrays again outside that `jax.vmap` (an UnexpectedTracerError)."""
    if steps == "fixed":
        kw = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01, solver=rj.RK4())
    else:
        kw = dict(rtol=1e-10, atol=1e-10)
    w = W[:2]

    def flips(g):
        damped = rj.simulate(
            BODY, w, ts=TS, event=flip_event(w), torque=lambda t, o, q: -g * o, **kw
        )
        return damped.event_t

    g0 = jnp.asarray(0.01)
    fwd, rev = jax.jacfwd(flips)(g0), jax.jacrev(flips)(g0)
    assert np.all(np.isfinite(np.asarray(fwd))) and np.all(np.abs(np.asarray(fwd)) > 1.0)
    np.testing.assert_allclose(fwd, rev, rtol=1e-9)
    if steps == "fixed":
        f, eps = jax.jit(flips), 1e-5
        np.testing.assert_allclose(fwd, (f(g0 + eps) - f(g0 - eps)) / (2 * eps), rtol=1e-6)


@pytest.mark.slow  # ~15-25 s each: the compiles of jax.grad and jax.jacfwd
@pytest.mark.parametrize("backend", ["adaptive", "fixed", "pallas"])
def test_derivatives_wrt_a_value_the_condition_closes_over(backend, monkeypatch):
    """`event_t` differentiated w.r.t. a threshold `c` the condition closes over: a spin about
    e_z at 1 rad/s from the identity, `sin t + c` falling through zero at `t* = π + asin c`,
    so `dt*/dc = 1/√(1 − c²)` (a closed form), by `jax.grad` and `jax.jacfwd` on the CPU
    kernels (adaptive, and fixed steps per body) and the adaptive Pallas kernel (interpreted).
    The kernels' rules closed over the condition's arrays (an UnexpectedTracerError)."""
    if backend == "pallas":
        import rigidjax.kernels.model_pallas_adaptive as pa
        from rigidjax.kernels import adaptive

        monkeypatch.setattr(adaptive, "build", lambda *args, **kwargs: None)
        monkeypatch.setattr(
            pa, "serves", lambda h, u, solver, *_: type(solver) in pa.tableau.ADAPTIVE
        )
    if backend == "fixed":
        kw = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01, solver=rj.RK4())
    else:
        kw = dict(options=TIGHT)
    w0, ts = jnp.array([0.0, 0.0, 1.0]), jnp.linspace(0.0, 5.0, 3)

    def crossing(c):
        def condition(t, w, q):
            return rj.quat.rotate(q, jnp.array([1.0, 0.0, 0.0]))[1] + c

        return rj.simulate(BODY, w0, ts=ts, event=rj.Event(condition, direction=-1), **kw).event_t

    c = jnp.asarray(0.5)
    np.testing.assert_allclose(crossing(c), np.pi + np.arcsin(0.5), atol=1e-9)
    exact = 1.0 / np.sqrt(1.0 - 0.5**2)
    rev, fwd = jax.grad(crossing)(c), jax.jacfwd(crossing)(c)
    np.testing.assert_allclose(rev, exact, rtol=1e-8)
    np.testing.assert_allclose(fwd, rev, rtol=1e-10)


@pytest.mark.slow
def test_adaptive_batch_is_each_body_alone_quaternion():
    _batch_alone_vmap(1e-12, solver=rj.ExplicitRK())


@pytest.mark.slow
def test_adaptive_batch_is_each_body_alone_geometric():
    _batch_alone_vmap(1e-12, kinematics="geometric")


@pytest.mark.slow
def test_adaptive_batch_is_each_body_alone_rotvec():
    # the same steps; the rotation vector's field (trigonometric coefficients, a matrix
    # product) rounds differently in XLA's code for one body and for a vectorised batch
    # (measured: 2e-12 apart after 3 s at rtol 1e-9), where the other paths agree to 1e-14
    _batch_alone_vmap(1e-11, kinematics="rotvec")
