"""Object arrays of a backend's scalars: how `_scalar.unroll` holds a jaxpr's arrays (a C++
expression or a JAX array per element, or a Python number for a constant)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

Scalar = Any
"""A backend's scalar: a C++ expression (`CEmitter`) or an array (`Components`), or a Python
number for a constant known when unrolling."""


def _is_const(x: Scalar) -> bool:
    return isinstance(x, int | float | bool | np.number | np.bool_)


def _filled(shape: tuple[int, ...], value: Scalar) -> np.ndarray:
    """An object array of `shape` holding `value` everywhere (element by element: NumPy would
    convert an array value)."""
    out = np.empty(shape, dtype=object)
    for idx in np.ndindex(shape):
        out[idx] = value
    return out


def objects(x) -> np.ndarray:
    """`x` (an object array or one scalar) as an object array holding `x`'s scalars themselves:
    never `np.asarray(x, dtype=object)`, which NumPy 2.5 answers by asking a JAX tracer for
    its value (`__array__`)."""
    if isinstance(x, np.ndarray):
        return x if x.dtype == object else x.astype(object)
    out = np.empty((), dtype=object)
    out[()] = x
    return out


def scalars(names: Sequence[Scalar], shape: tuple[int, ...]) -> np.ndarray:
    """An object array of `shape` holding `names` in order."""
    out = np.empty(len(names), dtype=object)
    for i, x in enumerate(names):
        out[i] = x
    return out.reshape(shape)
