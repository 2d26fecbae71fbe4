"""The `Gyrostat` parameters: a rigid body with rotors (see `rigidjax.mechanics.gyrostat`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import as_float, check_finite, check_positive, check_unit_norm, validate
from .._custom_types import RealLike
from ..rotations._validation import det
from .body import RigidBody


class Gyrostat(eqx.Module):
    """A rigid body with rotors: `inertia` of the whole system (principal moments `(3,)` or a
    tensor `(3, 3)`, as `RigidBody`), a constant internal momentum `h (3,)` (body axes; zero by
    default), and optionally reaction wheels: spin axes `wheel_axes (3, n)` (columns, normalised
    here), axial inertias `wheel_inertia (n,)` and a motor-torque bound `wheel_torque_max`
    (scalar or `(n,)`; unbounded by default). One gyrostat (no batch dimensions): `simulate`
    broadcasts the initial states, `jax.vmap` maps over gyrostats."""

    body: RigidBody
    h: Float[Array, "3"]
    wheel_axes: Float[Array, "3 n"] | None
    wheel_inertia: Float[Array, " n"] | None
    wheel_torque_max: Float[Array, " n"] | None

    def __init__(
        self,
        inertia: RealLike,
        h: RealLike | None = None,
        wheel_axes: RealLike | None = None,
        wheel_inertia: RealLike | None = None,
        wheel_torque_max: RealLike | None = None,
    ):
        self.body = RigidBody(inertia)
        if self.body.batch_shape:
            raise ValueError(
                f"Gyrostat takes one body, got inertia of batch shape {self.body.batch_shape}: "
                "use jax.vmap over the gyrostat for batches"
            )
        dtype = self.body.inertia.dtype
        self.h = (
            jnp.zeros(3, dtype) if h is None else check_finite(_exact(h, (3,), "h", dtype), "h")
        )
        if (wheel_axes is None) != (wheel_inertia is None):
            raise ValueError(
                "give both wheel_axes (3, n) and wheel_inertia (n,) for a gyrostat with wheels "
                "(or neither)"
            )
        if wheel_axes is None or wheel_inertia is None:
            if wheel_torque_max is not None:
                raise ValueError("wheel_torque_max bounds the wheels' torques: give wheel_axes")
            self.wheel_axes = self.wheel_inertia = self.wheel_torque_max = None
            return
        A = as_float(wheel_axes, "wheel_axes").astype(dtype)
        if A.ndim != 2 or A.shape[0] != 3 or A.shape[1] == 0:
            raise ValueError(
                f"wheel_axes must have shape (3, n): the spin axes as columns, got {A.shape}"
            )
        n = A.shape[1]
        A = check_unit_norm(A.T, "wheel_axes (columns)", "; give unit spin axes").T
        A = A / jnp.linalg.norm(A, axis=0)
        self.wheel_axes = A
        J = check_positive(_exact(wheel_inertia, (n,), "wheel_inertia", dtype), "wheel_inertia")
        self.wheel_inertia = validate(
            self.body.inertia - (A * J) @ A.T,
            _not_positive_definite,
            "wheel_inertia too large: I − A diag(J) Aᵀ (the inertia with the wheels free) must "
            "be positive definite; give the inertia of the whole system, wheels included",
            on=J,
        )
        self.wheel_torque_max = (
            None
            if wheel_torque_max is None
            else check_positive(_per_wheel(wheel_torque_max, n, dtype), "wheel_torque_max")
        )

    @property
    def wheels(self) -> int:
        """The number of wheels (0 without)."""
        return 0 if self.wheel_axes is None else self.wheel_axes.shape[1]

    def momentum(self, wheel_speed: Array | None) -> Array:
        """`h = h_const + A J ω_w` (`(..., 3)`) for wheel speeds `(..., n)` (or the constant h)."""
        if self.wheel_axes is None or self.wheel_inertia is None or wheel_speed is None:
            return self.h
        return self.h + (wheel_speed * self.wheel_inertia) @ self.wheel_axes.T

    def clip(self, u: Array) -> Array:
        """Motor torques `u (n,)` clipped to `±wheel_torque_max`."""
        if self.wheel_torque_max is None:
            return u
        return jnp.minimum(jnp.maximum(u, -self.wheel_torque_max), self.wheel_torque_max)


def _per_wheel(x: RealLike, n: int, dtype) -> Array:
    """The motor-torque bound: one for every wheel (a scalar) or one per wheel `(n,)`."""
    x = as_float(x, "wheel_torque_max").astype(dtype)
    if x.shape not in ((), (n,)):
        raise ValueError(
            f"wheel_torque_max must be a scalar or have shape ({n},) (one bound per wheel), got "
            f"{x.shape}"
        )
    return jnp.broadcast_to(x, (n,))


def _exact(x: RealLike, shape: tuple[int, ...], name: str, dtype) -> Array:
    x = as_float(x, name).astype(dtype)
    if x.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {x.shape}")
    return x


def _not_positive_definite(xp, M):
    """Whether the symmetric 3×3 `M` is not positive definite, by Sylvester's criterion (its
    leading principal minors positive): closed form, unlike an eigensolver per matrix."""
    m1 = M[..., 0, 0]
    m2 = m1 * M[..., 1, 1] - M[..., 0, 1] * M[..., 1, 0]
    m3 = det(xp, M)
    return ~((m1 > 0) & (m2 > 0) & (m3 > 0))[..., None]
