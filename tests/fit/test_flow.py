"""The fits' forward model (fixed-step RK4) against SciPy's DOP853."""

import jax
import jax.numpy as jnp
import numpy as np

from rigidjax.fit.design import piecewise_constant
from rigidjax.fit.flow import flow, substeps_for
from tests.fit.data import I_TRUE, Q0S, TS, W0S
from tests.helpers import rigid_body_dop853

EDGES = np.linspace(0.0, 8.0, 5)
U = np.array([[0.2, -0.1, 0.05], [-0.1, 0.3, 0.0], [0.0, -0.2, 0.2], [0.15, 0.1, -0.1]])


def test_flow_matches_dop853_with_piecewise_torque():
    """General tensor, a torque piecewise constant between sample times (discontinuous), the
    data-driven step counts of the fits (the design's fixed count: tests/fit/test_design.py)."""

    def torque_np(t, w, q):
        return U[min(np.searchsorted(EDGES, t, side="right") - 1, 3)]

    W, Q = rigid_body_dop853(I_TRUE, W0S[0], Q0S[0], TS, torque_np)

    def torque(t, w, q):
        return piecewise_constant(jnp.asarray(U), jnp.asarray(EDGES), t)

    n = substeps_for(jnp.asarray(TS), jnp.asarray(1.5 * np.abs(W).max()), 0.02, 1000)
    args = jnp.asarray(I_TRUE), jnp.asarray(W0S[0]), jnp.asarray(Q0S[0]), jnp.asarray(TS), n
    w, q = jax.jit(lambda *a: flow(*a, torque))(*args)
    np.testing.assert_allclose(w, W, atol=2e-8)
    np.testing.assert_allclose(q, Q, atol=2e-8)


def test_substeps_bound_the_step_angle():
    ts = jnp.array([0.0, 0.1, 0.35, 0.4])
    n = substeps_for(ts, jnp.asarray(2.0), 0.02, 100)
    np.testing.assert_array_equal(n, [10, 25, 5])
    assert np.all(np.diff(ts) * 2.0 / n <= 0.02 + 1e-12)
    assert int(substeps_for(ts, jnp.asarray(1e6), 0.02, 100).max()) == 100
