"""The output times and the initial rotational state, read and checked once for every
simulator of a rotating body (`simulate`, the gyrostat)."""

from __future__ import annotations

from jaxtyping import Array

from .._checks import (
    as_float,
    check_finite,
    check_times,
    check_times_shape,
    check_unit_norm,
    vector,
)
from .._custom_types import RealLike
from ..rotations import quat


def initial_rotation(
    ts: RealLike | None, omega0: RealLike, q0: RealLike | None, check: bool
) -> tuple[Array, Array, Array]:
    """`(ts (T,), omega0 (..., 3), q0 (..., 4))` as arrays of the float dtype of `ts` (`q0`
    the identity if None), with clear errors for missing or mis-shaped input; with `check`,
    increasing finite times, a finite `omega0` and a unit `q0` (see `simulate`'s `check`)."""
    if ts is None:
        raise ValueError("ts (the output times) is required")
    ts = check_times_shape(as_float(ts, "ts"))
    dtype = ts.dtype
    omega0 = vector(omega0, 3, "omega0").astype(dtype)
    q0 = quat.identity(dtype=dtype) if q0 is None else vector(q0, 4, "q0").astype(dtype)
    if check:
        ts = check_times(ts)
        omega0 = check_finite(omega0, "omega0")
        q0 = check_unit_norm(q0, "q0")
    return ts, omega0, q0
