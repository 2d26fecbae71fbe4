"""`simulate` with a torque on the fast path (the CPU kernel written from the JAX field) against
the Diffrax path on the same steps (`ExplicitRK(method)`, which never takes a kernel), SciPy's
DOP853 with the torque written in NumPy, and central differences."""

import shutil
import warnings

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax.kernels import _build
from rigidjax.solvers import ExplicitRK
from tests.helpers import rigid_body_dop853

pytestmark = pytest.mark.skipif(
    shutil.which(_build._compiler()[0]) is None, reason="no C++ compiler ($CXX or c++)"
)

TS = jnp.linspace(0.0, 1.0, 5)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.02)
MOMENTS = np.array([[1.0, 2.0, 3.0], [1.5, 1.7, 2.4], [2.0, 2.5, 3.5], [1.0, 1.0, 1.5]])
GAIN = jnp.array([0.3, 0.2, 0.1])  # closed over: lifted into the kernel's parameters
E_Z = jnp.array([0.0, 0.0, 1.0])


def damping(t, w, q):
    return -GAIN * w


def gravity_gradient(t, w, q):
    """3 n² c × (I c), c = Pᵀ e_Z (n² = 1/3, I = (1, 2, 3)): the gravity-gradient form."""
    c = rj.quat.to_matrix(q).T @ E_Z
    return jnp.cross(c, jnp.array([1.0, 2.0, 3.0]) * c)


def periodic_space(t, w, q):
    """A space-frame torque that depends on time (given with torque_frame="space")."""
    return jnp.array([0.5 * jnp.sin(3.0 * t), 0.2, jnp.where(t > 0.5, (t - 0.5) ** 3, 0.0)])


def _numpy(case):
    """The same torques in NumPy and SciPy (body frame), for DOP853."""
    if case == "damping":
        return lambda t, w, q: -np.asarray(GAIN) * w
    if case == "gravity_gradient":

        def gg(t, w, q):
            c = Rotation.from_quat(np.r_[q[1:], q[0]]).as_matrix().T @ np.array([0.0, 0.0, 1.0])
            return np.cross(c, np.array([1.0, 2.0, 3.0]) * c)

        return gg

    def space(t, w, q):
        K = np.array([0.5 * np.sin(3.0 * t), 0.2, (t - 0.5) ** 3 if t > 0.5 else 0.0])
        return Rotation.from_quat(np.r_[q[1:], q[0]]).inv().apply(K)

    return space


CASES = {"damping": damping, "gravity_gradient": gravity_gradient, "periodic_space": periodic_space}


def _inputs(B, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(B, 4))
    return jnp.asarray(rng.normal(size=(B, 3))), jnp.asarray(q / np.linalg.norm(q, axis=1)[:, None])


def _run(case, solver, body, w, q, ts=TS, **kw):
    frame = "space" if case == "periodic_space" else "body"
    return rj.simulate(
        body, w, q, ts, torque=CASES[case], torque_frame=frame, solver=solver, **FIXED, **kw
    )


@pytest.mark.parametrize("case", list(CASES))
def test_fast_path_equals_diffrax_path_and_scipy(case):
    """67 bodies with their own moments (a full block of 64 and a partial one): the kernel's
    numbers are the Diffrax path's to 1e-13, and SciPy's DOP853 at 1e-13 within RK4's error at
    h = 0.02 (up to ~2e-7 here)."""
    w, q = _inputs(67)
    moments = jnp.asarray(np.tile(MOMENTS, (17, 1))[:67])
    body = rj.RigidBody(moments)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the fast path takes every one of these torques
        fast = _run(case, rj.RK4(), body, w, q)
    slow = _run(case, ExplicitRK(rj.RK4()), body, w, q)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=1e-13)
    assert int(fast.stats["num_steps"]) == int(slow.stats["num_steps"])
    for i in (0, 5):
        w_ref, q_ref = rigid_body_dop853(np.asarray(moments[i]), w[i], q[i], TS, _numpy(case))
        np.testing.assert_allclose(fast.omega[i], w_ref, atol=1e-6)
        np.testing.assert_allclose(fast.quat[i], q_ref, atol=1e-6)


@pytest.mark.slow  # ~18 s: both reverse modes and the forward runs for the differences
def test_gradients_match_central_differences_and_the_diffrax_path():
    """Reverse mode through the kernel (its discrete adjoint): w.r.t. the moments, the torque's
    closed-over gain, the initial state and the output times, equal to the Diffrax path's
    gradient and to central differences of the kernel's own forward run."""
    w0, q0 = _inputs(3, seed=2)

    def loss(solver, moments, gain, w0, ts):
        def torque(t, w, q):
            c = rj.quat.to_matrix(q).T @ E_Z
            return jnp.cross(c, moments * c) - gain * w * jnp.cos(t)

        tr = rj.simulate(rj.RigidBody(moments), w0, q0, ts, torque=torque, solver=solver, **FIXED)
        return jnp.sum(tr.omega[:, -1] ** 2) + jnp.sum(tr.quat[:, -1, 1:] * jnp.arange(3.0))

    args = (jnp.array([1.5, 2.0, 3.0]), jnp.array([0.3, 0.2, 0.1]), w0, TS)
    fast = jax.jit(jax.grad(lambda *a: loss(rj.RK4(), *a), argnums=(0, 1, 2, 3)))(*args)
    slow = jax.jit(jax.grad(lambda *a: loss(ExplicitRK(rj.RK4()), *a), argnums=(0, 1, 2, 3)))(*args)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-11)
    f = jax.jit(lambda *a: loss(rj.RK4(), *a))
    eps = 1e-6
    for k, x in enumerate(args):
        flat = np.asarray(x, float).ravel()
        for j in range(flat.size):
            if k == 3 and j not in (2, 4):  # output times: an inner and the last one
                continue
            dx = np.zeros_like(flat)
            dx[j] = eps
            hi = [*args]
            lo = [*args]
            hi[k] = jnp.asarray((flat + dx).reshape(np.shape(x)))
            lo[k] = jnp.asarray((flat - dx).reshape(np.shape(x)))
            fd = (f(*hi) - f(*lo)) / (2 * eps)
            np.testing.assert_allclose(np.ravel(fast[k])[j], fd, rtol=1e-6, atol=1e-8)


def test_vmap_over_a_traced_gain_is_a_loop():
    """A sweep: `jax.vmap` over one-body `simulate` with the torque's gain traced (the sweep's
    layout); the mapped bodies join one kernel call with per-row parameters."""
    w0, q0 = _inputs(1, seed=4)
    gains = jnp.array([0.0, 0.5, 2.0])

    def one(g):
        tr = rj.simulate(
            rj.RigidBody(jnp.array([1.0, 2.0, 3.0])),
            w0[0],
            q0[0],
            TS,
            torque=lambda t, w, q: -g * w,
            solver=rj.RK4(),
            **FIXED,
        )
        return tr.omega[-1]

    mapped = jax.jit(jax.vmap(one))(gains)
    for i, g in enumerate(gains):
        np.testing.assert_allclose(mapped[i], one(g), rtol=0, atol=1e-14)
    assert not np.allclose(mapped[0], mapped[2])


@pytest.mark.slow  # ~14 s
def test_nested_vmap_shares_unmapped_blocks():
    """Two nested `jax.vmap`s (gains outside, moments inside) over one-body solves: the kernel
    reads each parameter block, the steps and the initial state through its own leading
    dimensions (size 1 where not mapped), and every member equals its own solve; the
    gradient w.r.t. the gains (a block mapped by the outer map only) equals the Diffrax
    path's."""
    w0, q0 = _inputs(1, seed=5)
    gains = jnp.array([0.0, 0.4, 1.1])
    moments = jnp.array([[1.0, 2.0, 3.0], [2.0, 2.5, 3.5]])

    def one(g, I, solver=None):
        tr = rj.simulate(
            rj.RigidBody(I), w0[0], q0[0], TS, torque=lambda t, w, q: -g * w * jnp.cos(t),
            solver=solver or rj.RK4(), **FIXED,
        )  # fmt: skip
        return tr.omega[-1]

    inner = jax.vmap(one, in_axes=(None, 0))
    mapped = jax.jit(jax.vmap(inner, in_axes=(0, None)))(gains, moments)
    alone = jax.jit(one)  # one compile for the six members' own solves
    for i, g in enumerate(gains):
        for j, I in enumerate(moments):
            np.testing.assert_allclose(mapped[i, j], alone(g, I), rtol=0, atol=1e-14)

    def loss(gs, solver):
        return jnp.sum(jax.vmap(lambda g: jax.vmap(lambda I: one(g, I, solver))(moments))(gs))

    fast, path = (
        jax.jit(jax.grad(lambda gs, s=s: loss(gs, s))) for s in (rj.RK4(), ExplicitRK(rj.RK4()))
    )
    np.testing.assert_allclose(fast(gains), path(gains), rtol=1e-10)


def test_unsupported_torque_falls_back_with_one_warning():
    """A torque with a primitive that has no scalar form (a host callback) runs on the Diffrax
    path, with one warning naming it, and the Diffrax path's numbers."""

    def host(t, w, q):
        shape = jax.ShapeDtypeStruct((3,), w.dtype)
        return jax.pure_callback(lambda w: -0.1 * np.asarray(w), shape, w, vmap_method="sequential")

    w, q = _inputs(2)
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
    with pytest.warns(RuntimeWarning, match="pure_callback") as record:
        fast = rj.simulate(body, w, q, TS, torque=host, solver=rj.RK4(), **FIXED)
    assert len([r for r in record if "fast path" in str(r.message)]) == 1
    slow = rj.simulate(body, w, q, TS, torque=damping, solver=ExplicitRK(rj.RK4()), **FIXED)
    ref = rj.simulate(
        body, w, q, TS, torque=lambda t, w, q: -0.1 * w, solver=ExplicitRK(rj.RK4()), **FIXED
    )
    np.testing.assert_allclose(fast.omega, ref.omega, rtol=0, atol=1e-14)
    assert not np.allclose(slow.omega, ref.omega)


@pytest.mark.parametrize(
    "options",
    [dict(solver=rj.RK4(), **FIXED), pytest.param({}, marks=pytest.mark.slow)],
    ids=["fixed", "tol"],
)
def test_a_users_check_and_callback_run_on_the_diffrax_path(options):
    """A user's `equinox.error_if` and `jax.debug.callback` inside the torque are not dropped:
    the torque runs on the Diffrax path (one warning naming them), where the check raises its
    message and the callback runs. The library's own checks (`quat.to_matrix`'s) keep the
    fast path."""
    seen = []

    def checked(t, w, q):
        return -0.1 * eqx.error_if(w, t > 0.5, "the torque's own check: t > 0.5")

    def printing(t, w, q):
        jax.debug.callback(lambda t: seen.append(float(t)), t)
        return -0.1 * w

    w, q = _inputs(2)
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
    with pytest.warns(RuntimeWarning, match="equinox.error_if"):
        with pytest.raises(eqx.EquinoxRuntimeError, match="the torque's own check"):
            rj.simulate(body, w, q, TS, torque=checked, **options)
    with pytest.warns(RuntimeWarning, match="debug_callback"):
        rj.simulate(body, w, q, TS, torque=printing, **options)
    assert max(seen) == TS[-1]  # the field evaluated at the last output time
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rj.simulate(body, w, q, TS, torque=gravity_gradient, **options)
