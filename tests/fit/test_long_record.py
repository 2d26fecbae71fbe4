"""A long record of tumbling: the fit follows growing prefixes of it. From the linear estimate
the fit of the whole record at once ran out of its 256 steps, not converged (the cost has more
minima the longer the record)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import identify_inertia
from tests.fit.data import I_TRUE, MOMENTS_REF, Q0S, W0S
from tests.helpers import rigid_body_dop853


@pytest.mark.slow  # SciPy's DOP853 over 500 s, and the fit of 1001 samples
def test_a_long_tumbling_record_is_identified():
    ts = np.linspace(0.0, 500.0, 1001)  # ~800 rad of tumbling
    omega, _ = rigid_body_dop853(I_TRUE, W0S[0], Q0S[0], ts)
    sigma = 0.01
    omega_obs = omega + sigma * np.random.default_rng(3).normal(size=omega.shape)
    est = identify_inertia(ts, omega_obs, sigma_omega=sigma, rtol=1e-6, atol=1e-6)
    assert bool(est.converged) and int(est.num_steps) < 256, est.num_steps
    std = np.asarray(est.principal_moments_std)
    assert np.all(std < 5e-4), std  # 500 s of data pin the moments down
    np.testing.assert_array_less(np.abs(np.asarray(est.principal_moments) - MOMENTS_REF), 5 * std)
    np.testing.assert_allclose(est.omega0, W0S[0], atol=5 * sigma)


@pytest.mark.slow  # two fits compiled (eager, and vmapped under jit)
def test_datasets_with_different_numbers_of_prefixes_under_vmap():
    """The number of prefix stages is computed from the data (traced): under `jax.vmap` a
    140 rad record (3 prefixes) and a 15 rad one (none) each equal their fit alone."""
    ts = np.linspace(0.0, 100.0, 501)
    sigma, rng = 0.002, np.random.default_rng(5)
    records = []
    for scale in (1.0, 0.11):
        omega, _ = rigid_body_dop853(I_TRUE, scale * W0S[0], Q0S[0], ts)
        records.append(omega + sigma * rng.normal(size=omega.shape))

    def fit(w):
        return identify_inertia(ts, w, sigma_omega=sigma, rtol=1e-6, atol=1e-6)

    batched = jax.jit(jax.vmap(fit))(jnp.asarray(np.stack(records)))
    for k, w in enumerate(records):
        alone = fit(w)
        assert bool(alone.converged) and bool(batched.converged[k])
        assert int(batched.num_steps[k]) == int(alone.num_steps)
        # as test_identify.py::test_vmap_over_datasets: the LM stops at its tolerance, and the
        # batched program rounds differently (1.4e-10 seen; the std is ~1e-4)
        np.testing.assert_allclose(batched.inertia[k], alone.inertia, rtol=0, atol=1e-8)
    assert int(batched.num_steps[0]) != int(batched.num_steps[1])  # different stage counts
