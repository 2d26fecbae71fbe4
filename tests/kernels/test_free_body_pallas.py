"""The Pallas kernel (the GPU fast path of `simulate(..., solver=method, ConstantStepSize,
dt0)`), run in Pallas' interpreter on the CPU, against the Diffrax path on the same steps
(`ExplicitRK(method)`, which never takes a kernel); and its wiring into `simulate`, with the
backend's choice forced to the GPU kernel."""

import functools
import re
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.kernels import free_body_pallas as pk
from rigidjax.mechanics import dynamics
from rigidjax.solvers import ExplicitRK
from tests.helpers import rigid_body_dop853

BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
TS = jnp.asarray([0.0, 0.1, 0.12, 0.35])  # 5, 1 and 12 steps of at most 0.02
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.02)


def _inputs(B, seed=0, dtype=jnp.float64):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(B, 4))
    w, q = rng.normal(size=(B, 3)), q / np.linalg.norm(q, axis=1)[:, None]
    return jnp.asarray(w, dtype), jnp.asarray(q, dtype)


def _diffrax_path(method, w, q, body=BODY, ts=TS, **kw):
    return rj.simulate(body, w, q, ts=ts, solver=ExplicitRK(method()), **FIXED, **kw)


@pytest.fixture
def on_gpu_kernel(monkeypatch):
    """`simulate` as on a GPU: no C++ kernel, and the Pallas kernel served for its methods
    (run in Pallas' interpreter here); `_kernel_for` itself decides."""
    monkeypatch.setattr(dynamics.kernel, "serves", lambda solver, dtype: False)
    monkeypatch.setattr(pk, "serves", lambda solver, dtype: type(solver) in pk.METHODS)


@pytest.mark.parametrize(
    "method", [rj.RK4, diffrax.Tsit5, diffrax.Dopri8], ids=lambda m: m.__name__
)
def test_kernel_equals_diffrax_path(method):
    """Every body of a full and a partial block (padded with resting bodies), per-body
    coefficients, three intervals of unequal steps: the Diffrax path's numbers, and SciPy's
    solution within the method's error."""
    B = pk.BLOCK + 5
    w, q = _inputs(B)
    I = jnp.asarray(np.random.default_rng(1).uniform(1.5, 2.5, size=(B, 3)))
    body = rj.RigidBody(I)
    want = _diffrax_path(method, w, q, body=body)
    I1, I2, I3 = I.T
    coef = jnp.stack([(I2 - I3) / I1, (I3 - I1) / I2, (I1 - I2) / I3])
    n = jnp.asarray([5, 1, 12], jnp.int32)
    h = jnp.diff(TS) / n
    got_w, got_q = pk.free_body_pallas(method, w, q, coef, n, h, interpret=True)
    # the same field and stages: equal but for 1 / sqrt against rsqrt (measured 4.4e-16)
    np.testing.assert_allclose(got_w, want.omega, rtol=0, atol=2e-15)
    np.testing.assert_allclose(got_q, want.quat, rtol=0, atol=2e-15)
    # and SciPy's DOP853 at 1e-13, an independent reference (measured: RK4 4.7e-10, Tsit5
    # and Dopri8 1.5e-13, SciPy's own tolerance)
    atol = 2e-9 if method is rj.RK4 else 1e-12
    for i in (0, B - 1):
        w_ref, q_ref = rigid_body_dop853(I[i], w[i], q[i], TS)
        np.testing.assert_allclose(got_w[i], w_ref, rtol=0, atol=atol)
        np.testing.assert_allclose(got_q[i], q_ref, rtol=0, atol=atol)


def test_shared_coefficients_float32_and_vmap():
    """One body for the whole batch (`coef (3, 1)`), an interval without steps (the state
    kept), float32 against float64, and `jax.vmap` over the kernel (a batch of step
    sequences) equal to a loop."""
    w, q = _inputs(7)
    coef = jnp.asarray([[-1.0], [1.0], [-1.0 / 3.0]])
    n, h = jnp.asarray([4, 0, 6], jnp.int32), jnp.asarray([0.05, 0.1, 0.02])
    w64, q64 = pk.free_body_pallas(rj.RK4, w, q, coef, n, h, interpret=True)
    assert w64.shape == (7, 4, 3) and q64.shape == (7, 4, 4)
    np.testing.assert_array_equal(w64[:, 2], w64[:, 1])
    np.testing.assert_array_equal(q64[:, 2], q64[:, 1])
    w32, q32 = pk.free_body_pallas(
        rj.RK4, w.astype(jnp.float32), q.astype(jnp.float32), coef, n, h, interpret=True
    )
    assert w32.dtype == jnp.float32
    np.testing.assert_allclose(w32, w64, rtol=0, atol=2e-6)
    np.testing.assert_allclose(q32, q64, rtol=0, atol=2e-6)
    hs = jnp.stack([h, 2 * h])
    mapped = jax.vmap(lambda h: pk.free_body_pallas(rj.RK4, w, q, coef, n, h, interpret=True))(hs)
    for i in range(2):
        one = pk.free_body_pallas(rj.RK4, w, q, coef, n, hs[i], interpret=True)
        np.testing.assert_allclose(mapped[0][i], one[0], rtol=0, atol=1e-15)
        np.testing.assert_allclose(mapped[1][i], one[1], rtol=0, atol=1e-15)


def test_simulate_takes_gpu_kernel_with_diffrax_gradients(on_gpu_kernel):
    """`simulate` through the GPU kernel: the Diffrax path's trajectory and statistics, and
    reverse-mode gradients (through Diffrax, the kernel having no adjoint) with respect to the
    moments, the initial state and the output times equal to the Diffrax path's, under
    `jax.jit`."""
    w, q = _inputs(3)
    jaxpr = jax.make_jaxpr(lambda w: rj.simulate(BODY, w, q, TS, solver=rj.RK4(), **FIXED).omega)
    assert "pallas_call" in str(jaxpr(w))
    fast = rj.simulate(BODY, w, q, TS, solver=rj.RK4(), **FIXED)
    slow = _diffrax_path(rj.RK4, w, q)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=2e-15)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=2e-15)
    assert int(fast.stats["num_steps"]) == int(slow.stats["num_steps"]) == 18  # 5 + 1 + 12

    def loss(I, w, ts, solver):
        tr = rj.simulate(rj.RigidBody(I), w, q, ts, solver=solver, **FIXED)
        q_end = tr.quat[:, -1, 1:] * jnp.arange(1.0, 4.0)
        return jnp.sum(tr.omega[:, 1:] ** 2) + jnp.sum(q_end)

    args = (jnp.asarray([1.0, 2.0, 3.0]), w, TS)
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2)), static_argnums=3)
    want = grads(*args, ExplicitRK(rj.RK4()))
    for g, r in zip(grads(*args, rj.RK4()), want, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-10, atol=1e-12)


def test_simulate_gpu_kernel_reports_max_steps(on_gpu_kernel):
    """An interval with more steps than `max_steps` is the same clear error as on the
    Diffrax path."""
    w, q = _inputs(2)
    with pytest.raises(rj.IntegrationError, match="max_steps"):
        rj.simulate(BODY, w, q, TS, solver=rj.RK4(), max_steps=4, **FIXED)


def test_served_only_where_checked(monkeypatch):
    """Not on the CPU; on a GPU only after a small batch, compiled, gave the interpreter's
    states: a kernel that fails to lower, or gives other numbers, warns once and is not
    served."""
    assert not pk.serves(rj.RK4(), jnp.float64)
    assert not pk.serves(ExplicitRK(rj.RK4()), jnp.float64)
    with pytest.warns(RuntimeWarning, match="Pallas kernel for RK4 in float64"):
        assert not pk._checked.__wrapped__(rj.RK4, "float64")  # Pallas can't compile for CPU
    run = pk.free_body_pallas

    def interpreted(*args, interpret=False, shift=0.0):
        w, q = run(*args, interpret=True)
        return w + (0.0 if interpret else shift), q

    monkeypatch.setattr(pk, "free_body_pallas", interpreted)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pk._checked.__wrapped__(rj.RK4, "float64")
    monkeypatch.setattr(pk, "free_body_pallas", lambda *a, **k: interpreted(*a, **k, shift=1e-6))
    with pytest.warns(RuntimeWarning, match="differ from Pallas' interpreter"):
        assert not pk._checked.__wrapped__(rj.RK4, "float64")


@pytest.fixture
def triton_modules(monkeypatch):
    """The list into which the text of each Triton module that Pallas builds goes (a private
    JAX function wrapped: skipped where this JAX lays it out otherwise)."""
    try:
        from jax._src.pallas.triton import lowering
    except ImportError as e:
        pytest.skip(f"this JAX has no Pallas Triton lowering where expected: {e}")
    modules = []
    lower = lowering.lower_jaxpr_to_triton_module

    def lower_and_keep(*args, **kwargs):
        result = lower(*args, **kwargs)
        modules.append(result.module.operation.get_asm())
        return result

    monkeypatch.setattr(lowering, "lower_jaxpr_to_triton_module", lower_and_keep)
    return modules


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_kernel_lowers_to_triton(triton_modules, dtype):
    """Lowered for CUDA on a machine without a GPU, the kernel takes Pallas' Triton backend
    (not Mosaic GPU, Pallas' default), whose module Triton takes (ops, dynamic loops, loads
    and stores, in float32 and float64), and the time loop is inside it:
    the lowered program is one Triton call and no loop of XLA's, also under `jax.vmap` (a
    sweep). The renormalisation is `1 / sqrt`, not `rsqrt`, which Triton lowers to the
    approximate `rsqrt.approx.f64` (seen in its PTX). What remains untested without a GPU,
    Triton's compile and the numbers, `serves` checks on the GPU before first use."""
    w, q = _inputs(pk.BLOCK + 5, dtype=dtype)
    coef = jnp.ones((3, 1), dtype)
    n, h = jnp.asarray([3, 4], jnp.int32), jnp.asarray([0.1, 0.2], dtype)
    run = functools.partial(pk.free_body_pallas, rj.RK4)
    for f, hs in ((run, h), (jax.vmap(run, in_axes=(None, None, None, None, 0)), h * h[:, None])):
        text = jax.jit(f).trace(w, q, coef, n, hs).lower(lowering_platforms=("cuda",)).as_text()
        assert text.count("__gpu$xla.gpu.triton") == 1 and "num_warps = 4 " in text
        assert "stablehlo.while" not in text
    assert len(triton_modules) == 2
    for module in triton_modules:
        assert re.findall(r'symbol = "(\w*sqrt\w*)"', module) in (["__nv_sqrt"], ["__nv_sqrtf"])
        assert module.count("scf.for") == 2  # the intervals and, inside, their steps
