"""The Darboux problem on the fast path: rotation-vector (with its shadow switch), quaternion
and Poisson-matrix kinematics driven by a JAX ω(t) at fixed explicit steps run on the CPU
kernel written from the field (ω included), against their Diffrax path on the same steps,
SciPy's `solve_ivp` of the Poisson equation, and central differences."""

import shutil
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rigidjax as rj
from rigidjax.kernels import _build
from rigidjax.solvers import ExplicitRK

pytestmark = pytest.mark.skipif(
    shutil.which(_build._compiler()[0]) is None, reason="no C++ compiler ($CXX or c++)"
)

TS = jnp.linspace(0.0, 2.0, 5)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01)
P0 = np.asarray(rj.quat.to_matrix(rj.quat.normalize(jnp.array([0.9, 0.1, -0.3, 0.2]))))


def omega(a, spin=1.0):
    return lambda t: spin * jnp.stack([a * jnp.sin(t), jnp.cos(2.0 * t), 0.3 + 0.1 * t * a])


def _darboux(a, method, frame, solver, spin=1.0, ts=TS, **kw):
    return rj.darboux(omega(a, spin), ts, P0, frame, method, solver=solver, **FIXED, **kw)


def _poisson(a, frame, spin=1.0):
    """Ṗ = ω × P (space) or P (Ω × E) (body), in NumPy, SciPy's DOP853 at 1e-13."""

    def f(t, y):
        P = y.reshape(3, 3)
        w = spin * np.array([a * np.sin(t), np.cos(2 * t), 0.3 + 0.1 * t * a])
        W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        return (W @ P if frame == "space" else P @ W).ravel()

    sol = solve_ivp(f, (0, 2), P0.ravel(), "DOP853", t_eval=np.asarray(TS), rtol=1e-13, atol=1e-13)
    return sol.y.T.reshape(-1, 3, 3)


def _kernel_call(fn, *args) -> bool:
    return "ffi_call" in str(jax.make_jaxpr(fn)(*args))


@pytest.mark.parametrize(
    ("method", "frame"), [("quat", "space"), ("quat", "body"), ("matrix", "body")]
)
def test_fast_path_equals_diffrax_path_and_scipy(method, frame):
    """The kernel (no fallback warning) gives the Diffrax path's rotations on the same RK4
    steps to 1e-13, and SciPy's within RK4's error at dt = 0.01."""
    a = 0.7
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fast = _darboux(a, method, frame, rj.RK4())
    assert _kernel_call(lambda x: _darboux(x, method, frame, rj.RK4()), a)
    assert not _kernel_call(lambda x: _darboux(x, method, frame, ExplicitRK(rj.RK4())), a)
    slow = _darboux(a, method, frame, ExplicitRK(rj.RK4()))
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast, _poisson(a, frame), rtol=0, atol=1e-8)


@pytest.mark.slow  # ~11 s; the kernel adjoint is tested quick in test_free_body_kernel
def test_gradient_through_omega_and_vmap():
    """The gradient of the final rotation w.r.t. a parameter of ω(t) through the kernel's
    adjoint: the Diffrax path's to 1e-10 and central differences to 1e-7; under `jax.vmap` over
    the parameter the rotations are those of separate solves."""

    def loss(a, solver):
        P = _darboux(a, "quat", "space", solver)
        return jnp.sum(P[-1] * jnp.arange(9.0).reshape(3, 3))

    a, eps = 0.7, 1e-5
    g = jax.grad(loss)(a, rj.RK4())
    np.testing.assert_allclose(g, jax.grad(loss)(a, ExplicitRK(rj.RK4())), rtol=1e-10)
    fd = (loss(a + eps, rj.RK4()) - loss(a - eps, rj.RK4())) / (2 * eps)
    np.testing.assert_allclose(g, fd, rtol=1e-7)
    gains = jnp.array([0.0, 0.7, 1.5])
    mapped = jax.vmap(lambda x: _darboux(x, "quat", "space", rj.RK4()))(gains)
    for i, x in enumerate(gains):
        np.testing.assert_allclose(mapped[i], _darboux(x, "quat", "space", rj.RK4()), atol=1e-14)


@pytest.mark.parametrize("frame", ["space", "body"])
def test_rotation_vector_with_its_shadow_switch(frame):
    """`"rotvec"` (the default) at 5 rad/s: θ passes |θ| = π several times and is replaced by
    its shadow after those steps, inside the kernel (Model::E). The rotations equal the Diffrax
    path's on the same steps to 1e-13 (measured 2.5e-15) and SciPy's Poisson solution within
    RK4's error (measured 4.5e-8); every saved state has |θ| ≤ π (without the switch, θ would
    reach the singularity of Z at 2π)."""
    a, spin = 0.7, 5.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fast, theta = _darboux(a, "rotvec", frame, rj.RK4(), spin, return_state=True)
    assert _kernel_call(lambda x: _darboux(x, "rotvec", frame, rj.RK4(), spin), a)
    slow = _darboux(a, "rotvec", frame, ExplicitRK(rj.RK4()), spin)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast, _poisson(a, frame, spin), rtol=0, atol=2e-7)
    assert np.all(np.linalg.norm(theta, axis=-1) <= np.pi * (1 + 1e-12))


@pytest.mark.slow  # ~19 s: the gradient compiled on both paths
def test_rotation_vector_gradient_across_shadow_switches():
    """The kernel's adjoint through the shadow map (Model::ET): the gradient w.r.t. a parameter
    of ω(t) and w.r.t. the output times (the reverse mode that carries the steps' times)
    equals the Diffrax path's to 1e-9, and central differences of the parameter's to 1e-6."""
    ts = jnp.linspace(0.0, 2.0, 3)

    def loss(a, ts, solver):
        P = _darboux(a, "rotvec", "space", solver, 5.0, ts)
        return jnp.sum(P[1:] * jnp.arange(9.0).reshape(3, 3))

    a, eps = 0.7, 1e-6
    for argnums in (0, (0, 1)):
        g = jax.grad(loss, argnums)(a, ts, rj.RK4())
        want = jax.grad(loss, argnums)(a, ts, ExplicitRK(rj.RK4()))
        for x, y in zip(jax.tree.leaves(g), jax.tree.leaves(want), strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9)
    fd = (loss(a + eps, ts, rj.RK4()) - loss(a - eps, ts, rj.RK4())) / (2 * eps)
    np.testing.assert_allclose(jax.grad(loss)(a, ts, rj.RK4()), fd, rtol=1e-6)
