"""Two example control laws, each an equinox Module called as
`controller(t_k, omega_k, q_k, params) -> command`: the gains are its fields (so that
`jax.grad` reaches them through a closure) and may be replaced by `params`, a dict passed as
`simulate(..., controller_params=...)`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import as_float, check_finite, check_unit_norm, validate, vector
from .._custom_types import RealLike
from ..rotations import quat


def _gain(params: Any, name: str, default: Array) -> Array:
    """`params[name]` if given, else the law's own gain."""
    if params is None:
        return default
    if not isinstance(params, dict):
        raise TypeError(
            f"controller_params must be None or a dict of gains (e.g. {{{name!r}: ...}}), got "
            f"{type(params).__name__}"
        )
    return jnp.asarray(params.get(name, default))


def _gain_arg(x: RealLike, name: str) -> Array:
    """A law's gain, checked finite and non-negative (a negative gain drives the body away:
    the error grows, or B-dot adds energy)."""
    return validate(
        check_finite(as_float(x, name), name),
        lambda xp, v: ~(v >= 0),
        f"{name} must be non-negative",
        lambda v: f", got {v}" if v.ndim == 0 else f", got min {np.min(v)}",
        hint=" (a negative gain pushes the body away from the goal)",
    )


class QuaternionPD(eqx.Module):
    """Quaternion-feedback PD law (Wie, Weiss & Arapostathis, J. Guid. Control Dyn. 12(3), 1989;
    Wie, *Space Vehicle Dynamics and Control*, §7.3): with the error quaternion
    `q_e = q_target⁻¹ ∘ q` (body frame), the body torque `u = −kp sgn(q_e0) q_e,1:3 − kd Ω`
    (the sign takes the shorter way round). With `wheel_axes A (3, n)` it returns the motor
    torques whose reaction `−A u_w` is `u`: `u_w = −A⁺ u` (the minimum-norm allocation)."""

    kp: Float[Array, "*#k"]
    kd: Float[Array, "*#k"]
    q_target: Float[Array, "4"]
    allocation: Float[Array, "n 3"] | None

    def __call__(self, t: RealLike, omega: RealLike, q: RealLike, params: Any = None) -> Array:
        omega, q = jnp.asarray(omega), jnp.asarray(q)
        kp, kd = _gain(params, "kp", self.kp), _gain(params, "kd", self.kd)
        qe = quat.mul(quat.conj(self.q_target), q)
        sign = jnp.where(qe[..., :1] < 0, -1.0, 1.0)  # (any leading batch dimensions)
        u = -kp * sign * qe[..., 1:] - kd * omega
        return u if self.allocation is None else u @ self.allocation.T


def quaternion_pd(
    kp: RealLike, kd: RealLike, q_target: RealLike, wheel_axes: RealLike | None = None
) -> QuaternionPD:
    """The `QuaternionPD` law `u = −kp sgn(q_e0) q_e,1:3 − kd Ω` towards the attitude
    `q_target (4,)` (unit; P body → space) with gains `kp`, `kd` ≥ 0 (scalars or `(3,)`), for a
    body torque, or for the wheels with unit spin axes `wheel_axes (3, n)` (motor torques
    `−A⁺ u`; the axes checked as `Gyrostat` checks them)."""
    qt = check_unit_norm(vector(q_target, 4, "q_target"), "q_target")
    if qt.shape != (4,):
        raise ValueError(f"q_target must be one quaternion, shape (4,), got {qt.shape}")
    allocation = None
    if wheel_axes is not None:
        A = as_float(wheel_axes, "wheel_axes")
        if A.ndim != 2 or A.shape[0] != 3:
            raise ValueError(f"wheel_axes must have shape (3, n), got {A.shape}")
        A = check_unit_norm(A.T, "wheel_axes (columns)", "; give unit spin axes").T  # as Gyrostat
        allocation = -jnp.linalg.pinv(A / jnp.linalg.norm(A, axis=0))
    return QuaternionPD(
        _gain_arg(kp, "kp"),
        _gain_arg(kd, "kd"),
        qt / jnp.linalg.norm(qt),
        allocation,
    )


class BDot(eqx.Module):
    """B-dot detumbling (Stickler & Alfriend, J. Spacecraft 13(5), 1976; Markley & Crassidis,
    *Fundamentals of Spacecraft Attitude Determination and Control*, §7.5.1): the magnetic
    dipole `m = −k Ḃ` with `Ḃ = −Ω × B` (the body-frame rate of a field fixed in space over one
    sample) and the torque `m × B`, `B = P(q)ᵀ b(t)` in body axes. It removes the rates across
    the field: `d/dt ½ Ω·IΩ = −k |Ω × B|²` in continuous time."""

    gain: Float[Array, ""]
    b_field: Callable[[Array], Array] | None

    def __call__(self, t: RealLike, omega: RealLike, q: RealLike, params: Any = None) -> Array:
        t, omega, q = jnp.asarray(t), jnp.asarray(omega), jnp.asarray(q)
        k = _gain(params, "gain", self.gain)
        b = jnp.array([0.0, 0.0, 1.0], omega.dtype) if self.b_field is None else self.b_field(t)
        B = quat.rotate(quat.conj(q), jnp.asarray(b, omega.dtype))
        dipole = -k * -jnp.cross(omega, B)
        return jnp.cross(dipole, B)


def bdot(gain: RealLike, b_field: Callable[[Array], Array] | None = None) -> BDot:
    """The `BDot` law with gain `k ≥ 0` and the magnetic field in space `b_field(t) -> (3,)`
    (default: a unit field along space Z)."""
    return BDot(_gain_arg(gain, "gain"), b_field)
