"""The compiled cores of the rotation maps (`rigidjax.rotations._compiled`, issue 26 item 2): an
eager call (quick-compiled program) and an eager `jacfwd`/`jacrev`/`grad` (the custom JVP
`J · dx` on the known primal) give the values and derivatives of the same map under `jax.jit`
(ordinary autodiff through the core) and of central differences, and a repeated eager call
compiles nothing."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax.rotations import euler, mrp, quat, so3
from tests.helpers import fd_jacobian

P0 = Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix()
HALF = 2 * np.outer([1.0, 2, 2], [1.0, 2, 2]) / 9 - np.eye(3)
THETA = np.array([0.3, -0.2, 0.5])
Q = np.array([0.5, -0.1, 0.7, 0.2])

MAPS = {
    "so3.log": (so3.log, P0),
    "so3.log half-turn": (so3.log, HALF),
    "quat.from_matrix": (quat.from_matrix, P0),
    "mrp.from_matrix": (mrp.from_matrix, P0),
    "mrp.from_matrix half-turn": (mrp.from_matrix, HALF),
    "euler.from_matrix ZXZ": (lambda P: euler.from_matrix(P, "ZXZ"), P0),
    "euler.from_matrix xyz degrees": (lambda P: euler.from_matrix(P, "xyz", True), P0),
    "so3.distance": (lambda P: so3.distance(P0, P), HALF),
    "so3.exp": (so3.exp, THETA),
    "quat.to_matrix": (quat.to_matrix, Q),
    "euler.to_matrix": (lambda a: euler.to_matrix(a, "zyx"), THETA),
}


def central_differences(f, x):
    """`fd_jacobian` in JAX's Jacobian shape `(*f(x).shape, *x.shape)`."""
    return fd_jacobian(f, x).reshape(np.shape(f(x)) + x.shape)


@pytest.mark.parametrize("name", MAPS)
def test_eager_values_and_derivatives_equal_the_compiled_ones(name):
    f, x = MAPS[name]
    x = jnp.asarray(x)
    np.testing.assert_allclose(f(x), jax.jit(f)(x), rtol=0, atol=2e-15)  # rounding
    J = jax.jit(jax.jacfwd(f))(x)
    np.testing.assert_allclose(jax.jacfwd(f)(x), J, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(jax.jacrev(f)(x), J, rtol=1e-13, atol=1e-14)
    grad = jax.grad(lambda x: jnp.sum(f(x)))(x)
    np.testing.assert_allclose(grad, J.reshape(-1, *x.shape).sum(0), rtol=1e-13, atol=1e-14)
    if "half-turn" not in name:  # θ and −θ (p and its shadow) jump there: no differences
        np.testing.assert_allclose(J, central_differences(f, np.asarray(x)), atol=1e-7)


@pytest.mark.slow  # ~9 s: second derivatives
def test_second_derivatives_of_the_eager_path():
    """The custom JVP's Jacobian is itself differentiable (a Hessian of so3.log)."""
    f = lambda P: so3.log(P)[0]  # noqa: E731
    H = jax.hessian(f)(jnp.asarray(P0))
    np.testing.assert_allclose(H, jax.jit(jax.hessian(f))(jnp.asarray(P0)), atol=1e-12)


def test_a_repeated_eager_call_compiles_nothing():
    compiles = []

    def count(event: str, duration_secs: float, **kwargs: str | int) -> None:
        compiles.append(event == "/jax/core/compile/backend_compile_duration")

    P = jnp.asarray(Rotation.from_rotvec([1.0, 0.2, -0.3]).as_matrix())
    P2 = jnp.asarray(Rotation.from_rotvec([-0.5, 2.0, 0.1]).as_matrix())
    calls = [so3.log, jax.jacfwd(so3.log), jax.jacrev(so3.log)]
    for g in calls:
        g(P)  # compiled here, if not yet
    jax.monitoring.register_event_duration_secs_listener(count)
    try:
        for g in calls:
            jax.block_until_ready(g(P2))
    finally:
        jax.monitoring.unregister_event_duration_listener(count)
    assert not any(compiles)
