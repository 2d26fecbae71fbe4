"""Designs: full-factorial grids and samples (Sobol, Latin hypercube, uniform, log ranges)."""

import jax
import numpy as np
import pytest
from scipy.stats import qmc

from rigidjax import sweep

KEY = jax.random.PRNGKey(0)


def test_grid_is_full_factorial_in_order():
    d = sweep.grid(a=[1.0, 2.0], b=[10.0, 20.0, 30.0])
    assert d.dims == ("a", "b") and d.shape == (2, 3) and d.size == 6
    np.testing.assert_array_equal(d.points["a"], [1, 1, 1, 2, 2, 2])
    np.testing.assert_array_equal(d.points["b"], [10, 20, 30, 10, 20, 30])
    assert d.coords["b"] == (("b",), pytest.approx(np.array([10.0, 20.0, 30.0])))


@pytest.mark.parametrize("method", ["sobol", "latin", "uniform"])
def test_sample_ranges_and_reproducibility(method):
    d = sweep.sample(64, key=KEY, method=method, x=(-1.0, 3.0), k=(1e-3, 10.0, "log"))
    assert d.dims == ("point",) and d.shape == (64,)
    assert np.all((d.points["x"] >= -1) & (d.points["x"] < 3))
    assert np.all((d.points["k"] >= 1e-3) & (d.points["k"] < 10))
    # log range: uniform in log k, so about half the points lie below the geometric mean 0.1
    assert 20 < np.sum(d.points["k"] < 0.1) < 44
    again = sweep.sample(64, key=KEY, method=method, x=(-1.0, 3.0), k=(1e-3, 10.0, "log"))
    np.testing.assert_array_equal(d.points["x"], again.points["x"])
    assert d.fingerprint() == again.fingerprint()
    other = sweep.sample(
        64, key=jax.random.PRNGKey(1), method=method, x=(-1.0, 3.0), k=(1e-3, 10.0, "log")
    )
    assert d.fingerprint() != other.fingerprint()


def test_quasi_random_designs_fill_the_cube_evenly():
    """Sobol and Latin hypercube have a lower discrepancy than independent uniform draws."""

    def disc(method):
        d = sweep.sample(256, key=KEY, method=method, x=(0.0, 1.0), y=(0.0, 1.0))
        return qmc.discrepancy(np.stack([d.points["x"], d.points["y"]], -1))

    assert disc("sobol") < disc("uniform") and disc("latin") < disc("uniform")
    d = sweep.sample(50, key=KEY, method="latin", x=(0.0, 1.0))
    np.testing.assert_array_equal(np.sort(np.floor(d.points["x"] * 50)), np.arange(50))


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: sweep.grid(), "at least one factor"),
        (lambda: sweep.grid(a=[]), "factor 'a' must be a non-empty 1-D array"),
        (lambda: sweep.grid(a=[1.0, np.nan]), r"factor 'a' must be finite: a\[1\] = nan"),
        (lambda: sweep.sample(0, key=KEY, x=(0, 1)), "n must be a positive integer"),
        (lambda: sweep.sample(4, key=KEY, method="halton", x=(0, 1)), "method must be one of"),
        (lambda: sweep.sample(4, key=KEY, x=(1, 0)), "range 'x' must have finite low < high"),
        (lambda: sweep.sample(4, key=KEY, x=(0, 1, "log")), "low must be positive"),
        (lambda: sweep.sample(4, key=KEY, x=(1, 2, "ln")), "may only be 'log'"),
        (lambda: sweep.grid(status=[1.0, 2.0]), "factor 'status' takes a name the results"),
        (lambda: sweep.sample(4, key=KEY, _sweep=(0, 1)), "factor '_sweep' takes a name"),
    ],
)
def test_bad_designs(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_hand_made_designs_are_checked_too():
    good = sweep.grid(a=[1.0, 2.0])
    with pytest.raises(ValueError, match=r"design factor 'a' must be finite: point 1 has nan"):
        sweep.Design(good.dims, good.shape, good.coords, {"a": np.array([1.0, np.nan])}, "grid")
    with pytest.raises(ValueError, match=r"design factor 'a' has \(3,\) values"):
        sweep.Design(good.dims, good.shape, good.coords, {"a": np.zeros(3)}, "grid")
    with pytest.raises(ValueError, match="design is empty"):
        sweep.Design(("point",), (0,), {}, {"a": np.zeros(0)}, "uniform")
