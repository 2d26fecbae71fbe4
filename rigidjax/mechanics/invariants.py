"""Integrals of the free rigid body and their drift along a trajectory (Zegrya–Parshin 004)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import vector
from .._custom_types import Mat33, QuatLike, Scalar, Vec3, Vec3Like
from ..rotations import quat
from .body import RigidBody

__all__ = ["angular_momentum", "drift", "energy", "momentum_squared"]


def _batched_inertia(body: RigidBody, omega: Array) -> Mat33:
    # inertia (..., 3, 3) broadcast against omega (..., [T,] 3): insert the time axis if needed
    if not isinstance(body, RigidBody):
        raise TypeError(
            f"body must be a rigidjax.RigidBody, got {type(body).__name__}: wrap the inertia, "
            "e.g. energy(RigidBody(inertia), omega)"
        )
    I = body.inertia
    extra = omega.ndim - 1 - (I.ndim - 2)
    I = I.reshape(I.shape[:-2] + (1,) * max(extra, 0) + (3, 3))
    try:
        jnp.broadcast_shapes(I.shape[:-2], omega.shape[:-1])
    except ValueError:
        raise ValueError(
            f"the body's batch {body.batch_shape} does not match omega's {omega.shape}: give "
            "one ω (..., 3) or one trajectory (..., T, 3) per body, the bodies' batch leading"
        ) from None
    return I


def angular_momentum(body: RigidBody, omega: Vec3Like, q: QuatLike | None = None) -> Vec3:
    """`M = I Ω` in body components; with the attitude `q`, the space components `P(q) I Ω`."""
    omega = vector(omega, 3, "omega")
    M = jnp.einsum("...ij,...j->...i", _batched_inertia(body, omega), omega)
    return M if q is None else quat.rotate(q, M)


def energy(body: RigidBody, omega: Vec3Like) -> Scalar:
    """Kinetic energy of rotation `T = ½ I_ik Ω_i Ω_k = ½ M·Ω`."""
    omega = vector(omega, 3, "omega")
    return 0.5 * jnp.sum(angular_momentum(body, omega) * omega, axis=-1)


def momentum_squared(body: RigidBody, omega: Vec3Like) -> Scalar:
    """`|M|² = |I Ω|²` (`I1²Ω1² + I2²Ω2² + I3²Ω3²` in principal axes)."""
    M = angular_momentum(body, omega)
    return jnp.sum(M * M, axis=-1)


def drift(
    body: RigidBody, omega: Float[Array, "*#batch T 3"], q: Float[Array, "*#batch T 4"]
) -> dict[str, Scalar]:
    """Largest relative deviation from the initial value along a torque-free trajectory of:
    the energy, |M|, and the space angular momentum vector (relative to |M(0)|)."""
    T = energy(body, omega)
    Mn = jnp.sqrt(momentum_squared(body, omega))
    Ms = angular_momentum(body, omega, q)
    return {
        "energy": jnp.max(jnp.abs(T / T[..., :1] - 1), axis=-1),
        "momentum_norm": jnp.max(jnp.abs(Mn / Mn[..., :1] - 1), axis=-1),
        "momentum_space": jnp.max(
            jnp.linalg.norm(Ms - Ms[..., :1, :], axis=-1) / Mn[..., :1], axis=-1
        ),
    }
