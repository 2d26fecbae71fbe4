"""The heavy top, the 6-DOF body and the satellite on the fast path (the CPU kernel written
from their fields) against their Diffrax path on the same steps, independent SciPy references
and central differences; the scalar program against JAX itself."""

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
from rigidjax.kernels._components import Components
from rigidjax.kernels._objects import scalars
from rigidjax.kernels._scalar import unroll
from rigidjax.mechanics import heavy_top as ht
from rigidjax.mechanics import satellite, sixdof
from rigidjax.solvers import ExplicitRK

pytestmark = pytest.mark.skipif(
    shutil.which(_build._compiler()[0]) is None, reason="no C++ compiler ($CXX or c++)"
)

TS = jnp.linspace(0.0, 2.0, 5)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01)
TENSOR = np.array([[1.2, 0.1, -0.05], [0.1, 1.5, 0.02], [-0.05, 0.02, 1.9]])


def _no_warnings(run):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the fast path takes the model: no fallback warning
        return run()


@pytest.mark.parametrize("inertia", ["principal", "tensor"])
def test_heavy_top_fast_path(inertia):
    """A generic top (and one with a full tensor) with its attitude: the kernel's numbers are
    the Diffrax path's to 1e-13; the Euler–Poisson equations written in NumPy and integrated
    by DOP853 agree within RK4's error at h = 0.01."""
    I = np.diag([1.0, 1.4, 1.9]) if inertia == "principal" else TENSOR
    top = ht.HeavyTop(I if inertia == "tensor" else np.diag(I), 1.0, [0.1, -0.05, 0.2])
    w0, q0 = np.array([0.5, -1.0, 2.0]), np.array([0.9, 0.2, -0.3, 0.1]) / np.sqrt(0.95)
    fast = _no_warnings(
        lambda: ht.simulate_heavy_top(top, w0, ts=TS, q0=q0, solver=rj.RK4(), **FIXED)
    )
    slow = ht.simulate_heavy_top(top, w0, ts=TS, q0=q0, solver=ExplicitRK(rj.RK4()), **FIXED)
    for a, b in ((fast.omega, slow.omega), (fast.gamma, slow.gamma), (fast.quat, slow.quat)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)
    I_inv, mu = np.linalg.inv(I), 9.81 * np.array([0.1, -0.05, 0.2])

    def rhs(t, y):
        w, ga = y[:3], y[3:]
        return np.concatenate([I_inv @ (np.cross(ga, mu) - np.cross(w, I @ w)), np.cross(ga, w)])

    gamma0 = np.asarray(fast.gamma[0])
    ref = solve_ivp(rhs, (0, 2), np.r_[w0, gamma0], "DOP853", t_eval=TS, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(fast.omega, ref.y[:3].T, atol=1e-7)
    np.testing.assert_allclose(fast.gamma, ref.y[3:].T, atol=1e-7)


@pytest.mark.slow  # ~12 s: the kernel adjoint and the Diffrax path
def test_heavy_top_vmap_and_gradient():
    """`jax.vmap` over tops (the mapped tops join one kernel call) equals a loop; the gradient
    of the final energy w.r.t. the centre of mass equals the Diffrax path's and central
    differences."""

    def final(com, solver):
        top = ht.HeavyTop(jnp.array([1.0, 1.4, 1.9]), 1.0, com)
        tr = ht.simulate_heavy_top(
            top, jnp.array([0.5, -1.0, 2.0]), jnp.array([0.0, 0.6, 0.8]), TS, solver=solver, **FIXED
        )
        return jnp.sum(tr.omega[-1] ** 2) + tr.gamma[-1, 0]

    coms = jnp.array([[0.1, -0.05, 0.2], [0.0, 0.0, 0.3], [0.2, 0.1, 0.0]])
    mapped = jax.vmap(lambda c: final(c, rj.RK4()))(coms)
    for i in range(3):
        np.testing.assert_allclose(mapped[i], final(coms[i], rj.RK4()), rtol=1e-14)
    g = jax.grad(lambda c: final(c, rj.RK4()))(coms[0])
    np.testing.assert_allclose(
        g, jax.grad(lambda c: final(c, ExplicitRK(rj.RK4())))(coms[0]), rtol=1e-9
    )
    eps = 1e-6
    fd = [
        (final(coms[0] + eps * e, rj.RK4()) - final(coms[0] - eps * e, rj.RK4())) / (2 * eps)
        for e in jnp.eye(3)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_sixdof_and_satellite_fast_path():
    """A 6-DOF body with an off-centre force and the satellite (orbit + gravity gradient) on the
    kernel: equal to their Diffrax paths to 1e-12 (positions of order 1e4 for the satellite)."""
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]), mass=2.0)

    def wrench(t, state):
        return sixdof.wrench_at_point(
            jnp.array([jnp.sin(t), 0.0, 1.0]), jnp.array([0.1, 0.2, 0.0]), state.q
        )

    args = (
        body,
        jnp.zeros(3),
        jnp.array([1.0, 0.0, 0.0]),
        None,
        jnp.array([0.1, 0.5, -0.2]),
        TS,
        wrench,
    )
    fast = _no_warnings(lambda: sixdof.simulate_6dof(*args, solver=rj.RK4(), **FIXED))
    slow = sixdof.simulate_6dof(*args, solver=ExplicitRK(rj.RK4()), **FIXED)
    for name in ("R", "V", "quat", "omega"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=0, atol=1e-13)
    mu, radius = 398600.4418, 7000.0
    R0, V0 = satellite.circular_orbit(mu, radius)
    sat = (body, R0, V0, None, jnp.array([0.0, -1e-3, 0.0]), jnp.linspace(0.0, 60.0, 4), mu)
    kw = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=1.0)
    fast = _no_warnings(lambda: satellite.simulate_satellite(*sat, solver=rj.RK4(), **kw))
    slow = satellite.simulate_satellite(*sat, solver=ExplicitRK(rj.RK4()), **kw)
    np.testing.assert_allclose(fast.R, slow.R, rtol=1e-14, atol=0)
    np.testing.assert_allclose(fast.quat, slow.quat, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fast.omega, slow.omega, rtol=0, atol=1e-13)


def test_scalar_program_equals_jax():
    """`_scalar.unroll` evaluating a field's jaxpr with JAX on component arrays (the Diffrax
    path's field) gives JAX's own values for slices, matrix products, reductions, `where`,
    trigonometry, integer powers, norms, `pad` (in a gradient) and `error_if` checks."""

    def f(t, y, p):
        M = rj.quat.to_matrix(y[3:7])
        c = M.T @ p[:3]
        a = jnp.cross(c, jnp.array([1.0, 2.0, 3.0]) * c) + jnp.where(
            y[:3] > 0, y[:3] ** 3, jnp.sin(y[:3])
        )
        b = (
            jnp.linalg.norm(y[:3]) * jnp.tanh(t)
            + jnp.max(y)
            - jnp.prod(p[:2])
            + jnp.arctan2(y[0], y[1])
        )
        g = jax.grad(lambda z: jnp.sum(z[1:3] ** 2) + z[0] * z[2])(y[:3])
        return jnp.concatenate([a + b + g, jnp.exp(-y[3:7]) * jnp.sqrt(1 + y[3:7] ** 2)])

    rng = np.random.default_rng(1)
    B = 5
    y = rng.normal(size=(7, B))
    p = rng.normal(size=(3, B))
    t = 0.3
    closed = jax.make_jaxpr(f)(t, jnp.zeros(7), jnp.zeros(3))
    consts = [np.asarray(np.asarray(c), dtype=object) for c in closed.consts]
    ins = [
        scalars([jnp.asarray(t)], ()),
        scalars([jnp.asarray(r) for r in y], (7,)),
        scalars([jnp.asarray(r) for r in p], (3,)),
    ]
    (out,) = unroll(closed, Components(), consts, ins)
    got = np.stack([np.asarray(x) for x in out.reshape(-1)])
    want = jax.vmap(f, in_axes=(None, 1, 1), out_axes=1)(t, jnp.asarray(y), jnp.asarray(p))
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-14)


@pytest.mark.slow  # ~15 s: the gradient compiled on both paths
def test_sixdof_gradient_through_the_kernel():
    """Reverse mode through the 6-DOF body's kernel (the point of application of the force, a
    constant traced into the kernel's parameters, and the mass): equal to the Diffrax path's
    gradient and to central differences."""

    def final(a, mass, solver):
        def wrench(t, state):
            return sixdof.wrench_at_point(jnp.array([jnp.sin(t), 0.0, 1.0]), a, state.q)

        body = rj.RigidBody(jnp.array([1.5, 2.0, 2.5]), mass=mass)
        w0 = jnp.array([0.1, 0.5, -0.2])
        tr = sixdof.simulate_6dof(
            body, jnp.zeros(3), jnp.zeros(3), None, w0, TS, wrench, solver=solver, **FIXED
        )
        return jnp.sum(tr.omega[-1] ** 2) + jnp.sum(tr.R[-1] * jnp.arange(1.0, 4.0))

    x = (jnp.array([0.1, 0.2, 0.0]), jnp.array(2.0))
    g = jax.jit(jax.grad(lambda a, m: final(a, m, rj.RK4()), argnums=(0, 1)))(*x)
    slow = jax.grad(lambda a, m: final(a, m, ExplicitRK(rj.RK4())), argnums=(0, 1))(*x)
    np.testing.assert_allclose(g[0], slow[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(g[1], slow[1], rtol=1e-9)
    f = jax.jit(lambda a, m: final(a, m, rj.RK4()))
    eps = 1e-6
    fd_a = [(f(x[0] + eps * e, x[1]) - f(x[0] - eps * e, x[1])) / (2 * eps) for e in jnp.eye(3)]
    fd_m = (f(x[0], x[1] + eps) - f(x[0], x[1] - eps)) / (2 * eps)
    np.testing.assert_allclose(g[0], fd_a, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(g[1], fd_m, rtol=1e-6)
