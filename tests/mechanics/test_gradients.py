"""Gradients through whole trajectories: reverse and forward mode against finite differences."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import RK4, RigidBody, quat, simulate

TS = jnp.linspace(0.0, 3.0, 4)
Q_REF = jnp.array([0.9, 0.1, -0.3, 0.2]) / jnp.linalg.norm(jnp.array([0.9, 0.1, -0.3, 0.2]))


class LinearDamping(eqx.Module):
    """A torque with trainable parameters: K = −c ⊙ Ω + k0 (body frame)."""

    c: jax.Array
    k0: jax.Array

    def __call__(self, t, w, q):
        return -self.c * w + self.k0


def unpack(x):
    # inertia moments, initial Ω, tangent-space attitude perturbation (3, not 4 numbers), torque
    return x[:3], x[3:6], quat.retract(Q_REF, x[6:9]), LinearDamping(x[9:12], x[12:15])


X0 = jnp.array([1.0, 2.0, 2.5, 0.3, 1.0, -0.4, 0.0, 0.0, 0.0, 0.05, 0.1, 0.02, 0.1, -0.1, 0.05])
WEIGHTS = jnp.arange(1.0, 8.0)


def loss(x, kinematics, adjoint):
    moments, w0, q0, torque = unpack(x)
    traj = simulate(
        RigidBody(moments),
        w0,
        q0,
        TS,
        torque=torque,
        kinematics=kinematics,
        rtol=1e-12,
        atol=1e-12,
        adjoint=adjoint,
    )
    return jnp.sum(jnp.concatenate([traj.omega[-1], traj.quat[-1]]) * WEIGHTS)


def _directional_fd(f, x, v, h=1e-5):
    return (f(x + h * v) - f(x - h * v)) / (2 * h)


@pytest.mark.parametrize(
    "kinematics",
    # ~30 s each (compiling reverse mode through the adaptive solve): with the slow tests
    # (the quick suite compares reverse with forward mode: test_forward_mode_matches_reverse)
    [
        pytest.param(k, marks=pytest.mark.slow)
        for k in ("quat", "rotvec", "geometric", "matrix", "euler", "cayley_klein")
    ],
)
def test_reverse_mode_every_kinematics(kinematics):
    # one compilation: the finite differences use the value of the same program as the gradient
    value_and_grad = jax.jit(
        jax.value_and_grad(lambda x: loss(x, kinematics, diffrax.RecursiveCheckpointAdjoint()))
    )
    g = value_and_grad(X0)[1]
    f = lambda x: value_and_grad(x)[0]  # noqa: E731
    assert np.all(np.isfinite(g))
    for seed in range(2):
        v = jax.random.normal(jax.random.PRNGKey(seed), X0.shape)
        np.testing.assert_allclose(g @ v, _directional_fd(f, X0, v), rtol=1e-6, atol=1e-8)


@pytest.mark.slow
def test_forward_mode_matches_reverse():
    """`diffrax.ForwardMode` (needed by optimistix's Jacobians) gives the same derivatives."""
    v = jax.random.normal(jax.random.PRNGKey(7), X0.shape)
    _, fwd = jax.jvp(lambda x: loss(x, "quat", diffrax.ForwardMode()), (X0,), (v,))
    rev = jax.grad(lambda x: loss(x, "quat", diffrax.RecursiveCheckpointAdjoint()))(X0)
    np.testing.assert_allclose(fwd, rev @ v, rtol=1e-9, atol=1e-11)


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_long_horizon_gradient_10k_steps():
    """10⁴ fixed RK4 steps, checkpointed reverse mode (bounded memory): gradient w.r.t. the
    moments and Ω(0) equals finite differences; no blow-up (brax#186)."""
    ts = jnp.array([0.0, 20.0])

    def f(x):
        traj = simulate(
            RigidBody(x[:3]),
            x[3:6],
            None,
            ts,
            solver=RK4(),
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=2e-3,
            max_steps=10_001,
        )
        return jnp.sum(traj.omega[-1] * jnp.array([1.0, -2.0, 0.5])) + traj.quat[-1, 1]

    f = jax.jit(f)
    x = X0[:6]
    g = jax.grad(f)(x)
    fd = np.array([_directional_fd(f, x, e, h=1e-6) for e in np.eye(6)])
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-7)
