"""Argument checks of the rotation maps, shared by every rotation module: finite values, the
checks of quaternions and of matrices passed as rotations (built on `rigidjax._checks.Check` and
`validate_all`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from jaxtyping import Array

from .._checks import Check, at, first, fmt, validate_all, zero_vector
from .._custom_types import Mat33, Quat

NONFINITE_HINT = "; replace its NaN/inf entries (they come from an earlier overflow or 0/0)"


def finite_check(name: str, core: int) -> Check:
    """`x` finite; `core` trailing dimensions make one element (0 scalar, 1 vector, 2 matrix)."""
    axes = tuple(range(-core, 0))

    def bad(xp: Any, x: Any) -> Any:
        return ~xp.all(xp.isfinite(x), axis=axes) if core else ~xp.isfinite(x)

    def detail(x: np.ndarray) -> str:
        k = first(bad(np, x))
        return f", got {at(name, k)} = {fmt(x[k])}"

    return Check(bad, f"{name} must be finite", detail, NONFINITE_HINT)


def check_finite(x: Array, name: str, core: int) -> Array:
    """`x`, checked to be finite (see `finite_check`)."""
    return validate_all(x, [finite_check(name, core)])


def quat_checks(name: str) -> list[Check]:
    """A quaternion `(..., 4)` that stands for a rotation: finite and non-zero."""

    def zero(xp: Any, q: Any) -> Any:
        return zero_vector(xp, q)

    def detail(q: np.ndarray) -> str:
        k = first(zero(np, q))
        return f": {at(name, k)} = {fmt(q[k])}"

    def out_of_range(xp: Any, q: Any) -> Any:  # |q|² overflows or is subnormal (flushed to 0)
        n2 = xp.sum(q * q, axis=-1)
        return (n2 > 0) & ~((n2 >= xp.finfo(q.dtype).tiny) & (n2 < xp.inf))

    def size(q: np.ndarray) -> str:
        k = first(out_of_range(np, q))
        return f": {at(name, k)} = {fmt(q[k])}"

    message = f"{name} is a zero quaternion, which is no rotation"
    hint = f"; a rotation needs |{name}| > 0 (use rigidjax.quat.identity() for no rotation)"
    scale = Check(
        out_of_range,
        f"|{name}|² is out of its float range (it overflows or underflows)",
        size,
        f"; scale {name} towards |{name}| = 1 (any positive multiple is the same rotation)",
    )
    return [
        *_finite_and(name, 1, "quaternion (w, x, y, z)", Check(zero, message, detail, hint)),
        scale,
    ]


def _finite_and(name: str, rank: int, what: str, check: Check) -> list[Check]:
    """`name` finite (a `what` of `rank` trailing dimensions), then `check`."""
    return [finite_check(name, rank)._replace(message=f"{name} must be a finite {what}"), check]


def check_quat(q: Quat, name: str, on: Array | None = None) -> Array:
    """`q` (or `on`), checked to be a finite, non-zero quaternion (one run-time check)."""
    return validate_all(q, quat_checks(name), q if on is None else on)


def det(xp: Any, P: Any) -> Any:
    """`det P = p0 · (p1 × p2)` (rows p_i), the same formula in NumPy and JAX."""
    return xp.sum(P[..., 0, :] * xp.cross(P[..., 1, :], P[..., 2, :]), axis=-1)


def matrix_checks(name: str) -> list[Check]:
    """A matrix `(..., 3, 3)` passed as a rotation: finite, with a positive determinant (relative
    to its size, `det P > 64 eps (‖P‖_F/√3)³`, so that rounding of a singular frame does not pass).
    Like SciPy's `Rotation.from_matrix`, nothing more: a matrix with det > 0 that is not quite
    orthogonal (an integrator's output) is accepted."""

    def improper(xp: Any, P: Any) -> Any:
        size = xp.sum(P * P, axis=(-2, -1)) / 3
        return ~(det(xp, P) > 64 * xp.finfo(P.dtype).eps * size * xp.sqrt(size))

    def detail(P: np.ndarray) -> str:
        k = first(improper(np, P))
        return f": det {at(name, k)} = {det(np, P[k]):.6g} for {at(name, k)} = {fmt(P[k])}"

    return _finite_and(
        name,
        2,
        "rotation matrix",
        Check(
            improper,
            f"{name} is not a rotation matrix: non-positive determinant (a left-handed or "
            "degenerate frame)",
            detail,
            "; a rotation has det = +1: negate one axis (column) of a left-handed frame "
            "(a matrix with det > 0 that is not quite orthogonal is accepted and orthogonalised)",
        ),
    )


def check_matrix(P: Mat33, name: str) -> Mat33:
    """`P`, checked to be finite with a positive determinant (see `matrix_checks`)."""
    return validate_all(P, matrix_checks(name))
