"""Rotation magnitude, powers and approximate equality, as SciPy's `Rotation.magnitude`,
`Rotation.__pow__` and `Rotation.approx_equal`.

`q^p = exp(p log q)`: the rotation about the same axis by p times the angle of `canonical(q)`,
`|θ| ≤ π` (SciPy's definition: `from_rotvec(p * as_rotvec())`; for a 180° rotation `q^½`
follows the axis sign of `to_rotvec`). The magnitude is `2 atan2(|λ|, |λ0|) ∈ [0, π]`.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp

from .._checks import as_float, vector
from .._custom_types import Quat, QuatLike, Scalar, ScalarLike
from . import _validation as _v
from ._quat_core import _angle, _from_rotvec, _to_rotvec, _unit, conj, identity, mul

__all__ = ["approx_equal", "magnitude", "power"]


def magnitude(q: QuatLike) -> Scalar:
    """Rotation angle ∈ [0, π] of `q` (SciPy's `Rotation.magnitude`; the same as `quat.angle`):
    `2 atan2(|λ|, |λ0|)`. Finite gradient at the identity (zero subgradient). `q` must be finite
    and non-zero."""
    return _angle(_v.check_quat(vector(q, 4, "q"), "q"))


def power(q: QuatLike, p: ScalarLike) -> Quat:
    """`q^p` (SciPy's `Rotation.__pow__`): `from_rotvec(p · to_rotvec(q))`, unit quaternion.

    As SciPy, `p = 0` gives the identity, `p = 1` returns `q/|q|` and `p = −1` `inv(q)/|q|⁻¹` with
    their sign as given (the general formula gives the `canonical` sign); the derivatives there
    are those of the general formula (correct in `p`). `p` (...) broadcasts against the batch
    dimensions of `q (..., 4)` (SciPy takes a scalar only). `q` must be finite and non-zero, `p`
    finite.
    """
    q = _unit(vector(q, 4, "q"), "q")
    p = _v.check_finite(as_float(p, "p"), "p", 0).astype(q.dtype)
    general = _from_rotvec(p[..., None] * _to_rotvec(q))
    special = jnp.where(
        (p == 0)[..., None],
        identity(dtype=q.dtype),
        jnp.where((p == -1)[..., None], conj(q), q),
    )
    is_special = ((p == 0) | (p == 1) | (p == -1))[..., None]
    # value of the special case, derivative of the general formula (same rotation, sign s)
    s = jax.lax.stop_gradient(jnp.where(jnp.sum(special * general, -1, keepdims=True) < 0, -1, 1))
    snapped = s * general + jax.lax.stop_gradient(special - s * general)
    return jnp.where(is_special, snapped, general)


def approx_equal(
    a: QuatLike, b: QuatLike, atol: float | None = None, degrees: bool = False
) -> jax.Array:
    """Whether `a` and `b` are the same rotation within `atol` (SciPy's
    `Rotation.approx_equal`): the magnitude of `b ∘ a⁻¹` is below `atol` (radians, or degrees
    with `degrees=True`; default 1e-8 rad, and then `degrees=True` warns as SciPy does). `a`, `b`
    `(..., 4)` broadcast; returns a boolean array of their batch shape. `q` and `−q` are equal.
    """
    a = _unit(vector(a, 4, "a"), "a")
    b = _unit(vector(b, 4, "b"), "b")
    try:
        jnp.broadcast_shapes(a.shape, b.shape)
    except ValueError:
        raise ValueError(
            f"Expected broadcastable shapes in both rotations, got {a.shape[:-1]} rotations in "
            f"first and {b.shape[:-1]} rotations in second object (a and b must broadcast)"
        ) from None
    if atol is None:
        if degrees:
            warnings.warn(
                "atol must be set to use the degrees flag, defaulting to 1e-8 radians.",
                stacklevel=2,
            )
        tol = 1e-8
    else:
        tol = atol * (jnp.pi / 180) if degrees else atol
    return _angle(mul(b, conj(a))) < tol
