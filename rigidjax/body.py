"""The rigid body as a parameterised equinox Module."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._util import as_float
from .inertia import as_tensor, check_inertia, principal_axes


class RigidBody(eqx.Module):
    """Inertia tensor in body axes (about the centre of mass or the fixed point) and mass.

    `inertia`: principal moments `(..., 3)` or a symmetric tensor `(..., 3, 3)`; it must be
    positive definite and satisfy the triangle inequality (each principal moment ≤ the sum of the
    other two, Zegrya–Parshin 004), checked on construction with an error naming the violated
    condition. Leading dimensions describe a batch of bodies.
    """

    inertia: Float[Array, "*batch 3 3"]
    mass: Float[Array, "*batch"]

    def __init__(self, inertia: ArrayLike, mass: ArrayLike = 1.0, *, check: bool = True):
        I = as_tensor(inertia)
        m = as_float(mass, "mass").astype(I.dtype)
        if check:
            I = check_inertia(I, "inertia")
            if isinstance(m, jax.core.Tracer):
                m = eqx.error_if(m, ~(m > 0), "mass must be positive and finite")
            elif not bool(jnp.all(m > 0) & jnp.all(jnp.isfinite(m))):
                raise ValueError(f"mass must be positive and finite, got {m}")
        self.inertia = I
        self.mass = m

    @property
    def principal_moments(self) -> Float[Array, "*batch 3"]:
        """Principal moments, ascending."""
        return principal_axes(self.inertia)[0]

    @property
    def principal_axes(self) -> Float[Array, "*batch 3 3"]:
        """Principal axes as the columns of a rotation matrix (body components)."""
        return principal_axes(self.inertia)[1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.inertia.shape[:-2])


def euler_rhs(
    inertia: Float[Array, "3 3"],
    inertia_inv: Float[Array, "3 3"],
    omega: Float[Array, "3"],
    torque: Float[Array, "3"],
) -> Float[Array, "3"]:
    """Euler's equations for a general body-frame tensor: `I Ω̇ + Ω × IΩ = K`
    (Zegrya–Parshin 004; in principal axes `I1 Ω̇1 + (I3 − I2) Ω2 Ω3 = K1`, cyclic)."""
    return inertia_inv @ (torque - jnp.cross(omega, inertia @ omega))
