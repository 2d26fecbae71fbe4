"""Designs of a sweep: the points at which a model is evaluated (`grid`, `sample`)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import warnings
from collections.abc import Mapping

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

__all__ = ["Design", "grid", "sample"]

_METHODS = ("sobol", "latin", "uniform")

RESERVED = ("status",)
"""Names that a sweep's Dataset gives its own variables, besides those with a leading `_`
(the store's records, `_sweep`): no factor or observable may take them."""


@dataclasses.dataclass(frozen=True, eq=False)
class Design:
    """The points of a sweep.

    `dims`, `shape`: the design's dimensions (a grid: one per factor, in order; a sample: one
    dimension `"point"`). `coords`: name → `(dims, values)` of each coordinate (a grid's factor
    values along their own dimension; a sample's factor values along `"point"`). `points`:
    factor → its value at every point, flattened in C order over `shape` (what the model sees).
    `method`: how the design was made, for the provenance of the results."""

    dims: tuple[str, ...]
    shape: tuple[int, ...]
    coords: Mapping[str, tuple[tuple[str, ...], np.ndarray]]
    points: Mapping[str, np.ndarray]
    method: str

    def __post_init__(self):
        """Every design is checked here, however it was made: points for every factor, one per
        cell of `shape`, all finite (a ValueError naming the factor and the point), none named
        as the results' own variables (`RESERVED`)."""
        if not self.points or math.prod(self.shape) == 0:
            raise ValueError("design is empty: give at least one factor and one point")
        for name, v in self.points.items():
            if name in RESERVED or name[:1] == "_":
                raise ValueError(
                    f"design factor {name!r} takes a name the results reserve "
                    f"({', '.join(RESERVED)}, or a leading '_'): rename it"
                )
            v = np.asarray(v)
            if v.shape != (math.prod(self.shape),):
                raise ValueError(
                    f"design factor {name!r} has {v.shape} values for the design shape {self.shape}"
                )
            if not np.all(np.isfinite(v)):
                k = int(np.flatnonzero(~np.isfinite(v))[0])
                raise ValueError(f"design factor {name!r} must be finite: point {k} has {v[k]}")

    @property
    def size(self) -> int:
        """The number of points."""
        return math.prod(self.shape)

    @property
    def factors(self) -> tuple[str, ...]:
        return tuple(self.points)

    def fingerprint(self) -> str:
        """SHA-256 of the dimensions, shape and every point's values: equal designs, equal
        fingerprints (a store records it and refuses another design)."""
        h = hashlib.sha256(json.dumps([self.dims, self.shape, self.method]).encode())
        for name, values in self.points.items():
            h.update(name.encode())
            h.update(np.ascontiguousarray(values, np.float64).tobytes())
        return h.hexdigest()


def _factor(name: str, values) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"factor {name!r} must be a non-empty 1-D array, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        k = int(np.flatnonzero(~np.isfinite(v))[0])
        raise ValueError(f"factor {name!r} must be finite: {name}[{k}] = {v[k]}")
    return v


def grid(**factors) -> Design:
    """The full-factorial design of `factors` (each a 1-D array): one dimension per factor, in the
    given order, with the factor's values as its coordinate."""
    if not factors:
        raise ValueError("grid needs at least one factor, e.g. grid(I2=np.linspace(1.1, 2.9, 50))")
    values = {name: _factor(name, v) for name, v in factors.items()}
    mesh = np.meshgrid(*values.values(), indexing="ij")
    return Design(
        dims=tuple(values),
        shape=tuple(v.size for v in values.values()),
        coords={name: ((name,), v) for name, v in values.items()},
        points={name: m.reshape(-1) for name, m in zip(values, mesh, strict=True)},
        method="grid",
    )


def _unit_sample(n: int, d: int, key: PRNGKeyArray, method: str) -> np.ndarray:
    """`n` points in the unit cube [0, 1)^d."""
    if method == "uniform":
        return np.asarray(jax.random.uniform(key, (n, d)), np.float64)
    from scipy.stats import qmc  # the quasi-random sequences of SciPy

    seed = int(jax.random.randint(key, (), 0, np.iinfo(np.int32).max))
    if method == "latin":
        return qmc.LatinHypercube(d, rng=seed).random(n)
    with warnings.catch_warnings():  # n need not be a power of 2 (documented in `sample`)
        warnings.filterwarnings("ignore", "The balance properties of Sobol")
        return qmc.Sobol(d, scramble=True, rng=seed).random(n)


def _range(name: str, spec) -> tuple[float, float, bool]:
    if not isinstance(spec, tuple | list) or len(spec) not in (2, 3):
        raise ValueError(f"range {name!r} must be (low, high) or (low, high, 'log'), got {spec!r}")
    low, high = float(spec[0]), float(spec[1])
    log = len(spec) == 3
    if log and spec[2] != "log":
        raise ValueError(f"range {name!r}: the third entry may only be 'log', got {spec[2]!r}")
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        raise ValueError(f"range {name!r} must have finite low < high, got ({low}, {high})")
    if log and low <= 0:
        raise ValueError(f"range {name!r} is logarithmic: low must be positive, got {low}")
    return low, high, log


def sample(n: int, *, key: PRNGKeyArray, method: str = "sobol", **ranges) -> Design:
    """`n` points with one dimension `"point"`: a scrambled Sobol sequence (`"sobol"`, SciPy's
    `qmc.Sobol`; balanced for n a power of 2), a Latin hypercube (`"latin"`) or independent
    uniform draws (`"uniform"`, `jax.random`), from `key`. Each range is `(low, high)` (linear)
    or `(low, high, "log")` (uniform in log: low · (high/low)^u)."""
    if not (isinstance(n, int | np.integer) and n > 0):
        raise ValueError(f"n must be a positive integer (the number of points), got {n!r}")
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    if not ranges:
        raise ValueError("sample needs at least one range, e.g. sample(64, key=key, I2=(1.1, 2.9))")
    specs = {name: _range(name, spec) for name, spec in ranges.items()}
    u = _unit_sample(int(n), len(specs), key, method)
    points = {}
    for j, (name, (low, high, log)) in enumerate(specs.items()):
        if log:
            points[name] = np.exp(np.log(low) + u[:, j] * (np.log(high) - np.log(low)))
        else:
            points[name] = low + u[:, j] * (high - low)
    return Design(
        dims=("point",),
        shape=(int(n),),
        coords={name: (("point",), v) for name, v in points.items()},
        points=points,
        method=method,
    )
