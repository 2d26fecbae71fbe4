"""The adaptive CPU kernel (`rigidjax.kernels.adaptive`, the default `simulate` at a tolerance)
against the Diffrax path of each body alone (`ExplicitRK(method)` under `jax.vmap`, which never
takes a kernel): the same steps and values, each body its own steps, gradients against the
Diffrax path's and central differences, failures per body."""

import shutil

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.kernels import _build
from rigidjax.solvers import ExplicitRK

pytestmark = pytest.mark.skipif(
    shutil.which(_build._compiler()[0]) is None, reason="no C++ compiler ($CXX or c++)"
)

BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
TS = jnp.linspace(0.0, 2.0, 5)
TOL = dict(rtol=1e-8, atol=1e-8)
COUNTS = ("num_steps", "num_accepted_steps", "num_rejected_steps")


def pd_torque(t, w, q):
    """An attitude torque: proportional–derivative toward the identity."""
    return -0.4 * q[0] * q[1:] - 0.2 * w


def _inputs(B, seed=0):
    """Spread rates: |Ω| log-uniform in 0.1–3 rad/s, random attitudes."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(B, 3))
    w *= (
        np.exp(rng.uniform(np.log(0.1), np.log(3.0), size=(B, 1)))
        / np.linalg.norm(w, axis=1)[:, None]
    )
    q = rng.normal(size=(B, 4))
    return jnp.asarray(w), jnp.asarray(q / np.linalg.norm(q, axis=1)[:, None])


def _each(w, q, torque=None, method=diffrax.Tsit5, body=BODY, **kw):
    """The Diffrax path, one body at a time (`jax.vmap`: each its own steps)."""

    def one(w, q):
        return rj.simulate(body, w, q, TS, torque, solver=ExplicitRK(method()), **TOL, **kw)

    return jax.vmap(one)(w, q)


@pytest.mark.parametrize("torque", [None, pd_torque], ids=["free", "pd"])
@pytest.mark.parametrize("method", [diffrax.Tsit5, diffrax.Dopri5])
def test_kernel_takes_the_diffrax_paths_steps(method, torque):
    w, q = _inputs(5)
    fast = rj.simulate(BODY, w, q, TS, torque, solver=method(), **TOL)
    slow = _each(w, q, torque, method)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=1e-13)
    for key in COUNTS:
        np.testing.assert_array_equal(fast.stats[key], slow.stats[key])
    assert fast.stats["num_steps"].shape == (5,)
    assert fast.result == diffrax.RESULTS.successful


@pytest.mark.slow
@pytest.mark.parametrize("method", [diffrax.Bosh3, diffrax.Dopri8])
def test_other_pairs_take_the_diffrax_paths_steps(method):
    w, q = _inputs(3, seed=1)
    fast = rj.simulate(BODY, w, q, TS, pd_torque, solver=method(), **TOL)
    slow = _each(w, q, pd_torque, method)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fast.stats["num_steps"], slow.stats["num_steps"])


def test_a_body_is_the_same_alone_and_in_any_batch():
    """Each body its own steps: the batch's values are each body's alone, bit for bit (67: a
    full block of 64 bodies and a partial one), and `jax.vmap(simulate)`'s."""
    w, q = _inputs(67, seed=2)
    batch = rj.simulate(BODY, w, q, TS, **TOL)
    for i in (0, 40, 66):
        alone = rj.simulate(BODY, w[i], q[i], TS, **TOL)
        np.testing.assert_array_equal(alone.omega, batch.omega[i])
        np.testing.assert_array_equal(alone.quat, batch.quat[i])
        assert int(alone.stats["num_steps"]) == int(batch.stats["num_steps"][i])
    mapped = jax.vmap(lambda w, q: rj.simulate(BODY, w, q, TS, **TOL))(w, q)
    np.testing.assert_array_equal(mapped.omega, batch.omega)
    # the step counts differ between bodies (each its own)
    assert len(set(np.asarray(batch.stats["num_steps"]).tolist())) > 5


def test_controller_options_reach_the_kernel():
    """`dt0` (the first step), `dtmax` and the PID coefficients give the Diffrax path's steps."""
    w, q = _inputs(3, seed=3)
    pid = diffrax.PIDController(rtol=1e-7, atol=1e-9, pcoeff=0.1, icoeff=0.4, dtmax=0.05)
    kw = dict(stepsize_controller=pid, dt0=0.01)
    fast = rj.simulate(BODY, w, q, TS, solver=diffrax.Tsit5(), **kw)
    slow = jax.vmap(
        lambda w, q: rj.simulate(BODY, w, q, TS, solver=ExplicitRK(diffrax.Tsit5()), **kw)
    )(w, q)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fast.stats["num_steps"], slow.stats["num_steps"])


@pytest.mark.slow  # (a minute of compiling)
def test_gradients_match_the_diffrax_path_and_differences():
    """Reverse mode through the kernel's adjoint of the accepted steps: the moments, Ω0 and a
    torque gain closed over, against the Diffrax path (1e-9) and central differences."""
    w, q = _inputs(3, seed=4)

    def loss(I, w0, gain, solver):
        def torque(t, om, qq):
            return -gain * qq[0] * qq[1:] - 0.2 * om

        traj = rj.simulate(rj.RigidBody(I), w0, q, TS, torque, solver=solver, **TOL)
        return jnp.sum(traj.omega[:, -1] ** 2) + jnp.sum(traj.quat[:, -1, 1:] * 0.3)

    args = (jnp.array([1.2, 2.0, 3.0]), w, jnp.asarray(0.4))
    fast = jax.grad(loss, argnums=(0, 1, 2))(*args, diffrax.Tsit5())

    def each(I, w0, gain):  # the Diffrax path: one body at a time, each its own steps
        def one(wi, qi):
            def torque(t, om, qq):
                return -gain * qq[0] * qq[1:] - 0.2 * om

            traj = rj.simulate(rj.RigidBody(I), wi, qi, TS, torque, solver=ExplicitRK(), **TOL)
            return jnp.sum(traj.omega[-1] ** 2) + jnp.sum(traj.quat[-1, 1:] * 0.3)

        return jnp.sum(jax.vmap(one)(w0, q))

    slow = jax.grad(each, argnums=(0, 1, 2))(*args)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-11)
    eps = 1e-6
    e = jnp.array([0.0, 1.0, 0.0]) * eps
    diff = (
        loss(args[0] + e, *args[1:], diffrax.Tsit5())
        - loss(args[0] - e, *args[1:], diffrax.Tsit5())
    ) / (2 * eps)
    np.testing.assert_allclose(fast[0][1], diff, rtol=1e-5)


@pytest.mark.slow  # (a minute of compiling)
def test_output_times_are_differentiated_through_diffrax():
    w, q = _inputs(2, seed=5)

    def loss(ts, solver):
        return jnp.sum(rj.simulate(BODY, w, q, ts, solver=solver, **TOL).omega[:, -1] ** 2)

    fast = jax.grad(loss)(TS, diffrax.Tsit5())
    slow = jax.grad(loss)(TS, ExplicitRK())  # a batch as one state: other steps, same limit
    np.testing.assert_allclose(fast, slow, rtol=1e-6, atol=1e-7)


def test_max_steps_and_failures_are_per_body():
    """A fast body that needs more than `max_steps` steps in an interval fails alone: the slow
    body's states are its own solve's; the batch's result names the first failure."""
    w = jnp.array([[0.05, 0.02, 0.01], [8.0, 6.0, 5.0]])
    q = jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0]), (2, 1))
    traj = rj.simulate(BODY, w, q, TS, max_steps=30, throw=False, **TOL)
    alone = rj.simulate(BODY, w[0], q[0], TS, max_steps=30, **TOL)
    np.testing.assert_array_equal(traj.omega[0], alone.omega)
    assert traj.result == diffrax.RESULTS.max_steps_reached
    fast = rj.simulate(BODY, w[1], q[1], TS, max_steps=30, throw=False, solver=ExplicitRK(), **TOL)
    assert fast.result == diffrax.RESULTS.max_steps_reached
    assert int(traj.stats["num_valid"]) == int(fast.stats["num_valid"]) < TS.shape[0]
    with pytest.raises(rj.IntegrationError, match="failed for body 1 of 2 .*max_steps"):
        rj.simulate(BODY, w, q, TS, max_steps=30, **TOL)


@pytest.mark.slow  # (a minute of compiling)
def test_a_full_tensor_runs_on_the_kernels():
    """A body not in principal axes (a rotated tensor, as CAD gives it) is a model of the
    kernels (fixed and adaptive steps): its motion is the principal-axes body's, rotated, and
    its adaptive steps the Diffrax path's."""
    from scipy.spatial.transform import Rotation

    w, q = _inputs(3, seed=6)
    R = jnp.asarray(Rotation.random(random_state=7).as_matrix())
    r = jnp.asarray(Rotation.from_matrix(np.asarray(R)).as_quat(scalar_first=True))
    tensor = rj.RigidBody(R @ jnp.diag(jnp.array([1.2, 2.0, 3.0])) @ R.T)
    wt, qt = w @ R.T, rj.quat.mul(q, rj.quat.conj(r))  # the same motion in the rotated axes
    principal = rj.RigidBody(jnp.array([1.2, 2.0, 3.0]))
    for kw in (dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01), TOL):
        ref = rj.simulate(principal, w, q, TS, solver=diffrax.Tsit5(), **kw)
        got = rj.simulate(tensor, wt, qt, TS, solver=diffrax.Tsit5(), **kw)
        np.testing.assert_allclose(got.omega, ref.omega @ R.T, rtol=0, atol=1e-7)
    slow = _each(wt, qt, body=tensor)
    np.testing.assert_allclose(got.omega, slow.omega, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.stats["num_steps"], slow.stats["num_steps"])


@pytest.mark.slow  # (a minute of compiling)
def test_events_are_located_on_the_kernel():
    """The first flip as an event on the adaptive kernel: its time is the closed form's to
    1e-8; with `terminate` the state is held at the event, without it the motion goes on as
    if there were none; the Diffrax path's event agrees; its gradient (through the Diffrax
    path's event) is the closed form's."""
    from rigidjax.events import flip_event

    rng = np.random.default_rng(8)
    w = jnp.asarray(
        np.stack([0.2 * rng.uniform(-1, 1, 3), np.ones(3), 0.2 * rng.uniform(-1, 1, 3)], 1)
    )
    I = jnp.array([1.0, 2.0, 3.0])
    ts = jnp.linspace(0.0, 20.0, 5)
    tight = dict(rtol=1e-12, atol=1e-12)
    exact = jax.vmap(lambda w0: rj.analytic.time_of_first_flip(I, w0))(w)
    held = rj.simulate(rj.RigidBody(I), w, None, ts, event=flip_event(w), **tight)
    np.testing.assert_allclose(held.event_t, exact, rtol=0, atol=1e-8)
    after = ts[None, :] > held.event_t[:, None]
    np.testing.assert_allclose(jnp.where(after, held.omega[..., 1], 0.0), 0.0, atol=1e-9)
    going = rj.simulate(rj.RigidBody(I), w, None, ts, event=flip_event(w, terminate=False), **tight)
    plain = rj.simulate(rj.RigidBody(I), w, None, ts, **tight)
    # (to rounding: the kernel with the event condition is another build of the same steps)
    np.testing.assert_allclose(going.omega, plain.omega, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(going.stats["num_steps"], plain.stats["num_steps"])
    np.testing.assert_allclose(going.event_t, exact, rtol=0, atol=1e-8)
    through = rj.simulate(
        rj.RigidBody(I), w, None, ts, event=flip_event(w), solver=ExplicitRK(), **tight
    )
    np.testing.assert_allclose(held.event_t, through.event_t, rtol=0, atol=1e-9)

    def first(w0):
        return rj.simulate(rj.RigidBody(I), w0, None, ts, event=flip_event(w0), **tight).event_t

    grad = jax.grad(first)(w[0])
    np.testing.assert_allclose(
        grad, jax.grad(rj.analytic.time_of_first_flip, 1)(I, w[0]), rtol=1e-6
    )


@pytest.mark.slow  # (a minute of compiling)
def test_eigenaxis_slew_switching_time():
    """A rest-to-rest eigenaxis slew by θ about the principal axis e under the constant torque
    K0 e turns by φ(t) = K0 t² / (2 I_e): its switch at φ = θ/2 is t_s = √(θ I_e / K0). As an
    event of the attitude (rising), on the kernel and through Diffrax, to 1e-8."""
    I, K0, theta = jnp.array([1.0, 2.0, 3.0]), 0.1, 1.0

    def torque(t, w, q):
        return jnp.array([0.0, K0, 0.0]) + 0.0 * w

    def half_way(t, w, q):  # the angle turned, minus θ/2
        return 2 * jnp.arctan2(jnp.sqrt(jnp.sum(q[1:] ** 2)), q[0]) - theta / 2

    event = rj.Event(half_way, direction=1)
    switch = np.sqrt(theta * 2.0 / K0)
    ts = jnp.linspace(0.0, 10.0, 3)
    for solver in (diffrax.Tsit5(), ExplicitRK()):
        traj = rj.simulate(
            rj.RigidBody(I), jnp.zeros(3), None, ts, torque, event=event, solver=solver,
            rtol=1e-12, atol=1e-12,
        )  # fmt: skip
        np.testing.assert_allclose(traj.event_t, switch, rtol=0, atol=1e-8)
        np.testing.assert_allclose(traj.omega[-1], [0.0, K0 * switch / 2.0, 0.0], atol=1e-8)


@pytest.mark.slow  # (a minute of compiling)
def test_the_adaptive_kernel_composes_with_jax():
    """The default adaptive `simulate` with a torque on the kernel under `jit` on captured
    constants, in a `lax.scan` body, under `vmap`, `jacfwd` and `jacrev` (against each other and
    central differences), and a torque the kernel refuses (`while`): the Diffrax path's values."""
    I, w0 = jnp.array([1.2, 2.0, 3.0]), jnp.array([0.3, 1.0, -0.2])
    q0 = jnp.array([0.9, 0.1, -0.2, 0.3]) / jnp.linalg.norm(jnp.array([0.9, 0.1, -0.2, 0.3]))
    tight = dict(rtol=1e-10, atol=1e-10)

    def final(w, torque=pd_torque, **kw):
        return rj.simulate(rj.RigidBody(I), w, q0, TS, torque, **tight, **kw).omega[-1]

    ref = final(w0, solver=ExplicitRK())
    np.testing.assert_allclose(final(w0), ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose(jax.jit(lambda: final(w0))(), ref, rtol=0, atol=1e-13)
    scanned = jax.lax.scan(lambda c, w: (c, final(w)), 0, w0[None])[1][0]
    np.testing.assert_allclose(scanned, ref, rtol=0, atol=1e-13)
    mapped = jax.vmap(final)(jnp.stack([w0, 0.5 * w0]))[0]
    np.testing.assert_allclose(mapped, ref, rtol=0, atol=1e-13)
    forward, reverse = jax.jacfwd(final)(w0), jax.jacrev(final)(w0)
    np.testing.assert_allclose(forward, reverse, rtol=0, atol=1e-12)
    eps = 1e-6
    diff = jnp.stack(
        [(final(w0 + eps * e) - final(w0 - eps * e)) / (2 * eps) for e in jnp.eye(3)], 1
    )
    np.testing.assert_allclose(reverse, diff, rtol=0, atol=1e-8)

    def looped(t, w, q):  # a `while` loop: no scalar form, the Diffrax path with one warning
        x = jax.lax.while_loop(lambda c: c[0] < 2, lambda c: (c[0] + 1, c[1] * 1.0), (0, w))[1]
        return pd_torque(t, x, q)

    with pytest.warns(RuntimeWarning, match="`while`"):
        refused = final(w0, looped)
    np.testing.assert_allclose(refused, ref, rtol=0, atol=1e-13)
