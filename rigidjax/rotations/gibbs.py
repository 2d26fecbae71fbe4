"""Gibbs (Rodrigues) finite-rotation vector `θ_G = 2 tan(χ/2) e` (Borisov–Mamaev (001); THEORY §3).

`χ` is the rotation angle about the unit axis `e`. In quaternions `θ_G = 2 λ/λ0`, so `q` and `−q`
give the same vector. It is infinite at `χ = π`: every function that would produce such a vector
raises an error instead (use quaternions or `rigidjax.mrp` there). Conventions as
`rigidjax.quat`: `P` maps body to space, Hamilton product, `P(q1 ∘ q2) = P(q1) P(q2)`.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import matrix, vector
from .._custom_types import Mat33, Mat33Like, Quat, QuatLike, Vec3, Vec3Like
from . import _quat_core, _validation
from .so3 import hat

__all__ = ["compose", "from_matrix", "from_quat", "rotate", "to_matrix", "to_quat"]

_PI_HINT = (
    "; its Gibbs vector 2 tan(χ/2) e is infinite: use quaternions (rigidjax.quat) or MRPs "
    "(rigidjax.mrp) instead"
)


def _ratio(q: Array) -> Vec3:
    return 2 * q[..., 1:] / q[..., :1]


def _half_turn_check(name: str) -> _validation.Check:
    """A quaternion `(..., 4)` whose Gibbs vector is finite (not a 180° rotation, λ0 ≠ 0)."""

    def bad(xp: Any, q: Any) -> Any:
        return ~xp.all(xp.isfinite(2 * q[..., 1:] / q[..., :1]), axis=-1)

    def detail(q: np.ndarray) -> str:
        k = _validation.first(bad(np, q))
        return f" (λ0 = 0 in the quaternion {_validation.fmt(q[k])} of {_validation.at(name, k)})"

    return _validation.Check(bad, f"{name} is a rotation by χ = π", detail, _PI_HINT)


def _finite(g: Vec3, what: str) -> Vec3:
    """`g`, checked finite: else `what` (the product of two rotations) is a half turn."""
    return _validation.validate_all(
        g,
        [
            _validation.Check(
                lambda xp, v: ~xp.all(xp.isfinite(v), axis=-1),
                f"{what} is a rotation by χ = π (or not finite)",
                None,
                _PI_HINT,
            )
        ],
    )


def from_quat(q: QuatLike) -> Vec3:
    """`θ_G = 2 λ/λ0` (`q` any finite non-zero quaternion). Raises for a 180° rotation
    (`λ0 = 0`)."""
    q = vector(q, 4, "q")
    return _ratio(
        _validation.validate_all(q, [*_validation.quat_checks("q"), _half_turn_check("q")])
    )


def to_quat(g: Vec3Like) -> Quat:
    """Unit quaternion `(1, θ_G/2)/√(1 + θ_G²/4)` with λ0 > 0; `g` must be finite."""
    g = _validation.check_finite(vector(g, 3, "g"), "g", 1)
    h = g / 2
    s = 1 / jnp.sqrt(1 + jnp.sum(h * h, axis=-1, keepdims=True))
    return jnp.concatenate([s, s * h], axis=-1)


def from_matrix(P: Mat33Like) -> Vec3:
    """Gibbs vector of a rotation matrix (through the largest-component quaternion; equals
    `4 vee(P)/(1 + tr P)` but loses less accuracy near χ = π). Raises at χ = π, and for a
    non-finite `P` or det P ≤ 0 (see `quat.from_matrix`)."""
    q = _quat_core._from_matrix(matrix(P, "P"), "P")
    return _ratio(_validation.validate_all(q, [_half_turn_check("P")]))


def to_matrix(g: Vec3Like) -> Mat33:
    """`P = E + (R + ½ R²)/(1 + θ_G²/4)`, `R = θ_G × E` (the Cayley transform
    `(E − R/2)⁻¹ (E + R/2)`); `g` must be finite."""
    g = _validation.check_finite(vector(g, 3, "g"), "g", 1)
    R = hat(g)
    c = 1 / (1 + jnp.sum(g * g, axis=-1) / 4)
    return jnp.eye(3, dtype=g.dtype) + c[..., None, None] * (R + 0.5 * (R @ R))


def rotate(g: Vec3Like, r: Vec3Like) -> Vec3:
    """`r' = r + θ_G × (r + ½ θ_G × r)/(1 + θ_G²/4)` (Borisov–Mamaev (001); THEORY §3); `g`
    must be finite."""
    g = _validation.check_finite(vector(g, 3, "g"), "g", 1)
    r = vector(r, 3, "r")
    g = jnp.broadcast_to(g, jnp.broadcast_shapes(g.shape, r.shape))
    c = 1 / (1 + jnp.sum(g * g, axis=-1, keepdims=True) / 4)
    return r + c * jnp.cross(g, r + 0.5 * jnp.cross(g, r))


def compose(g1: Vec3Like, g2: Vec3Like) -> Vec3:
    """Gibbs vector of `P(g1) P(g2)`: `(g1 + g2 + ½ g1 × g2)/(1 − g1·g2/4)` (from the Hamilton
    product divided by λ0(1) λ0(2)). `g1`, `g2` must be finite; raises if the product is a
    180° rotation."""
    g1 = _validation.check_finite(vector(g1, 3, "g1"), "g1", 1)
    g2 = _validation.check_finite(vector(g2, 3, "g2"), "g2", 1)
    num = g1 + g2 + 0.5 * jnp.cross(g1, g2)
    return _finite(
        num / (1 - jnp.sum(g1 * g2, axis=-1, keepdims=True) / 4), "the product P(g1) P(g2)"
    )
