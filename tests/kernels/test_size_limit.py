"""A field larger than the kernels take (`kernels.model.MAX_OPERATIONS`: an MLP torque) runs on
the Diffrax path with its own field, with one warning, and its values are right (SciPy)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rigidjax as rj
from rigidjax.kernels import model as model_kernel
from rigidjax.kernels._scalar import Unsupported
from rigidjax.mechanics._rigid_model import rigid_body_model

I = np.array([1.0, 2.0, 2.5])


def _weights(width):
    rng = np.random.default_rng(width)
    return (
        0.3 * rng.normal(size=(7, width)),
        0.3 * rng.normal(size=(width, width)),
        0.1 * rng.normal(size=(width, 3)),
    )


def _mlp(weights, xp):
    a, b, c = weights

    def torque(t, w, q):
        h = xp.tanh(xp.concatenate([w, q]) @ a)
        return xp.tanh(h @ b) @ c

    return torque


def _hoist(width):
    model = rigid_body_model(_mlp(_weights(width), jnp))
    return model_kernel.hoist(model.field, model.size, model.params, jnp.float64)


def test_size_counted_and_refused():
    """The field's scalar statements are counted; 7 → 4 → 4 → 3 is taken, 7 → 16 → 16 → 3 is
    refused with its count."""
    assert _hoist(4).operations < model_kernel.MAX_OPERATIONS
    with pytest.raises(Unsupported, match=r"a field of \d+ scalar operations"):
        _hoist(16)


def test_large_field_on_its_own_field():
    """`simulate` with the 16-wide MLP torque: one warning naming the size, and Ω and q equal
    SciPy's DOP853 of the same equations (NumPy MLP) to 1e-8."""
    weights = _weights(16)
    torque = _mlp(weights, np)
    w0, q0, ts = np.array([0.3, 1.0, -0.2]), np.array([1.0, 0.0, 0.0, 0.0]), np.linspace(0, 2, 5)

    def f(t, s):
        w, q = s[:3], s[3:]
        a, v = q[0], q[1:]
        dq = np.concatenate([[-0.5 * v @ w], 0.5 * (a * w + np.cross(v, w))])
        return np.concatenate([(np.cross(I * w, w) + torque(t, w, q)) / I, dq])

    want = solve_ivp(f, (0, 2), np.concatenate([w0, q0]), "DOP853", ts, rtol=1e-12, atol=1e-12).y.T
    body = rj.RigidBody(jnp.asarray(I))
    with pytest.warns(RuntimeWarning, match="scalar operations"):
        tr = rj.simulate(body, w0, q0, ts, torque=_mlp(weights, jnp), rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(tr.omega, want[:, :3], rtol=0, atol=1e-8)
    np.testing.assert_allclose(tr.quat, want[:, 3:], rtol=0, atol=1e-8)

    def loss(w0):
        return jnp.sum(rj.simulate(body, w0, q0, ts, torque=_mlp(weights, jnp)).omega[-1])

    with pytest.warns(RuntimeWarning, match="scalar operations"):
        assert np.all(np.isfinite(jax.grad(loss)(jnp.asarray(w0))))
