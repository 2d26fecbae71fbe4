"""Bad input to the dynamics' entry points: a clear ValueError naming the argument, before any
integration."""

import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj

TS = jnp.linspace(0.0, 1.0, 3)
BODY = rj.RigidBody(jnp.array([1.0, 2.0, 2.5]))
W0 = jnp.array([0.3, 1.0, -0.2])


def test_empty_batch():
    with pytest.raises(ValueError, match=r"batch is empty.*\(0,\)"):
        rj.simulate(BODY, jnp.zeros((0, 3)), None, TS)


@pytest.mark.parametrize("shape", [(), (2,), (3, 1), (2, 3)])
def test_torque_of_the_wrong_shape(shape):
    with pytest.raises(
        ValueError, match=rf"torque\(t, omega, q\) must return .*got shape \{shape}"[:-1]
    ):
        rj.simulate(BODY, W0, None, TS, torque=lambda t, w, q: jnp.zeros(shape))


def test_torque_not_callable():
    with pytest.raises(TypeError, match="torque must be a callable"):
        rj.simulate(BODY, W0, None, TS, torque=jnp.zeros(3))


@pytest.mark.parametrize("bad", [[0.0, 1.0, np.inf], [np.nan, 0.5, 1.0], [0.0, np.inf, np.inf]])
def test_non_finite_times(bad):
    with pytest.raises(ValueError, match=r"ts must be strictly increasing and finite: ts\[\d\] ="):
        rj.simulate(BODY, W0, None, jnp.array(bad))


def test_non_finite_state_names_the_entry():
    with pytest.raises(ValueError, match=r"omega0 must be finite: omega0\[1, 2\] = nan"):
        rj.simulate(BODY, jnp.array([W0, [0.0, 1.0, np.nan]]), None, TS)
