"""The CPU kernels of `simulate(..., solver=method, ConstantStepSize, dt0)` against the Diffrax
path on the same steps (`ExplicitRK(method)`, which never takes a kernel), against SciPy and
against central differences."""

import concurrent.futures
import errno
import fcntl
import shutil
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.kernels import _build
from rigidjax.kernels import free_body as kernel
from rigidjax.solvers import ExplicitRK
from tests.helpers import rigid_body_dop853

# Skipped only without a C++ compiler: where there is one, a kernel that fails to build fails
# these tests (its warning names the compiler's error) instead of skipping them.
pytestmark = pytest.mark.skipif(
    shutil.which(_build._compiler()[0]) is None, reason="no C++ compiler ($CXX or c++)"
)

BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
TS = jnp.linspace(0.0, 1.0, 5)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.02)
QUICK_METHODS = (diffrax.Bosh3, diffrax.Tsit5, diffrax.Dopri8)  # others: slow tests


def _inputs(B, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(B, 4))
    return jnp.asarray(rng.normal(size=(B, 3))), jnp.asarray(q / np.linalg.norm(q, axis=1)[:, None])


def _both(*args, body=BODY, ts=TS, **kw):
    fast = rj.simulate(body, *args, ts=ts, solver=rj.RK4(), **FIXED, **kw)
    slow = rj.simulate(body, *args, ts=ts, solver=ExplicitRK(rj.RK4()), **FIXED, **kw)
    return fast, slow


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_kernel_builds_and_serves(dtype):
    """With a compiler the kernel builds (otherwise the tests below would compare the Diffrax
    path with itself); `ExplicitRK(RK4())`, the Diffrax path, is never served."""
    assert kernel.serves(rj.RK4(), dtype)
    assert not kernel.serves(ExplicitRK(rj.RK4()), dtype)


def test_batch_equals_diffrax_path():
    w, q = _inputs(67)  # one full block of 64 bodies and a partial one
    fast, slow = _both(w, q)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=1e-13)
    for key in ("num_steps", "num_accepted_steps", "num_rejected_steps", "num_valid"):
        assert int(fast.stats[key]) == int(slow.stats[key])
    assert fast.result == diffrax.RESULTS.successful


@pytest.mark.parametrize(
    "method",
    [
        pytest.param(m, marks=[] if m in QUICK_METHODS else pytest.mark.slow, id=m.__name__)
        for m in kernel.METHODS
        if m is not rj.RK4  # the test above
    ],
)
def test_each_method_equals_diffrax_path(method):
    """Every tableau with a kernel (RK4 above): the same numbers as `ExplicitRK(method)`, the
    Diffrax path, with stages that never reach the solution (first-same-as-last) dropped. The
    kernels build on first use (6-12 s each), so the quick suite takes three."""
    w, q = _inputs(67)
    kw = dict(ts=TS, stepsize_controller=diffrax.ConstantStepSize(), dt0=0.1)
    assert kernel.serves(method(), jnp.float64)
    fast = rj.simulate(BODY, w, q, solver=method(), **kw)
    slow = rj.simulate(BODY, w, q, solver=ExplicitRK(method()), **kw)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=1e-13)


def test_tableau_drops_only_dead_stages():
    """The kernels' tableau: Diffrax's coefficients, without the stages that reach neither the
    solution nor a stage that does (the last, first-same-as-last stage of Dopri5/Dopri8)."""
    for method, stages in (
        (rj.RK4, 4),
        (diffrax.Bosh3, 3),
        (diffrax.Dopri5, 6),
        (diffrax.Dopri8, 13),
    ):
        a = kernel.coefficients(method)
        tab = method.tableau
        assert a.shape == (stages + 1, stages)
        np.testing.assert_array_equal(a[-1], tab.b_sol[:stages])
        assert not np.any(tab.b_sol[stages:])
        for i in range(1, stages):
            np.testing.assert_array_equal(a[i, :i], tab.a_lower[i - 1])


@pytest.mark.parametrize("case", ["one_body", "per_body_moments", "dopri8"])
def test_matches_scipy(case):
    """Against SciPy DOP853 at 1e-13 (tests.helpers): one body with the moments shared, a batch
    with its own moments per body (the kernel's per-body coefficients), and the Dopri8 kernel
    (the benchmark's high-accuracy configuration) at h = 0.1."""
    B = 1 if case == "one_body" else 4  # (4, 3): principal moments (a (3, 3) is a tensor)
    w, q = _inputs(B, seed=3)
    moments = np.array([[1.0, 2.0, 3.0], [1.5, 1.7, 2.4], [2.0, 2.5, 3.5], [1.0, 1.0, 1.5]])[:B]
    if case == "one_body":
        tr = rj.simulate(BODY, w[0], q[0], TS, solver=rj.RK4(), **FIXED)
        omega, quat = tr.omega[None], tr.quat[None]
    else:
        solver, dt0 = (diffrax.Dopri8(), 0.1) if case == "dopri8" else (rj.RK4(), 0.02)
        tr = rj.simulate(
            rj.RigidBody(jnp.asarray(moments)),
            w,
            q,
            TS,
            solver=solver,
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=dt0,
        )
        omega, quat = tr.omega, tr.quat
    atol = 1e-10 if case == "dopri8" else 1e-7  # RK4 at h = 0.02: ~1e-8; Dopri8 at 0.1: ~1e-11
    for i in range(B):
        w_ref, q_ref = rigid_body_dop853(moments[i], w[i], q[i], TS)
        np.testing.assert_allclose(omega[i], w_ref, atol=atol)
        np.testing.assert_allclose(quat[i], q_ref, atol=atol)


def test_vmap_single_bodies_and_per_row_times():
    w, q = _inputs(5)

    def run(solver, w, q, t1):
        ts = jnp.stack([0.0, 0.5 * t1, t1])
        return rj.simulate(BODY, w, q, ts, solver=solver, **FIXED).quat

    for t1 in (jnp.ones(5), jnp.linspace(0.5, 1.5, 5)):  # shared steps, then each its own
        fast = jax.vmap(lambda *a: run(rj.RK4(), *a))(w, q, t1)
        slow = jax.vmap(lambda *a: run(ExplicitRK(rj.RK4()), *a))(w, q, t1)
        np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-13)


def test_float32():
    w, q = _inputs(9)
    ts = TS.astype(jnp.float32)
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0], jnp.float32))
    fast, slow = _both(w.astype(jnp.float32), q.astype(jnp.float32), body=body, ts=ts)
    assert fast.quat.dtype == jnp.float32
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=2e-6)


@pytest.mark.slow  # two reverse-mode compiles of the Diffrax loop: ~30 s
def test_gradient_is_the_diffrax_paths():
    w, q = _inputs(3)

    def loss(I, solver):
        tr = rj.simulate(rj.RigidBody(I), w, q, TS, solver=solver, **FIXED)
        return jnp.sum(tr.quat[:, -1] * jnp.arange(4.0)) + jnp.sum(tr.omega**2)

    I = jnp.array([1.0, 2.0, 2.5])  # inside the triangle inequality, for the differences
    fast = jax.jit(jax.grad(loss), static_argnums=1)(I, rj.RK4())
    slow = jax.grad(loss)(I, ExplicitRK(rj.RK4()))
    np.testing.assert_allclose(fast, slow, rtol=1e-12)
    eps = 1e-6
    fd = [
        (loss(I.at[i].add(eps), rj.RK4()) - loss(I.at[i].add(-eps), rj.RK4())) / (2 * eps)
        for i in range(3)
    ]
    np.testing.assert_allclose(fast, fd, rtol=1e-6)


def test_gradient_over_several_blocks_and_unequal_intervals():
    """The adjoint reuses one state buffer per thread across its 64-body blocks, grown when an
    interval has more steps than the ones before (reversed: 5, then 20, then 5 steps here):
    per-body gradients of the initial Ω in four different blocks against central
    differences."""
    B = 200
    w, q = _inputs(B, seed=5)
    I = jnp.asarray(np.random.default_rng(6).uniform(1.5, 2.5, size=(B, 3)))
    ts = jnp.array([0.0, 0.1, 0.5, 0.6])  # 5, 20, 5 steps of 0.02
    weights = jnp.asarray(np.random.default_rng(8).normal(size=(B, 4, 7)))

    @jax.jit
    def loss(w):
        tr = rj.simulate(rj.RigidBody(I), w, q, ts, solver=rj.RK4(), **FIXED, check=False)
        return jnp.sum(jnp.concatenate([tr.omega, tr.quat], -1) * weights)

    grad = jax.jit(jax.grad(loss))(w)
    eps = 1e-6
    for b in (0, 70, 130, 199):  # blocks 0, 1, 2, 3
        for j in range(3):
            d = jnp.zeros_like(w).at[b, j].set(eps)
            fd = (loss(w + d) - loss(w - d)) / (2 * eps)
            np.testing.assert_allclose(grad[b, j], fd, rtol=1e-7, atol=1e-9)


def test_gradient_of_a_jitted_function():
    """`jax.grad(jax.jit(f))`: the kernel's derivative rule is traced inside the jit (nothing
    may be closed over); the same gradient as `jax.jit(jax.grad(f))`."""
    w, q = _inputs(2)

    def f(x):
        tr = rj.simulate(rj.RigidBody(x[:3]), x[3:6], None, TS, solver=rj.RK4(), **FIXED)
        return jnp.sum(tr.omega[-1] * jnp.array([1.0, -2.0, 0.5])) + tr.quat[-1, 1]

    x = jnp.concatenate([jnp.array([1.0, 2.0, 2.5]), w[0]])
    np.testing.assert_allclose(jax.grad(jax.jit(f))(x), jax.jit(jax.grad(f))(x), rtol=1e-13)


@pytest.mark.slow  # ~45 s: forward mode and second order compile the Diffrax path twice
def test_forward_mode_and_hessian_with_default_options():
    """`jax.jvp` and `jax.hessian` through the kernel with the default adjoint (issue 34): the
    tangent equals `jax.jacrev`'s Jacobian applied to it and central differences; the
    Hessian of a scalar loss equals central differences of its gradient."""
    w, q = _inputs(2)

    def f(I):
        return rj.simulate(rj.RigidBody(I), w, q, TS, solver=rj.RK4(), **FIXED).omega

    I, v = jnp.array([1.5, 2.0, 3.0]), jnp.array([0.3, -0.2, 0.5])
    _, tangent = jax.jvp(f, (I,), (v,))
    np.testing.assert_allclose(tangent, jax.jacrev(f)(I) @ v, rtol=0, atol=1e-12)
    eps = 1e-6
    central = (f(I + eps * v) - f(I - eps * v)) / (2 * eps)
    np.testing.assert_allclose(tangent, central, rtol=0, atol=1e-8)

    def loss(I):
        return jnp.sum(f(I) ** 2)

    grad = jax.grad(loss)
    hessian = jax.hessian(loss)(I)
    np.testing.assert_allclose(
        hessian @ v, (grad(I + eps * v) - grad(I - eps * v)) / (2 * eps), atol=1e-7
    )


@pytest.mark.parametrize("case", ["nonfinite", "max_steps"])
def test_failures_as_the_diffrax_path(case):
    w, q = _inputs(4)
    kw = dict(max_steps=10) if case == "max_steps" else {}
    w = w.at[2].set(1e200) if case == "nonfinite" else w
    fast, slow = _both(w, q, throw=False, **kw)
    assert fast.result == slow.result != diffrax.RESULTS.successful
    assert int(fast.stats["num_valid"]) == int(slow.stats["num_valid"])
    assert int(fast.stats["num_steps"]) == int(slow.stats["num_steps"])
    keep = np.isfinite(np.asarray(slow.quat))
    np.testing.assert_allclose(np.asarray(fast.quat)[keep], np.asarray(slow.quat)[keep], atol=1e-13)
    with pytest.raises(rj.IntegrationError, match="between t = 0 and t = 0.25"):
        rj.simulate(BODY, w, q, TS, solver=rj.RK4(), **FIXED, **kw)


def test_no_compiler_is_a_clear_failure(monkeypatch, tmp_path):
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    with pytest.raises(_build.KernelUnavailable, match="no C\\+\\+ compiler"):
        _build.build("model")


def _fake_compiler(monkeypatch, tmp_path) -> Path:
    """$CXX a script that records each compilation in the returned file, takes 1 s, and writes
    an empty library; the user's cache in tmp_path."""
    calls = tmp_path / "calls"
    fake = tmp_path / "fake-c++"
    fake.write_text(
        "#!/bin/sh\n"
        'if [ "$1" = --version ]; then echo fake 1; exit 0; fi\n'
        f"echo compile >> {calls}; sleep 1\n"
        'while [ $# -gt 1 ]; do if [ "$1" = -o ]; then touch "$2"; fi; shift; done\n'
    )
    fake.chmod(0o755)
    monkeypatch.setenv("CXX", str(fake))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return calls


def test_processes_needing_one_kernel_compile_it_once(monkeypatch, tmp_path):
    """Two builds of the same new kernel at once (threads here; each holds its own lock file
    descriptor, as separate processes do): one compiles it, the other waits and finds it."""
    calls = _fake_compiler(monkeypatch, tmp_path)
    headers = (("model.h", "// one kernel"),)
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        paths = list(pool.map(lambda _: _build.build("model", headers), range(2)))
    assert paths[0] == paths[1] and paths[0].exists()
    assert calls.read_text().split() == ["compile"]


def test_the_linked_handlers_compile_once_for_every_model(monkeypatch, tmp_path):
    """The units every kernel links (the XLA FFI handlers) are one cached object file: a
    second model compiles only itself (its object, then the link), and links the same one."""
    calls = _fake_compiler(monkeypatch, tmp_path)
    link = (("model_ffi", (("model_layout.h", "// layout"),)),)
    first = _build.build("model", (("model.h", "// model 1"),), link)
    second = _build.build("model", (("model.h", "// model 2"),), link)
    assert first != second and first.exists() and second.exists()
    assert calls.read_text().split() == ["compile"] * (1 + 2 + 2)
    assert len(list((tmp_path / "cache").rglob("model_ffi-*.o"))) == 1
    assert _build.build("model", (("model.h", "// model 1"),), link) == first
    assert calls.read_text().split() == ["compile"] * 5
    # changed handlers: their object and every library that links them built anew
    changed = (("model_ffi", (("model_layout.h", "// another layout"),)),)
    assert _build.build("model", (("model.h", "// model 1"),), changed) != first
    assert calls.read_text().split() == ["compile"] * (5 + 1 + 2)


def test_a_file_system_without_locks_still_builds(monkeypatch, tmp_path):
    calls = _fake_compiler(monkeypatch, tmp_path)

    def refuse(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", refuse)
    assert _build.build("model", (("model.h", "// no lock"),)).exists()
    assert calls.read_text().split() == ["compile"]


@pytest.mark.parametrize(
    "case",
    [
        "batch",
        "one_body",
        pytest.param("vmapped_times", marks=pytest.mark.slow),  # ~9 s
        "checkpointed",
        "dopri8",
        "bosh3",
    ],
)
def test_adjoint_matches_central_differences(case):
    """The kernel's reverse mode against central differences of its forward run, along a
    random direction of every input (initial states, per-body moments, output times)."""
    rng = np.random.default_rng(7)
    B = 1 if case == "one_body" else 5
    w, q = _inputs(B, seed=11)
    I = jnp.asarray(rng.uniform(1.5, 2.5, size=(B, 3)))
    # off the dt0 grid, so that the differences never change a step count
    ts = jnp.array([0.0, 0.313, 0.671, 1.029])
    # checkpointed: more than 2048 steps an interval (kStoreAll in model.cc): segments
    dt0 = 1.4e-4 if case == "checkpointed" else 0.02
    if case == "checkpointed":
        assert np.min(np.diff(np.asarray(ts))) / dt0 > 2048
    solver = {"dopri8": diffrax.Dopri8(), "bosh3": diffrax.Bosh3()}.get(case, rj.RK4())
    weights = jnp.asarray(rng.normal(size=(4, 7)))

    def loss(w, q, I, ts):
        def one(w, q, I, ts):
            tr = rj.simulate(
                rj.RigidBody(I),
                w,
                q,
                ts,
                solver=solver,
                stepsize_controller=diffrax.ConstantStepSize(),
                dt0=dt0,
                check=False,  # the perturbed q0 is off the unit sphere by eps
            )
            return jnp.sum(jnp.concatenate([tr.omega, tr.quat], -1) * weights)

        if case == "one_body":
            return one(w[0], q[0], I[0], ts)
        if case == "vmapped_times":
            shifts = jnp.linspace(0.0, 0.2, B)[:, None]
            return jnp.sum(jax.vmap(one)(w, q, I, ts + shifts * jnp.array([0, 1, 1, 1.0])))
        return one(w, q, I, ts)

    x = (w, q, I, ts)
    v = tuple(jnp.asarray(rng.normal(size=a.shape)) for a in x)
    v = (v[0], v[1], v[2], v[3].at[0].set(0.0))  # keep t0 fixed
    grad = jax.grad(loss, argnums=(0, 1, 2, 3))(*x)
    along = sum(jnp.sum(g * d) for g, d in zip(grad, v, strict=True))
    eps = 1e-6
    plus = loss(*(a + eps * d for a, d in zip(x, v, strict=True)))
    minus = loss(*(a - eps * d for a, d in zip(x, v, strict=True)))
    np.testing.assert_allclose(along, (plus - minus) / (2 * eps), rtol=2e-6)


def test_step_count_beyond_int32_is_max_steps():
    """1e10 steps in an interval (more than int32 holds) stop at max_steps, as Diffrax does."""
    w, q = _inputs(2)
    kw = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=1e-9, max_steps=50)
    ts = jnp.array([0.0, 10.0])
    fast = rj.simulate(BODY, w, q, ts, solver=rj.RK4(), throw=False, **kw)
    slow = rj.simulate(BODY, w, q, ts, solver=ExplicitRK(rj.RK4()), throw=False, **kw)
    assert fast.result == slow.result == diffrax.RESULTS.max_steps_reached
    assert int(fast.stats["num_steps"]) == int(slow.stats["num_steps"]) == 50
    with pytest.raises(rj.IntegrationError, match="max_steps = 50"):
        rj.simulate(BODY, w, q, ts, solver=rj.RK4(), **kw)
