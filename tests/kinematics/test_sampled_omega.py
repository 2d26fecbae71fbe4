"""darboux with sampled angular velocity (gyro data): interpolated inside the samples, never
extrapolated; bad samples are clear errors naming the argument."""

import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import darboux

T_S = np.linspace(0.0, 2.0, 21)
W_S = np.stack([0.3 + 0.1 * T_S, -0.2 * np.ones_like(T_S), 0.5 * np.cos(T_S)], -1)


@pytest.mark.parametrize(("lo", "hi"), [(0.0, 2.5), (-0.1, 2.0)])
def test_times_beyond_the_samples(lo, hi):
    with pytest.raises(ValueError, match=r"ts must lie within the times of the omega samples"):
        darboux((T_S, W_S), jnp.linspace(lo, hi, 4))


def test_non_finite_samples():
    bad = W_S.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"omega samples must be finite: omega samples\[7, 1\]"):
        darboux((T_S, bad), jnp.linspace(0.0, 2.0, 4))
    with pytest.raises(ValueError, match=r"omega t_samples must be strictly increasing"):
        darboux((T_S[::-1], W_S), jnp.linspace(0.0, 2.0, 4))


def test_the_sampled_interval_itself_is_fine():
    P = darboux((T_S, W_S), jnp.linspace(0.0, 2.0, 4))
    assert P.shape == (4, 3, 3) and np.all(np.isfinite(P))
