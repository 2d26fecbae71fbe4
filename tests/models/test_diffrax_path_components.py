"""The Diffrax path's field on component arrays: `_materialized`, which keeps XLA from fusing a
stage's components (and their tangents) into every consumer, is the identity to the bit, on
values that are not finite and on signed zeros too, and so are its tangent and cotangent on
finite ones; the solve's derivatives through it equal central differences (how much it saves
is measured by `benchmarks/bench_modes.py`, its path "event")."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.models._diffrax_path import _materialized

K = (
    jnp.array([1.5, -0.0, 0.0]),
    jnp.array([jnp.inf, -jnp.inf, jnp.nan]),
    jnp.array([-2.0, 1e-300, 3e300]),
)


def _bits(xs) -> list[np.ndarray]:
    return [np.asarray(x).view(np.int64) for x in xs]


def test_values_pass_unchanged_to_the_bit():
    for fn in (_materialized, jax.jit(_materialized)):
        np.testing.assert_array_equal(_bits(fn(K)), _bits(K))
    # one body's solve, mapped over the bodies: scalars per component under `jax.vmap`
    mapped = jax.vmap(_materialized)(K)
    np.testing.assert_array_equal(_bits(mapped), _bits(K))


def test_tangents_and_cotangents_pass_unchanged():
    k = tuple(jnp.array([0.3, -1.2, 2.5]) * (i + 1) for i in range(3))
    dk = tuple(jnp.array([1.0, -0.5, 0.25]) / (i + 1) for i in range(3))
    out, tangent = jax.jvp(_materialized, (k,), (dk,))
    np.testing.assert_array_equal(out, k)
    np.testing.assert_array_equal(tangent, dk)
    _, pullback = jax.vjp(_materialized, k)
    np.testing.assert_array_equal(pullback(dk)[0], dk)
    tangent = jax.vmap(lambda k, dk: jax.jvp(_materialized, (k,), (dk,))[1])(k, dk)
    np.testing.assert_array_equal(tangent, dk)


@pytest.mark.slow  # (two solves' derivatives compiled: ~45 s)
def test_event_derivatives_on_the_diffrax_path_equal_central_differences():
    """A gravity-gradient torque with a traced gain and a terminating event: the value on the
    adaptive kernel, `jax.grad` and `jax.jvp` through the Diffrax path (the gain is one of the
    field's constants `c`, the path whose cotangents were a chain of pads; 110 statements:
    through `_materialized`)."""
    e_z, moments = jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 2.0, 3.0])
    rng = np.random.default_rng(3)
    w0 = jnp.asarray(rng.normal(size=(3, 3)))
    q0 = rj.quat.normalize(jnp.asarray(rng.normal(size=(3, 4))))
    ts = jnp.linspace(0.0, 1.0, 3)

    def loss(g):
        def torque(t, w, q):
            c = rj.quat.rotate(rj.quat.conj(q), e_z)
            return g * jnp.cross(c, moments * c)

        tr = rj.simulate(
            rj.RigidBody(moments),
            w0,
            q0,
            ts,
            torque=torque,
            rtol=1e-10,
            atol=1e-10,
            event=rj.Event(lambda t, w, q: w[0] - 0.5 * w0[0, 0]),
        )
        return jnp.sum(tr.omega[:, -1] ** 2)

    g, eps = jnp.asarray(0.7), 1e-5
    central = (loss(g + eps) - loss(g - eps)) / (2 * eps)
    reverse = jax.jit(jax.grad(loss))(g)
    _, forward = jax.jit(lambda g: jax.jvp(loss, (g,), (jnp.ones_like(g),)))(g)
    np.testing.assert_allclose(reverse, central, rtol=1e-6)
    np.testing.assert_allclose(forward, reverse, rtol=1e-9)
