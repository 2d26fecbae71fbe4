"""Do the reported standard deviations mean what they say? 200 noisy datasets, one vmapped fit
(compiled once): the 95% intervals `estimate ± 1.96 std` must cover the truth 93–97% of the
time, for the inertia entries and for the principal moments."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import identify_inertia
from tests.fit.data import I_REF, MOMENTS_REF, TS, experiments

N = 200
SIGMA = 2e-3


@pytest.mark.slow  # ~20-50 s on 2 cores: 200 fits
def test_95_percent_intervals_cover_the_truth():
    W, _ = experiments(n=1)
    rng = np.random.default_rng(5)
    data = jnp.asarray(W[0][None] + SIGMA * rng.normal(size=(N, *W[0].shape)))
    est = jax.vmap(lambda w: identify_inertia(TS, omega_obs=w, sigma_omega=SIGMA))(data)
    assert est.covariance_method == "gauss_newton"
    assert bool(jnp.all(est.converged))
    iu = np.triu_indices(3)
    err = (np.asarray(est.inertia) - I_REF)[:, iu[0], iu[1]]
    z = err / np.asarray(est.inertia_std)[:, iu[0], iu[1]]
    entries = float(np.mean(np.abs(z) <= 1.96))  # 6 entries × 200 intervals
    zm = (np.asarray(est.principal_moments) - MOMENTS_REF) / np.asarray(est.principal_moments_std)
    moments = float(np.mean(np.abs(zm) <= 1.96))  # 3 moments × 200 intervals
    print(f"coverage of the 95% intervals: entries {entries:.3f}, principal moments {moments:.3f}")
    assert 0.93 <= entries <= 0.97, entries
    assert 0.93 <= moments <= 0.97, moments
    # and the std are of the size of the actual scatter (not just wide enough)
    ratio = err.std(axis=0) / np.asarray(est.inertia_std)[:, iu[0], iu[1]].mean(axis=0)
    assert np.all((0.85 < ratio) & (ratio < 1.15)), ratio
