"""The rigid body as a parameterised equinox Module."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import as_float, check_positive
from .._custom_types import InertiaLike, Mat33, Scalar, ScalarLike, Vec3
from .inertia import as_tensor, check_inertia, diagonal, principal_axes

__all__ = ["RigidBody", "euler_rhs"]


class RigidBody(eqx.Module):
    """Inertia tensor in body axes (about the centre of mass or the fixed point) and mass.

    `inertia`: principal moments `(..., 3)` or a symmetric tensor `(..., 3, 3)`; it must be
    positive definite and satisfy the triangle inequality (each principal moment ≤ the sum of the
    other two, Zegrya–Parshin 004), checked on construction with an error naming the violated
    condition. Leading dimensions describe a batch of bodies.
    """

    inertia: Mat33
    mass: Scalar
    diagonal: bool = eqx.field(static=True)

    def __init__(self, inertia: InertiaLike, mass: ScalarLike = 1.0, *, check: bool = True):
        inertia = as_float(inertia, "inertia")
        # principal moments given: the tensor is diagonal by construction (a static fact that
        # lets the integrators use elementwise Euler equations)
        self.diagonal = (
            inertia.ndim >= 1
            and inertia.shape[-1] == 3
            and (inertia.ndim < 2 or inertia.shape[-2] != 3)
        )
        I = as_tensor(inertia)
        m = as_float(mass, "mass").astype(I.dtype)
        batch = I.shape[:-2]
        try:
            fits = np.broadcast_shapes(m.shape, batch) == batch
        except ValueError:
            fits = False
        if not fits:
            raise ValueError(
                f"mass must be a scalar or broadcast to the inertia's batch shape {batch} (one "
                f"mass per body), got shape {m.shape}"
            )
        if check:
            I = check_inertia(I, "inertia", diagonal=self.diagonal)
            m = check_positive(m, "mass")
        self.inertia = I
        self.mass = m

    @property
    def principal_moments(self) -> Vec3:
        """Principal moments, ascending."""
        return principal_axes(self.inertia)[0]

    @property
    def principal_axes(self) -> Mat33:
        """Principal axes as the columns of a rotation matrix (body components)."""
        return principal_axes(self.inertia)[1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.inertia.shape[:-2])

    def operator(self) -> tuple[Mat33 | Vec3, Mat33 | Vec3]:
        """`(I, I⁻¹)` for `euler_rhs`: the principal moments `(..., 3)` and their reciprocals for
        a diagonal body, else the tensor and its inverse `(..., 3, 3)`."""
        if self.diagonal:
            m = diagonal(self.inertia)
            return m, 1 / m
        return self.inertia, jnp.linalg.inv(self.inertia)


def _apply(A: Array, x: Array) -> Array:
    """`A x` for a diagonal `A` given by its entries (same rank as x) or a full matrix, in
    elementwise form (fuses well on CPU, unlike many tiny batched dot products)."""
    if A.ndim == x.ndim:
        return A * x
    return jnp.sum(A * x[..., None, :], axis=-1)


def euler_rhs(inertia: Mat33 | Vec3, inertia_inv: Mat33 | Vec3, omega: Vec3, torque: Vec3) -> Vec3:
    """Euler's equations `I Ω̇ + Ω × IΩ = K` solved for Ω̇ (Zegrya–Parshin 004; in principal
    axes `I1 Ω̇1 + (I3 − I2) Ω2 Ω3 = K1`, cyclic). `inertia`, `inertia_inv` as from
    `RigidBody.operator()`: moments `(..., 3)` or tensors `(..., 3, 3)`."""
    return _apply(inertia_inv, torque - jnp.cross(omega, _apply(inertia, omega)))
