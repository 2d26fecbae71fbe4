"""The Pallas kernel (the GPU fast path of every model at fixed steps of an explicit Runge–Kutta
method), run in Pallas' interpreter on the CPU, against the Diffrax path on the same steps
(`ExplicitRK(method)`, which never takes a kernel); and its wiring into `solve_model`, with the
backend's choice forced to the GPU kernel: the free body, a torque with a traced gain, the heavy
top."""

import functools
import re
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.kernels import model as model_kernel
from rigidjax.kernels import model_pallas as pk
from rigidjax.kernels import model_pallas_back as pkb
from rigidjax.kinematics.formulations import lookup
from rigidjax.mechanics import heavy_top as ht
from rigidjax.mechanics._rigid_model import moments_params, rigid_body_model
from rigidjax.solvers import ExplicitRK
from tests.helpers import rigid_body_dop853
from tests.kernels.held import closed_loop, held, sample_law

BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
TS = jnp.asarray([0.0, 0.1, 0.12, 0.35])  # 5, 1 and 12 steps of at most 0.02
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.02)
E_Z = jnp.array([0.0, 0.0, 1.0])


def _inputs(B, seed=0, dtype=jnp.float64):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(B, 4))
    w, q = rng.normal(size=(B, 3)), q / np.linalg.norm(q, axis=1)[:, None]
    return jnp.asarray(w, dtype), jnp.asarray(q, dtype)


def _free(dtype=jnp.float64):
    model = rigid_body_model(None)
    return model, model_kernel.hoist(model.field, model.size, model.params, dtype)


def _steps(ts=TS, n=(5, 1, 12)):
    n = jnp.asarray(n, jnp.int32)
    return n, jnp.diff(ts) / n, ts[:-1]


@pytest.fixture
def on_gpu_kernel(monkeypatch):
    """`solve_model` as on a GPU: no C++ kernel, and the Pallas kernel served for its methods
    (run in Pallas' interpreter here)."""
    monkeypatch.setattr(model_kernel, "build", lambda *args: None)
    monkeypatch.setattr(pk, "serves", lambda hoisted, unit, solver, *_: type(solver) in pk.METHODS)


@pytest.mark.parametrize(
    "method",
    [rj.RK4, diffrax.Tsit5, pytest.param(diffrax.Dopri8, marks=pytest.mark.slow)],  # (~10 s)
    ids=lambda m: m.__name__,
)
def test_kernel_equals_diffrax_path(method):
    """Every body of a full and a partial block (padded), per-body moments, three intervals of
    unequal steps: the Diffrax path's numbers, and SciPy's solution within the method's
    error."""
    B = pk.BLOCK + 5
    w, q = _inputs(B)
    I = jnp.asarray(np.random.default_rng(1).uniform(1.5, 2.5, size=(B, 3)))
    want = rj.simulate(rj.RigidBody(I), w, q, ts=TS, solver=ExplicitRK(method()), **FIXED)
    model, hoisted = _free()
    y0 = jnp.concatenate([w, q], axis=1)
    got = pk.run(
        pk.Spec(hoisted, model.unit, method), y0, moments_params(I).T, _steps(), interpret=True
    )
    # the same field and stages: equal but for 1 / sqrt against rsqrt (measured 4.4e-16)
    np.testing.assert_allclose(got[..., :3], want.omega, rtol=0, atol=2e-15)
    np.testing.assert_allclose(got[..., 3:], want.quat, rtol=0, atol=2e-15)
    # and SciPy's DOP853 at 1e-13, an independent reference (measured: RK4 4.7e-10, Tsit5
    # and Dopri8 1.5e-13, SciPy's own tolerance)
    atol = 2e-9 if method is rj.RK4 else 1e-12
    for i in (0, B - 1):
        w_ref, q_ref = rigid_body_dop853(I[i], w[i], q[i], TS)
        np.testing.assert_allclose(got[i, :, :3], w_ref, rtol=0, atol=atol)
        np.testing.assert_allclose(got[i, :, 3:], q_ref, rtol=0, atol=atol)


def test_shared_parameters_float32_and_vmap():
    """One body for the whole batch (`p (P, 1)`), an interval without steps (the state kept),
    float32 against float64, and `jax.vmap` over the kernel (a batch of step sequences) equal
    to a loop."""
    w, q = _inputs(7)
    y0 = jnp.concatenate([w, q], axis=1)
    p = moments_params(jnp.array([1.0, 2.0, 3.0]))[:, None]
    n, h, t0 = jnp.asarray([4, 0, 6], jnp.int32), jnp.asarray([0.05, 0.1, 0.02]), jnp.zeros(3)
    model, hoisted = _free()
    run = functools.partial(pk.run, pk.Spec(hoisted, model.unit, rj.RK4), interpret=True)
    y64 = run(y0, p, (n, h, t0))
    assert y64.shape == (7, 4, 7)
    np.testing.assert_array_equal(y64[:, 2], y64[:, 1])
    _, hoisted32 = _free(jnp.float32)
    y32 = pk.run(
        pk.Spec(hoisted32, model.unit, rj.RK4),
        y0.astype(jnp.float32),
        p,
        (n, h, t0),
        interpret=True,
    )
    assert y32.dtype == jnp.float32
    np.testing.assert_allclose(y32, y64, rtol=0, atol=2e-6)
    hs = jnp.stack([h, 2 * h])
    mapped = jax.vmap(lambda h: run(y0, p, (n, h, t0)))(hs)
    for i in range(2):
        np.testing.assert_allclose(mapped[i], run(y0, p, (n, hs[i], t0)), rtol=0, atol=1e-15)


def _gravity_gradient(gain):
    def torque(t, w, q):
        c = rj.quat.to_matrix(q).T @ E_Z
        return gain * jnp.cross(c, jnp.array([1.0, 2.0, 3.0]) * c) - 0.1 * jnp.sin(t) * w

    return torque


@pytest.mark.slow  # over 20 s here (the gradient's compiles)
def test_torque_through_gpu_kernel_with_diffrax_gradients(on_gpu_kernel):
    """`simulate` with a torque (an attitude torque with a traced gain, and a time-dependent
    damping) through the GPU kernel, which evaluates the JAX torque itself: the Diffrax path's
    trajectory and statistics, and reverse-mode gradients (through Diffrax, the kernel having
    no adjoint) with respect to the moments, the gain, the initial state and the output times
    equal to the Diffrax path's, under `jax.jit`."""
    w, q = _inputs(3)
    jaxpr = jax.make_jaxpr(
        lambda g: (
            rj.simulate(BODY, w, q, TS, torque=_gravity_gradient(g), solver=rj.RK4(), **FIXED).omega
        )
    )
    assert "pallas_call" in str(jaxpr(0.3))

    def loss(I, g, w, ts, solver):
        tr = rj.simulate(
            rj.RigidBody(I), w, q, ts, torque=_gravity_gradient(g), solver=solver, **FIXED
        )
        q_end = tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0)
        return jnp.sum(tr.omega[:, 1:] ** 2) + jnp.sum(q_end)

    args = (jnp.asarray([1.0, 2.0, 3.0]), jnp.asarray(0.3), w, TS)
    fast = rj.simulate(BODY, w, q, TS, torque=_gravity_gradient(0.3), solver=rj.RK4(), **FIXED)
    slow = rj.simulate(
        BODY, w, q, TS, torque=_gravity_gradient(0.3), solver=ExplicitRK(rj.RK4()), **FIXED
    )
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=2e-15)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=2e-15)
    assert int(fast.stats["num_steps"]) == int(slow.stats["num_steps"]) == 18  # 5 + 1 + 12
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)), static_argnums=4)
    want = grads(*args, ExplicitRK(rj.RK4()))
    for g, r in zip(grads(*args, rj.RK4()), want, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-10, atol=1e-12)


@pytest.mark.slow  # ~11 s: Pallas' interpreter
def _switched(t, w, q):
    """`lax.switch` on t; the untaken first branch is NaN for t > 0.1."""
    k = jnp.clip(jnp.floor(10 * t).astype(jnp.int32), 0, 2)
    branches = [lambda: -0.1 * w * jnp.sqrt(0.1 - t), lambda: 0.2 * w[::-1], lambda: w * q[0]]
    return jax.lax.switch(k, branches)


@pytest.mark.slow  # ~15 s: Pallas' interpreter
def test_switch_through_gpu_kernel(on_gpu_kernel):
    """A torque with `lax.switch` takes the GPU kernel (a selection between the branches, as on
    the CPU): the Diffrax path's values; the untaken branch's NaN does not leak."""
    w, q = _inputs(3)
    run = functools.partial(rj.simulate, BODY, w, q, TS, torque=_switched, **FIXED)
    assert "pallas_call" in str(jax.make_jaxpr(lambda: run(solver=rj.RK4()).omega)())
    fast, slow = run(solver=rj.RK4()), run(solver=ExplicitRK(rj.RK4()))
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=2e-15)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=2e-15)


@pytest.mark.slow  # ~9 s: Pallas' interpreter
def test_heavy_top_through_gpu_kernel(on_gpu_kernel):
    """The heavy top's model (a PyTree state) takes the GPU kernel too: the Diffrax path's
    numbers; under `jax.vmap` over tops (one-body solves) the tops join one kernel call."""
    top = ht.HeavyTop(np.array([1.0, 1.4, 1.9]), 1.0, [0.1, -0.05, 0.2])
    w0, q0 = np.array([0.5, -1.0, 2.0]), np.array([0.9, 0.2, -0.3, 0.1]) / np.sqrt(0.95)
    run = functools.partial(ht.simulate_heavy_top, top, w0, ts=TS, q0=q0, **FIXED)
    assert "pallas_call" in str(jax.make_jaxpr(lambda: run(solver=rj.RK4()).omega)())
    fast, slow = run(solver=rj.RK4()), run(solver=ExplicitRK(rj.RK4()))
    for a, b in ((fast.omega, slow.omega), (fast.gamma, slow.gamma), (fast.quat, slow.quat)):
        np.testing.assert_allclose(a, b, rtol=0, atol=2e-15)

    def one(com, solver):
        tops = ht.HeavyTop(np.array([1.0, 1.4, 1.9]), 1.0, com)
        return ht.simulate_heavy_top(tops, w0, ts=TS, q0=q0, solver=solver, **FIXED).omega

    coms = jnp.asarray([[0.1, -0.05, 0.2], [0.0, 0.1, 0.3], [0.2, 0.0, -0.1]])
    jaxpr = str(jax.make_jaxpr(jax.vmap(lambda c: one(c, rj.RK4())))(coms))
    assert jaxpr.count("pallas_call") == 1 and "grid=(1,)" in jaxpr  # 3 tops: one block
    mapped = jax.vmap(lambda c: one(c, rj.RK4()))(coms)
    for i in range(3):
        np.testing.assert_allclose(mapped[i], one(coms[i], ExplicitRK(rj.RK4())), atol=2e-15)


@pytest.mark.slow  # ~18 s: Pallas' interpreter
def test_darboux_rotation_vector_through_gpu_kernel(on_gpu_kernel):
    """The Darboux rotation-vector model with its shadow switch (the step-end map, evaluated in
    the kernel after every step) at 6 rad/s, where |θ| passes π: the Diffrax path's rotations,
    and the reverse kernel's gradient w.r.t. a parameter of ω(t) equal to the Diffrax path's."""

    def run(a, solver):
        def omega(t):
            return jnp.stack([a * jnp.cos(t), 6.0 * jnp.ones_like(t), a * jnp.sin(2.0 * t)])

        return rj.darboux(omega, TS, method="rotvec", solver=solver, **FIXED)

    assert "pallas_call" in str(jax.make_jaxpr(lambda a: run(a, rj.RK4()))(0.5))
    fast, slow = run(0.5, rj.RK4()), run(0.5, ExplicitRK(rj.RK4()))
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-14)
    theta = rj.so3.log(fast[-1])
    assert 0.5 < np.linalg.norm(theta) < np.pi  # 2.1 rad of spin beyond π: shadowed

    def loss(a, solver):
        return jnp.sum(run(a, solver)[1:] * jnp.arange(9.0).reshape(3, 3))

    got = jax.grad(loss)(0.5, rj.RK4())
    np.testing.assert_allclose(got, jax.grad(loss)(0.5, ExplicitRK(rj.RK4())), rtol=1e-10)


def test_gpu_kernel_reports_max_steps(on_gpu_kernel):
    """An interval with more steps than `max_steps` is the same clear error as on the
    Diffrax path."""
    w, q = _inputs(2)
    with pytest.raises(rj.IntegrationError, match="max_steps"):
        rj.simulate(BODY, w, q, TS, solver=rj.RK4(), max_steps=4, **FIXED)


def test_served_only_where_checked(monkeypatch):
    """Not on the CPU; on a GPU only after a small batch, compiled, gave the interpreter's
    states: a kernel that fails to lower, or gives other numbers, warns once and is not
    served."""
    model, hoisted = _free()
    spec = pk.Spec(hoisted, model.unit, rj.RK4)
    assert not pk.serves(hoisted, model.unit, rj.RK4())
    assert not pk.serves(hoisted, model.unit, ExplicitRK(rj.RK4()))
    with pytest.warns(RuntimeWarning, match="Pallas kernel for RK4 in float64"):
        assert not pk._checked.__wrapped__(spec)  # Pallas can't compile for CPU
    run = pk.run

    def interpreted(*args, interpret=False, shift=0.0):
        return run(*args, interpret=True) + (0.0 if interpret else shift)

    monkeypatch.setattr(pk, "run", interpreted)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pk._checked.__wrapped__(spec)
    monkeypatch.setattr(pk, "run", lambda *a, **k: interpreted(*a, **k, shift=1e-6))
    with pytest.warns(RuntimeWarning, match="differ from Pallas' interpreter"):
        assert not pk._checked.__wrapped__(spec)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_kernel_lowers_to_triton(triton_modules, dtype):
    """Lowered for CUDA on a machine without a GPU, the kernel of a model with an attitude
    torque and `sin(t)` takes Pallas' Triton backend (not Mosaic GPU, Pallas' default), whose
    module Triton takes (ops, dynamic loops, loads and stores, in float32 and float64), and
    the time loop is inside it: the lowered program is one Triton call and no loop of XLA's,
    also under `jax.vmap` (a sweep). The renormalisation is `1 / sqrt`, not `rsqrt`, which
    Triton lowers to the approximate `rsqrt.approx.f64` (seen in its PTX). What remains
    untested without a GPU, Triton's compile and the numbers, `serves` checks on the GPU
    before first use."""
    model = rigid_body_model(_gravity_gradient(0.3))
    hoisted = model_kernel.hoist(model.field, model.size, model.params, dtype)
    w, q = _inputs(pk.BLOCK + 5, dtype=dtype)
    y0 = jnp.concatenate([w, q], axis=1)
    p = jnp.concatenate([moments_params(jnp.ones(3, dtype)), hoisted.c])[:, None]
    n, h, t0 = jnp.asarray([3, 4], jnp.int32), jnp.asarray([0.1, 0.2], dtype), jnp.zeros(2, dtype)
    run = functools.partial(pk.run, pk.Spec(hoisted, model.unit, rj.RK4))
    vrun = jax.vmap(run, in_axes=(None, None, (None, 0, None)))
    for f, hs in ((run, h), (vrun, h * h[:, None])):
        text = jax.jit(f).trace(y0, p, (n, hs, t0)).lower(lowering_platforms=("cuda",)).as_text()
        assert text.count("__gpu$xla.gpu.triton") == 1 and "num_warps = 4 " in text
        assert "stablehlo.while" not in text
    assert len(triton_modules) == 2
    for module in triton_modules:
        symbols = set(re.findall(r'symbol = "(\w*)"', module))
        assert symbols & {"__nv_sqrt", "__nv_sqrtf"} and not any("rsqrt" in s for s in symbols)
        assert symbols & {"__nv_sin", "__nv_sinf"}
        assert module.count("scf.for") == 2  # the intervals and, inside, their steps


@pytest.mark.slow  # ~15 s: Pallas' interpreter
def test_forward_kernel_writes_the_checkpoints():
    """The forward kernel of a differentiated solve (`run(..., longest=12)`: checkpoints every
    L = 4 steps, C = 3 slots per interval) gives the plain kernel's states bit for bit, and in
    slot s of interval k the state after s·L of its steps (a separate run of that many steps),
    the slots past the interval's last segment its end state."""
    model = rigid_body_model(_gravity_gradient(0.3))
    hoisted = model_kernel.hoist(model.field, model.size, model.params, jnp.float64)
    spec = pk.Spec(hoisted, model.unit, rj.RK4)
    w, q = _inputs(3)
    y0 = jnp.concatenate([w, q], axis=1)
    p = jnp.concatenate([moments_params(jnp.array([1.0, 2.0, 3.0])), hoisted.c])[:, None]
    n, h, t0 = steps = _steps()  # 5, 1 and 12 steps
    assert pk.checkpoints(12) == (4, 3)
    ys, ck = pk.run(spec, y0, p, steps, interpret=True, longest=12)
    np.testing.assert_array_equal(ys, pk.run(spec, y0, p, steps, interpret=True))
    for k, slots in ((0, (0, 4, 5)), (1, (0, 1, 1)), (2, (0, 4, 8))):
        for s, done in enumerate(slots):
            part = (jnp.asarray([done], jnp.int32), h[k : k + 1], t0[k : k + 1])
            want = pk.run(spec, ys[:, k], p, part, interpret=True)[:, 1]
            np.testing.assert_array_equal(ck[:, k, s], want)


@pytest.mark.slow  # over 20 s here (the gradient's compiles)
def test_gpu_kernel_adjoint(on_gpu_kernel):
    """Reverse mode through the GPU kernel's own adjoint (a second Pallas kernel that reverses
    the same steps, recomputed from checkpoints) where the output times are not
    differentiated: gradients w.r.t. the moments, a traced gain and the initial state equal the
    Diffrax path's, and central differences of the gain's; under `jax.jit` with the output
    times traced (step counts unknown when tracing: the reverse kernel recomputes the
    checkpoints from the states) the same gradients; under `jax.vmap` of a one-body gradient
    (per-member gains) the members' gradients are their own."""
    w, q = _inputs(3)

    def loss(I, g, w, solver, ts=TS):
        tr = rj.simulate(
            rj.RigidBody(I), w, q, ts, torque=_gravity_gradient(g), solver=solver, **FIXED
        )
        q_end = tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0)
        return jnp.sum(tr.omega[:, 1:] ** 2) + jnp.sum(q_end)

    args = (jnp.asarray([1.0, 2.0, 3.0]), jnp.asarray(0.3), w)
    grad = jax.grad(loss, argnums=(0, 1, 2))
    assert str(jax.make_jaxpr(lambda *a: grad(*a, rj.RK4()))(*args)).count("pallas_call") == 2
    want = grad(*args, ExplicitRK(rj.RK4()))
    got = grad(*args, rj.RK4())
    for g, r in zip(got, want, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-10, atol=1e-12)
    eps = 1e-6
    fd = (loss(args[0], args[1] + eps, w, rj.RK4()) - loss(args[0], args[1] - eps, w, rj.RK4())) / (
        2 * eps
    )
    np.testing.assert_allclose(got[1], fd, rtol=1e-7)
    traced = jax.jit(lambda I, g, w, ts: grad(I, g, w, rj.RK4(), ts))
    assert not pkb.stores_checkpoints(np.array([1, 1, 100]), 100)  # (uneven: recomputed)
    assert str(jax.make_jaxpr(traced)(*args, TS)).count("pallas_call") == 2
    for g, r in zip(traced(*args, TS), want, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-10, atol=1e-12)

    def one(g, solver):
        return jax.grad(lambda g: loss(args[0], g, w[:1], solver, TS[:3]))(g)

    gains = jnp.asarray([0.1, 0.3])
    mapped = jax.jit(jax.vmap(lambda g: one(g, rj.RK4())))(gains)
    for i in range(2):
        np.testing.assert_allclose(mapped[i], one(gains[i], ExplicitRK(rj.RK4())), rtol=1e-10)


def test_reverse_kernel_lowers_to_triton(triton_modules):
    """The reverse-mode kernel (`run_back`) of the same attitude-torque model, and the forward
    kernel that writes its checkpoints, lowered for CUDA without a GPU: one Triton call each
    holding the whole (reversed) time loop (no loop of XLA's), also under `jax.vmap`; their
    numbers on a GPU are checked by `serves_back` before use."""
    dtype = jnp.float64
    model = rigid_body_model(_gravity_gradient(0.3))
    hoisted = model_kernel.hoist(model.field, model.size, model.params, dtype)
    B = pk.BLOCK + 5
    spec = pk.Spec(hoisted, model.unit, rj.RK4)
    # 2 intervals of at most 4 steps: checkpoints 2 steps apart, 2 per interval
    ck, g = jnp.ones((B, 2, 2, 7), dtype), jnp.ones((B, 3, 7), dtype)
    p = jnp.concatenate([moments_params(jnp.ones(3, dtype)), hoisted.c.astype(dtype)])[:, None]
    n, h, t0 = jnp.asarray([3, 4], jnp.int32), jnp.asarray([0.1, 0.2], dtype), jnp.zeros(2, dtype)
    back = functools.partial(pkb.run_back, spec, longest=4)
    vback = jax.vmap(back, in_axes=(0, 0, None, None))
    forward = functools.partial(pk.run, spec, longest=4)
    cases = ((back, (ck, g)), (vback, (ck[None], g[None])), (forward, (g[:, 0],)))
    for f, a in cases:
        text = jax.jit(f).trace(*a, p, (n, h, t0)).lower(lowering_platforms=("cuda",)).as_text()
        assert text.count("__gpu$xla.gpu.triton") == 1 and "stablehlo.while" not in text
    assert len(triton_modules) == 3 and all("scf.for" in m for m in triton_modules)


def test_step_end_map_lowers_to_triton(triton_modules):
    """The rotation vector's shadow switch (a step-end map whose `round` Pallas' Triton lowering
    lacks: the scalar program builds it from `floor`) lowers for CUDA inside the forward and
    the reverse kernel; a model without parameters takes its lifted constants (the Taylor
    coefficients of Z(θ)) as its only rows."""
    kin = lookup("rotvec", "space")

    def field(t, y, p):
        return kin.vector_field(y, jnp.stack([jnp.sin(t), 2.0 * jnp.ones_like(t), 3.0]))

    hoisted = model_kernel.hoist(field, 3, 0, jnp.float64, end=kin.step_end)
    spec = pk.Spec(hoisted, (), rj.RK4)
    ys, p = jnp.ones((pk.BLOCK, 3, 3)), hoisted.c[:, None]  # (3 states: the output times')
    ck = jnp.ones((pk.BLOCK, 2, 2, 3))  # (the checkpoints of 2 intervals of at most 4 steps)
    steps = (jnp.asarray([3, 4], jnp.int32), jnp.asarray([0.1, 0.2]), jnp.zeros(2))
    forward = functools.partial(pk.run, spec)
    back = functools.partial(pkb.run_back, spec, longest=4)
    for f, args in ((forward, (ys[:, 0], p, steps)), (back, (ck, ys, p, steps))):
        text = jax.jit(f).trace(*args).lower(lowering_platforms=("cuda",)).as_text()
        assert text.count("__gpu$xla.gpu.triton") == 1
    assert len(triton_modules) == 2 and all("__nv_floor" in m for m in triton_modules)


@pytest.mark.slow  # forward mode compiles the Diffrax path beside the Pallas kernel
def test_gpu_kernel_forward_mode(on_gpu_kernel):
    """`jax.jacfwd` through the Pallas kernel with default options (issue 34) equals its own
    reverse mode (the Pallas adjoint) and central differences, w.r.t. a traced gain."""
    w, q = _inputs(2)

    def f(g):
        torque = _gravity_gradient(g[0])
        return rj.simulate(BODY, w, q, TS, torque=torque, solver=rj.RK4(), **FIXED).omega[:, -1]

    g = jnp.array([0.3])
    forward, reverse = jax.jacfwd(f)(g), jax.jacrev(f)(g)
    np.testing.assert_allclose(forward, reverse, rtol=0, atol=1e-12)
    eps = 1e-6
    np.testing.assert_allclose(forward[..., 0], (f(g + eps) - f(g - eps)) / (2 * eps), atol=1e-8)


@pytest.mark.slow  # ~40 s: Pallas' interpreter, the gradients' compiles
def test_closed_loop_through_gpu_kernel(on_gpu_kernel):
    """A closed loop (a gyrostat with four wheels under a quaternion PD law sampled every 5
    steps and held, the outputs every 2 samples) takes the GPU kernel with its jump map: the
    Diffrax path's attitudes, wheel speeds and held commands (the records), and the gradient
    of a loss of the attitudes and commands w.r.t. the initial rates (through the Diffrax
    path) equal to the Diffrax path's."""
    sat, law = closed_loop()
    ts = jnp.linspace(0.0, 2.0, 5)
    w0 = jnp.asarray([[0.0, 0.0, 0.0], [0.02, -0.01, 0.0], [0.0, 0.03, 0.01]])

    def run(w0, solver):
        kw = dict(controller=law, control_period=0.25, solver=solver, **FIXED)
        return rj.simulate(sat, w0, None, ts, **{**kw, "dt0": 0.05})

    assert "pallas_call" in str(jax.make_jaxpr(lambda w: run(w, rj.RK4()).quat)(w0))
    fast, slow = run(w0, rj.RK4()), run(w0, ExplicitRK(rj.RK4()))
    for name in ("quat", "omega", "wheel_speed", "command"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=0, atol=1e-14)
    assert fast.command.shape[1] == 8 and np.ptp(np.asarray(fast.command)) > 0.01

    def loss(w0, solver):
        tr = run(w0, solver)
        return jnp.sum(tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0)) + jnp.sum(tr.command**2)

    got = jax.grad(loss)(w0, rj.RK4())
    np.testing.assert_allclose(got, jax.grad(loss)(w0, ExplicitRK(rj.RK4())), rtol=1e-10)


def test_jump_map_lowers_to_triton(triton_modules):
    """Lowered for CUDA on a machine without a GPU, the kernel of a model with a jump map (a
    held command, sampled at flagged intervals and recorded) is one Triton call whose module
    has the jump's branch (`scf.if`) inside the intervals' loop; and in the interpreter its
    kept states and records equal a loop that applies the jump map and the kernel's steps
    interval by interval."""
    hoisted = model_kernel.hoist(held, 3, 1, jnp.float64, sample_law)
    spec = pk.Spec(hoisted, (), rj.RK4, (2, 1))
    jumps, keep = np.array([True, False, True]), np.array([True, False, True, True])
    schedule = model_kernel.Schedule.of(3, jumps, keep, 1)
    y0 = jnp.asarray(np.random.default_rng(0).normal(size=(5, 3)))
    p = jnp.concatenate([jnp.asarray([2.0]), hoisted.c])[:, None]
    steps = (jnp.asarray([3, 0, 5], jnp.int32), jnp.asarray([0.1, 0.2, 0.05]), TS[:-1])
    run = functools.partial(pk.run, spec, schedule=schedule)
    lowered = jax.jit(run).trace(y0, p, steps).lower(lowering_platforms=("cuda",))
    assert lowered.as_text().count("__gpu$xla.gpu.triton") == 1
    (module,) = triton_modules
    assert module.count("scf.for") == 2 and module.count("scf.if") >= 1
    ys, rec = run(y0, p, steps, interpret=True)
    assert ys.shape == (5, 3, 3) and rec.shape == (5, 2, 1)
    plain = functools.partial(
        pk.run, pk.Spec(model_kernel.hoist(held, 3, 1, jnp.float64), (), rj.RK4)
    )
    y, want, recs = y0, [y0], []
    for k in range(3):
        if jumps[k]:
            y = jax.vmap(sample_law, in_axes=(None, 0, None))(TS[k], y, p[0])
            recs.append(y[:, 2:])
        y = plain(y, p, tuple(a[k : k + 1] for a in steps), interpret=True)[:, 1]
        want.append(y)
    np.testing.assert_allclose(ys, jnp.stack(want, 1)[:, keep], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rec, jnp.stack(recs, 1), rtol=0, atol=1e-15)
