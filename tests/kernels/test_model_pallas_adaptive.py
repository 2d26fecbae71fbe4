"""The adaptive Pallas kernel (the GPU fast path at a tolerance: each body its own steps of an
embedded pair under Diffrax's PIDController), run in Pallas' interpreter on the CPU, against the
adaptive CPU kernel and the Diffrax path of one body mapped over the bodies (`ExplicitRK`, which
never takes a kernel); its wiring into `simulate` with the backend's choice forced to it; and
its lowering to Triton for CUDA, on a machine without a GPU."""

import functools
import re
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.kernels import adaptive
from rigidjax.kernels import model as model_kernel
from rigidjax.kernels import model_pallas as pk
from rigidjax.kernels import model_pallas_adaptive as pa
from rigidjax.kernels import model_pallas_adaptive_back as pab
from rigidjax.mechanics._rigid_model import moments_params, rigid_body_model
from rigidjax.solvers import ExplicitRK
from tests.kernels.held import Q_T, closed_loop, held, sample_law

TS = jnp.asarray([0.0, 0.5, 0.7, 2.0])
TOL = dict(rtol=1e-8, atol=1e-8)
E_Z = jnp.array([0.0, 0.0, 1.0])


def _bodies(B, seed=0):
    """Random attitudes, |Ω| log-uniform in 0.14–2.7 rad/s (spread step sizes), per-body
    moments."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(B, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    w = rng.normal(size=(B, 3)) * np.exp(rng.uniform(-2, 1, size=(B, 1)))
    return jnp.asarray(rng.uniform(1.5, 2.5, size=(B, 3))), jnp.asarray(w), jnp.asarray(q)


def _run(method, I, w, q, ts=TS, max_steps=4096, dtype=jnp.float64):
    model = rigid_body_model(None)
    hoisted = model_kernel.hoist(model.field, model.size, model.params, dtype)
    spec = pk.Spec(hoisted, model.unit, method)
    ctl = adaptive.controls(diffrax.PIDController(**TOL), method(), None, max_steps, dtype)
    assert ctl is not None
    y0 = jnp.concatenate([w, q], axis=1).astype(dtype)
    return pa.run(spec, y0, moments_params(I).T.astype(dtype), ts, ctl, interpret=True)


@pytest.mark.parametrize(
    "method",
    [pytest.param(m, marks=pytest.mark.slow) for m in (diffrax.Tsit5, diffrax.Dopri5)],  # ~15 s
    ids=lambda m: m.__name__,
)
def test_kernel_equals_cpu_kernel_and_diffrax_path(method):
    """Two blocks of bodies (one partial, padded) with spread rates and moments: each body's
    states and step counts those of the adaptive CPU kernel and of the Diffrax path (the same
    steps, to rounding: measured 4.4e-15), and a body alone the same bits as in the batch."""
    B = pk.BLOCK + 5
    I, w, q = _bodies(B)
    ys, _, st = _run(method, I, w, q)
    assert ys.shape == (B, 4, 7) and st.shape == (B, 5)
    kw = dict(solver=method(), **TOL)
    cpu = rj.simulate(rj.RigidBody(I), w, q, TS, **kw)
    path = rj.simulate(rj.RigidBody(I), w, q, TS, **{**kw, "solver": ExplicitRK(method())})
    for want in (cpu, path):
        np.testing.assert_allclose(ys[..., :3], want.omega, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ys[..., 3:], want.quat, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(st[:, 0], want.stats["num_steps"])
        np.testing.assert_array_equal(st[:, 1], want.stats["num_accepted_steps"])
    assert np.ptp(np.asarray(st[:, 1])) > 5  # the bodies' own step counts, not the batch's
    np.testing.assert_array_equal(st[:, 3:], np.tile([4, 0], (B, 1)))
    alone, _, st_alone = _run(method, I[B - 1 :], w[B - 1 :], q[B - 1 :])
    np.testing.assert_array_equal(alone[0], ys[B - 1])
    np.testing.assert_array_equal(st_alone[0], st[B - 1])


@pytest.mark.slow  # ~7 s: Pallas' interpreter
def test_float32_max_steps_and_nonfinite():
    """float32 within its rounding of float64; `max_steps` reached per body and interval (the
    later output times not reached, the body's code 1); a non-finite initial state: code 2,
    not integrated (its attempts 0)."""
    I, w, q = _bodies(3, seed=1)
    y64, *_ = _run(diffrax.Tsit5, I, w, q)
    y32, _, st32 = _run(diffrax.Tsit5, I, w, q, dtype=jnp.float32)
    assert y32.dtype == jnp.float32 and np.all(st32[:, 4] == 0)
    np.testing.assert_allclose(y32, y64, rtol=0, atol=2e-5)
    fast = jnp.asarray([[0.1, 0.2, 0.3], [5.0, -4.0, 3.0], [np.nan, 0.0, 0.0]])
    *_, st = _run(diffrax.Tsit5, I, fast, q, max_steps=12)
    assert st[0, 4] == 0 and st[0, 3] == 4  # slow: done within 12 an interval
    assert st[1, 4] == 1 and st[1, 3] < 4 and st[1, 0] >= 12  # fast: max_steps reached
    assert st[2, 4] == 2 and st[2, 3] == 1 and st[2, 0] == 0


@pytest.fixture
def on_gpu_adaptive(monkeypatch):
    """`simulate` at a tolerance as on a GPU: no CPU kernel, and the adaptive Pallas kernel
    served for its pairs (run in Pallas' interpreter here)."""
    monkeypatch.setattr(adaptive, "build", lambda *args, **kwargs: None)
    monkeypatch.setattr(
        pa, "serves", lambda hoisted, unit, solver, *_: type(solver) in pa.tableau.ADAPTIVE
    )


def _torque(gain):
    def torque(t, w, q):
        c = rj.quat.to_matrix(q).T @ E_Z
        return gain * jnp.cross(c, jnp.array([1.0, 2.0, 3.0]) * c) - 0.1 * jnp.sin(t) * w

    return torque


@pytest.mark.slow  # ~50 s: the interpreter, the gradient's compile
def test_torque_through_adaptive_gpu_kernel(on_gpu_adaptive):
    """`simulate` at a tolerance with a torque (attitude, traced gain, time-dependent) takes the
    adaptive Pallas kernel: the Diffrax path's trajectory and per-body step counts; a body under
    `jax.vmap` the batch's; the reverse-mode derivatives w.r.t. the gain and an output time
    (through the Diffrax path) equal central differences of the kernel's own values."""
    I, w, q = _bodies(4, seed=2)

    def run(g, ts, solver=None):
        return rj.simulate(rj.RigidBody(I), w, q, ts, torque=_torque(g), solver=solver, **TOL)

    assert "pallas_call" in str(jax.make_jaxpr(lambda g: run(g, TS).omega)(0.3))
    fast, slow = run(0.3, TS), run(0.3, TS, ExplicitRK(diffrax.Tsit5()))
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fast.stats["num_steps"], slow.stats["num_steps"])
    mapped = jax.vmap(lambda I, w, q: rj.simulate(rj.RigidBody(I), w, q, TS, **TOL).omega)
    batch = rj.simulate(rj.RigidBody(I), w, q, TS, **TOL).omega
    np.testing.assert_allclose(mapped(I, w, q), batch, rtol=0, atol=1e-15)

    def loss(g, t1):
        tr = run(g, TS.at[1].set(t1))
        return jnp.sum(tr.omega[:, 1:] ** 2) + jnp.sum(tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0))

    got = jax.grad(loss, argnums=(0, 1))(0.3, 0.5)
    eps = 1e-5
    fd = ((loss(0.3 + eps, 0.5) - loss(0.3 - eps, 0.5)) / (2 * eps),
          (loss(0.3, 0.5 + eps) - loss(0.3, 0.5 - eps)) / (2 * eps))  # fmt: skip
    np.testing.assert_allclose(got, fd, rtol=1e-5)


def test_simulate_reports_max_steps(on_gpu_adaptive):
    """A body that needs more attempts than `max_steps` is the same clear error as on the
    Diffrax path."""
    I, w, q = _bodies(2, seed=3)
    with pytest.raises(rj.IntegrationError, match="max_steps"):
        rj.simulate(rj.RigidBody(I), 3 * w, q, TS, max_steps=5, **TOL)


@pytest.mark.slow  # ~13 s: Pallas lowering and interpreter
def test_served_only_where_checked(monkeypatch):
    """Not on the CPU; on a GPU only after a small batch, compiled, gave the interpreter's
    states and counts: a kernel that fails to lower, or gives other numbers, warns once and is
    not served."""
    model = rigid_body_model(None)
    hoisted = model_kernel.hoist(model.field, model.size, model.params, jnp.float64)
    spec = pk.Spec(hoisted, model.unit, diffrax.Tsit5)
    assert not pa.serves(hoisted, model.unit, diffrax.Tsit5())
    assert not pa.serves(hoisted, model.unit, rj.RK4())
    with pytest.warns(RuntimeWarning, match="Pallas adaptive kernel for Tsit5 in float64"):
        assert not pa._checked.__wrapped__(spec)  # Pallas can't compile for CPU
    with pytest.warns(RuntimeWarning, match="adaptive kernel with its adjoint's residuals"):
        assert not pab._checked_back.__wrapped__(spec)
    run = pa.run

    def interpreted(*args, interpret=False, shift=0.0, **kw):
        ys, rec, st = run(*args, interpret=True, **kw)
        return ys + (0.0 if interpret else shift), rec, st

    monkeypatch.setattr(pa, "run", interpreted)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pa._checked.__wrapped__(spec)
    monkeypatch.setattr(pa, "run", lambda *a, **k: interpreted(*a, **k, shift=1e-6))
    with pytest.warns(RuntimeWarning, match="differ from Pallas' interpreter"):
        assert not pa._checked.__wrapped__(spec)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_kernel_lowers_to_triton(triton_modules, dtype):
    """Lowered for CUDA on a machine without a GPU, the adaptive kernel of an attitude torque
    takes Pallas' Triton backend, whose module Triton takes: one Triton call per batch, also
    under `jax.vmap` (a sweep), with the intervals' loop and, inside it, the attempts' loop
    (`scf.while` on the block's reduction), `pow` of the controller and `1 / sqrt`. What
    remains untested without a GPU, Triton's compile and the numbers, `serves` checks on the
    GPU before first use."""
    model = rigid_body_model(_torque(0.3))
    hoisted = model_kernel.hoist(model.field, model.size, model.params, dtype)
    spec = pk.Spec(hoisted, model.unit, diffrax.Tsit5)
    _, w, q = _bodies(pk.BLOCK + 5)
    y0 = jnp.concatenate([w, q], axis=1).astype(dtype)
    p = jnp.concatenate([moments_params(jnp.ones(3, dtype)), hoisted.c])[:, None]
    ctl = adaptive.controls(diffrax.PIDController(**TOL), diffrax.Tsit5(), None, 100, dtype)
    run = functools.partial(pa.run, spec, ctl=ctl)
    vrun = jax.vmap(run, in_axes=(0, None, None))
    for f, y in ((run, y0), (vrun, jnp.stack([y0, y0]))):
        text = jax.jit(f).trace(y, p, TS.astype(dtype)).lower(lowering_platforms=("cuda",))
        assert text.as_text().count("__gpu$xla.gpu.triton") == 1
    assert len(triton_modules) == 2
    for module in triton_modules:
        symbols = set(re.findall(r'symbol = "(\w*)"', module))
        assert symbols & {"__nv_pow", "__nv_powf"} and symbols & {"__nv_sqrt", "__nv_sqrtf"}
        assert not any("rsqrt" in s for s in symbols)
        assert module.count("scf.for") == 1 and module.count("scf.while") == 1


@pytest.mark.slow  # ~90 s: Pallas' interpreter, the gradients' compiles
def test_closed_loop_at_a_tolerance(on_gpu_adaptive):
    """A closed loop (a gyrostat with four wheels under a quaternion PD law sampled every
    0.25 s and held, outputs every 0.5 s) at rtol = atol = 1e-8 takes the adaptive kernel with
    its jump map, each interval from the initial-step heuristic: the Diffrax path's attitudes,
    wheel speeds, held commands and per-body step counts, and its gradient w.r.t. the initial
    rates (through the Diffrax path)."""
    sat, law = closed_loop()
    ts = jnp.linspace(0.0, 2.0, 5)
    w0 = jnp.asarray([[0.0, 0.0, 0.0], [0.02, -0.01, 0.0], [0.3, 0.03, 0.01]])

    def run(w0, solver=None):
        kw = dict(controller=law, control_period=0.25, solver=solver, **TOL)
        return rj.simulate(sat, w0, None, ts, **kw)

    assert "pallas_call" in str(jax.make_jaxpr(lambda w: run(w).quat)(w0))
    fast, slow = run(w0), run(w0, ExplicitRK(diffrax.Tsit5()))
    for name in ("quat", "omega", "wheel_speed", "command"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fast.stats["num_steps"], slow.stats["num_steps"])
    assert fast.command.shape[1] == 8 and np.ptp(np.asarray(fast.command)) > 0.01

    def loss(w0, solver=None):
        tr = run(w0, solver)
        return jnp.sum(tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0)) + jnp.sum(tr.command**2)

    want = jax.grad(loss)(w0, ExplicitRK(diffrax.Tsit5()))
    np.testing.assert_allclose(jax.grad(loss)(w0), want, rtol=1e-9, atol=1e-12)


@pytest.mark.slow  # ~10 s
def test_jump_map_lowers_to_triton_and_restarts_each_interval(triton_modules):
    """A model with a jump map (a held command, sampled at flagged intervals and recorded):
    lowered for CUDA, one Triton call with the jump's branch (`scf.if`) and the attempts'
    `while` inside the intervals' loop; in the interpreter, its kept states, records and step
    counts those of a loop that applies the jump map and then the kernel, interval by
    interval (each interval from the initial-step heuristic, as the CPU kernel)."""
    hoisted = model_kernel.hoist(held, 3, 1, jnp.float64, sample_law)
    spec = pk.Spec(hoisted, (), diffrax.Tsit5, (2, 1))
    ts = jnp.asarray([0.0, 0.4, 0.5, 1.5])
    jumps, keep = np.array([True, False, True]), np.array([True, False, True, True])
    schedule = model_kernel.Schedule.of(3, jumps, keep, 1)
    ctl = adaptive.controls(diffrax.PIDController(**TOL), diffrax.Tsit5(), None, 100, jnp.float64)
    y0 = jnp.asarray(np.random.default_rng(0).normal(size=(5, 3)))
    p = jnp.concatenate([jnp.asarray([2.0]), hoisted.c])[:, None]
    run = functools.partial(pa.run, spec, ctl=ctl, schedule=schedule)
    lowered = jax.jit(run).trace(y0, p, ts).lower(lowering_platforms=("cuda",))
    assert lowered.as_text().count("__gpu$xla.gpu.triton") == 1
    (module,) = triton_modules
    assert module.count("scf.for") == 1 and module.count("scf.while") == 1
    assert module.count("scf.if") >= 1
    ys, rec, st = run(y0, p, ts, interpret=True)
    assert ys.shape == (5, 3, 3) and rec.shape == (5, 2, 1)
    plain = pk.Spec(model_kernel.hoist(held, 3, 1, jnp.float64), (), diffrax.Tsit5)
    y, want, recs, steps = y0, [y0], [], 0
    for k in range(3):
        if jumps[k]:
            y = jax.vmap(sample_law, in_axes=(None, 0, None))(ts[k], y, p[0])
            recs.append(y[:, 2:])
        out, _, s = pa.run(plain, y, p, ts[k : k + 2], ctl, interpret=True)
        y, steps = out[:, 1], steps + s[:, 0]
        want.append(y)
    # (the jump map there evaluated by XLA: measured 1.2e-15 apart)
    np.testing.assert_allclose(ys, jnp.stack(want, 1)[:, keep], rtol=0, atol=1e-14)
    np.testing.assert_allclose(rec, jnp.stack(recs, 1), rtol=0, atol=1e-14)
    np.testing.assert_array_equal(st[:, 0], steps)


BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
# near the intermediate axis: each flips, at different times
W_FLIP = jnp.array([[0.05, 1.0, 0.02], [0.1, 1.2, -0.03], [0.02, -0.9, 0.1]])
TS_FLIP = jnp.linspace(0.0, 12.0, 4)


def _same_flips(got: rj.Trajectory, cpu: rj.Trajectory) -> None:
    """The kernel's flips are the CPU kernel's (times, states, per-body steps) and the closed
    form's (1e-8)."""
    np.testing.assert_allclose(got.event_t, cpu.event_t, rtol=0, atol=1e-12)
    exact = rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), W_FLIP)
    np.testing.assert_allclose(got.event_t, exact, rtol=0, atol=1e-8)
    np.testing.assert_allclose(got.omega, cpu.omega, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.quat, cpu.quat, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.stats["num_steps"], cpu.stats["num_steps"])


@pytest.mark.slow  # ~12 s: Pallas' interpreter (the fixed-step event's stays quick)
def test_flip_event_in_the_kernel(monkeypatch):
    """The first flip (`flip_event`, terminating) located in the adaptive kernel by the Illinois
    method on the step, each body its own: the CPU kernel's event times (measured ≤ 1e-14
    apart) and held states, and the closed form (`analytic.time_of_first_flip`, 1e-8); not
    terminating, the motion unchanged and the same times."""
    tight = dict(rtol=1e-12, atol=1e-12)
    cpu = rj.simulate(BODY, W_FLIP, ts=TS_FLIP, event=rj.events.flip_event(W_FLIP), **tight)
    monkeypatch.setattr(adaptive, "build", lambda *args, **kwargs: None)
    monkeypatch.setattr(pa, "serves", lambda h, u, solver, *_: type(solver) in pa.tableau.ADAPTIVE)

    def run(terminate=True):
        event = rj.events.flip_event(W_FLIP, terminate=terminate)
        return rj.simulate(BODY, W_FLIP, ts=TS_FLIP, event=event, **tight)

    assert "pallas_call" in str(jax.make_jaxpr(lambda: run().event_t)())
    got = run()
    _same_flips(got, cpu)
    assert np.all(np.asarray(got.event_t) < TS_FLIP[-1])  # held from then on: the CPU's
    going = run(terminate=False)
    np.testing.assert_allclose(going.event_t, cpu.event_t, rtol=0, atol=1e-12)
    plain = rj.simulate(BODY, W_FLIP, ts=TS_FLIP, **tight)
    np.testing.assert_array_equal(going.omega, plain.omega)


@pytest.mark.slow  # ~40 s: the gradients' compiles through Diffrax's events
def test_event_time_gradient(on_gpu_adaptive):
    """The gradient of the flip times w.r.t. the initial rates from the adaptive kernel (through
    the Diffrax path's events) equals the closed form's, `analytic.time_of_first_flip`."""
    tight = dict(rtol=1e-12, atol=1e-12)

    def flips(w):
        event = rj.events.flip_event(W_FLIP)
        return rj.simulate(BODY, w, ts=TS_FLIP, event=event, **tight).event_t

    def exact(w):
        return rj.analytic.time_of_first_flip(BODY.inertia.diagonal(), w)

    got = jax.grad(lambda w: jnp.sum(flips(w) * jnp.arange(1.0, 4.0)))(W_FLIP)
    want = jax.grad(lambda w: jnp.sum(exact(w) * jnp.arange(1.0, 4.0)))(W_FLIP)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("fixed", [False, True], ids=["adaptive", "fixed steps"])
def test_event_lowers_to_triton(triton_modules, fixed):
    """The adaptive kernel with an event's condition, lowered for CUDA: one Triton call whose
    module has the location's `while` (`locate`) behind a branch taken only where a body's
    condition crossed, inside the attempts' `while` (at fixed steps: inside the steps' loop)."""
    model = rigid_body_model(None)
    hoisted = model_kernel.hoist(
        model.field, model.size, model.params, jnp.float64, event=lambda t, y, p: y[1] - 0.5
    )
    method = rj.RK4 if fixed else diffrax.Tsit5
    spec = pk.Spec(hoisted, model.unit, method, fixed=fixed)
    if fixed:
        ctl = adaptive.fixed_controls(0.01, 100, jnp.float64)
    else:
        pid = diffrax.PIDController(**TOL)
        ctl = adaptive.controls(pid, diffrax.Tsit5(), None, 100, jnp.float64)
    _, w, q = _bodies(5)
    y0 = jnp.concatenate([w, q], axis=1)
    p = moments_params(jnp.ones(3))[:, None]
    run = functools.partial(pa.run, spec, ctl=ctl)
    lowered = jax.jit(run).trace(y0, p, TS).lower(lowering_platforms=("cuda",))
    assert lowered.as_text().count("__gpu$xla.gpu.triton") == 1
    (module,) = triton_modules
    assert module.count("scf.while") == (1 if fixed else 2) and module.count("scf.if") >= 1


@pytest.mark.slow  # ~25 s: Pallas' interpreter
def test_closed_loop_settling_event(monkeypatch):
    """A closed loop stopped at its settling event (`settling_event` after a per-body time) in
    the adaptive kernel: the CPU kernel's event times, held attitudes, wheel speeds and
    commands (no sample acts after the event; measured ≤ 1e-14 apart)."""
    sat, law = closed_loop()
    w0 = jnp.asarray([[0.0, 0.0, 0.0], [0.02, -0.01, 0.0], [0.3, 0.03, 0.01]])
    event = rj.events.settling_event(Q_T, np.radians(20.0), jnp.asarray([2.0, 3.0, 1.0]))

    ts = np.linspace(0.0, 12.0, 13)

    def run():
        kw = dict(controller=law, control_period=0.25, event=event, **TOL)
        return rj.simulate(sat, w0, None, ts, **kw)

    cpu = run()
    monkeypatch.setattr(adaptive, "build", lambda *args, **kwargs: None)
    monkeypatch.setattr(pa, "serves", lambda h, u, solver, *_: type(solver) in pa.tableau.ADAPTIVE)
    assert "pallas_call" in str(jax.make_jaxpr(lambda: run().quat)())
    got = run()
    np.testing.assert_allclose(got.event_t, cpu.event_t, rtol=0, atol=1e-12)
    assert np.all((5.0 < np.asarray(got.event_t)) & (np.asarray(got.event_t) < 7.0))
    for name in ("quat", "omega", "wheel_speed", "command"):
        np.testing.assert_allclose(getattr(got, name), getattr(cpu, name), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("window", "solver"),
    [
        pytest.param(pab.WINDOW, ExplicitRK(diffrax.Tsit5()), marks=pytest.mark.slow),  # ~30 s
        # ~15 s: the CPU kernel's reverse compiles in a third of the Diffrax path's
        pytest.param(4, None, marks=pytest.mark.slow),
    ],
    ids=["one window, Diffrax path", "windows of 4, CPU kernel"],
)
def test_reverse_kernel_equals_diffrax_gradient(monkeypatch, window, solver):
    """The adaptive kernel's own reverse mode (`run_back`: each interval's attempts recomputed
    from its first state, the accepted steps reversed through `jax.vjp` of the step) gives the
    cotangents of the initial states and moments of the Diffrax path's reverse mode on the
    same steps (measured 4e-15), also where an interval's attempts take several windows
    (there against the CPU kernel's reverse mode, itself the Diffrax path's in
    test_adaptive_kernel.py)."""
    monkeypatch.setattr(pab, "WINDOW", window)
    I, w, q = _bodies(5, seed=4)
    model = rigid_body_model(None)
    hoisted = model_kernel.hoist(model.field, model.size, model.params, jnp.float64)
    spec = pk.Spec(hoisted, model.unit, diffrax.Tsit5)
    ctl = adaptive.controls(diffrax.PIDController(**TOL), diffrax.Tsit5(), None, 4096, jnp.float64)
    y0, p = jnp.concatenate([w, q], axis=1), moments_params(I).T
    ys, _, _, hk, nk = pa.run(spec, y0, p, TS, ctl, interpret=True, adjoint=True)
    assert window > 4 or int(jnp.max(nk)) > 2 * window  # several windows
    g = jnp.asarray(np.random.default_rng(5).normal(size=ys.shape))
    y0b, pb = pab.run_back(spec, ys, hk, nk, g, p, TS, ctl, interpret=True)

    def reference(I, w, q):
        tr = rj.simulate(rj.RigidBody(I), w, q, TS, solver=solver, **TOL)
        return jnp.concatenate([tr.omega, tr.quat], -1)

    gI, gw, gq = jax.vjp(reference, I, w, q)[1](g)
    np.testing.assert_allclose(y0b, jnp.concatenate([gw, gq], -1), rtol=0, atol=1e-12)
    got_I = jax.vjp(lambda I: moments_params(I).T, I)[1](pb)[0]
    np.testing.assert_allclose(got_I, gI, rtol=0, atol=1e-12)


@pytest.mark.slow  # ~40 s: Pallas' interpreter, the Diffrax path's gradient compile
def test_simulate_gradient_through_the_reverse_kernel(on_gpu_adaptive):
    """`jax.grad` through `simulate` at a tolerance with a torque (a traced gain, time-dependent)
    runs the kernel's own reverse mode (two Pallas calls in the gradient's program, no
    Diffrax) and equals the Diffrax path's gradient w.r.t. the moments, the gain and the
    initial rates."""
    I, w, q = _bodies(4, seed=6)

    def loss(I, g, w, solver=None):
        tr = rj.simulate(rj.RigidBody(I), w, q, TS, torque=_torque(g), solver=solver, **TOL)
        return jnp.sum(tr.omega[:, 1:] ** 2) + jnp.sum(tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0))

    grad = jax.grad(loss, argnums=(0, 1, 2))
    program = str(jax.make_jaxpr(grad)(I, 0.3, w))
    assert program.count("pallas_call") == 2  # the forward with its residuals, the reverse
    want = grad(I, 0.3, w, ExplicitRK(diffrax.Tsit5()))
    for got, ref in zip(grad(I, 0.3, w), want, strict=True):
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)


def test_reverse_kernel_lowers_to_triton(triton_modules):
    """The forward kernel with the adjoint's residuals and the reverse-mode kernel of an
    attitude torque, lowered for CUDA: a Triton call each; the reverse's module has the
    intervals' and windows' loops and the recomputed attempts, with the controller's `pow`."""
    model = rigid_body_model(_torque(0.3))
    hoisted = model_kernel.hoist(model.field, model.size, model.params, jnp.float64)
    spec = pk.Spec(hoisted, model.unit, diffrax.Tsit5)
    ctl = adaptive.controls(diffrax.PIDController(**TOL), diffrax.Tsit5(), None, 100, jnp.float64)
    _, w, q = _bodies(5)
    y0 = jnp.concatenate([w, q], axis=1)
    p = jnp.concatenate([moments_params(jnp.ones(3)), hoisted.c])[:, None]
    run = functools.partial(pa.run, spec, ctl=ctl, adjoint=True)
    jax.jit(run).trace(y0, p, TS).lower(lowering_platforms=("cuda",))
    ys, hk, nk = jnp.zeros((5, 4, 7)), jnp.zeros((5, 3)), jnp.zeros((5, 3), jnp.int32)
    back = functools.partial(pab.run_back, spec, ctl=ctl)
    lowered = jax.jit(back).trace(ys, hk, nk, ys, p, TS).lower(lowering_platforms=("cuda",))
    assert lowered.as_text().count("__gpu$xla.gpu.triton") == 1
    assert len(triton_modules) == 2
    symbols = set(re.findall(r'symbol = "(\w*)"', triton_modules[1]))
    assert "__nv_pow" in symbols and triton_modules[1].count("scf.for") >= 4


@pytest.mark.parametrize(
    "method",
    [rj.RK4, pytest.param(diffrax.Tsit5, marks=pytest.mark.slow)],  # ~7 s each
    ids=lambda m: m.__name__,
)
def test_fixed_step_flip_event_in_the_kernel(monkeypatch, method):
    """An event at fixed steps (each body its own fixed steps, as the CPU's per-body kernel
    built for fixed steps, which the lockstep kernels cannot stop one body of): the CPU
    kernel's event times (measured ≤ 1e-15 apart), states and per-body step counts (a stopped
    body takes no more), and the closed form's flip times."""
    fixed = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01, solver=method())

    def run():
        event = rj.events.flip_event(W_FLIP)
        return rj.simulate(BODY, W_FLIP, ts=TS_FLIP, event=event, **fixed)

    cpu = run()
    monkeypatch.setattr(adaptive, "build", lambda *args, **kwargs: None)
    monkeypatch.setattr(pa, "serves", lambda h, u, solver, *_: type(solver) in pa.tableau.METHODS)
    assert "pallas_call" in str(jax.make_jaxpr(lambda: run().event_t)())
    got = run()
    _same_flips(got, cpu)
    assert np.all(np.asarray(got.stats["num_steps"]) < 1200)  # stopped before t = 12
