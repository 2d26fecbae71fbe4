"""The scalar program's JAX backend (`_components.Components`): `round` built from `floor`
(Pallas' Triton lowering has no `round`) equals `jax.lax.round` for every float."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rigidjax.kernels._components import _round

EDGES = [0.0, -0.0, 0.5, -0.5, 1.5, 2.5, -2.5, 0.49999999999999994, -0.49999999999999994,
         2.0**52 + 1, 4503599627370495.5, -(2.0**52) - 1, 2.0**53, 1e300, 5e-324, -5e-324,
         np.inf, -np.inf, np.nan]  # fmt: skip
ROUND = jax.jit(lambda x: [_round(x, m) for m in (0, 1)])
LAX = jax.jit(lambda x: [jax.lax.round(x, m) for m in (0, 1)])


def _same(x: np.ndarray) -> None:
    for a, b in zip(ROUND(jnp.asarray(x)), LAX(jnp.asarray(x)), strict=True):
        np.testing.assert_array_equal(a, b)  # NaN equal to NaN
        assert np.array_equal(np.signbit(a), np.signbit(b))


def test_round_edges_and_halves():
    """Halves (to even and away from zero), the largest float below ½, floats past 2⁵², ±0,
    denormals, ±inf and NaN, in float64 and float32."""
    x = np.concatenate([EDGES, np.arange(-10.0, 10.25, 0.25)])
    _same(x)
    with np.errstate(over="ignore"):
        _same(x.astype(np.float32))


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=64, max_size=64))
def test_round_matches_lax(xs):
    _same(np.asarray(xs))
