"""The Levenberg–Marquardt loop's stopping rule, on linear least squares (the answer from
NumPy's `lstsq`)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax.fit.levenberg import levenberg_marquardt


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stops_at_a_minimum_to_rounding(seed):
    """Asked for a tolerance below rounding (`rtol = 1e-16`, `atol = 0`), the loop reaches the
    least-squares solution and stops at the first small step that leaves the cost unchanged,
    accepted or not: 5–10 steps. (Stopping at accepted steps only, it waited for λ to pass
    10¹⁶ through rejected ones: 40–42 steps.)"""
    rng = np.random.default_rng(seed)
    A, b = rng.normal(size=(20, 3)), rng.normal(size=20)

    def residuals(p, stage):
        return jnp.asarray(A) @ p - jnp.asarray(b), jnp.zeros(0)

    fit = jax.jit(lambda p0: levenberg_marquardt(residuals, p0, rtol=1e-16, atol=0.0))
    out = fit(jnp.zeros(3))
    want = np.linalg.lstsq(A, b, rcond=None)[0]
    np.testing.assert_allclose(out.params, want, rtol=1e-10)  # (the cost is flat to 1e-24 there)
    assert bool(out.converged) and int(out.num_steps) <= 12
