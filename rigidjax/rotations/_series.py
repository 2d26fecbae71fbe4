"""Coefficients of the rotation formulas as functions of θ² = θ·θ, finite with finite gradients.

Each is the closed form away from θ = 0 and its Taylor series near it (see
`rigidjax._numerics.guarded`).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._numerics import guarded, poly


def sin_over(x2: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """A(θ) = sin θ / θ."""
    return guarded(
        x2,
        lambda x: jnp.sin(jnp.sqrt(x)) / jnp.sqrt(x),
        lambda x: poly(x, [1.0, -1 / 6, 1 / 120, -1 / 5040, 1 / 362880]),
    )


def one_minus_cos_over(x2: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """B(θ) = (1 − cos θ) / θ² = 2 sin²(θ/2) / θ² (the second form has no cancellation)."""
    return guarded(
        x2,
        lambda x: 2 * jnp.sin(jnp.sqrt(x) / 2) ** 2 / x,
        lambda x: poly(x, [1 / 2, -1 / 24, 1 / 720, -1 / 40320, 1 / 3628800]),
    )


def theta_minus_sin_over(x2: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """C(θ) = (θ − sin θ) / θ³."""
    return guarded(
        x2,
        lambda x: (jnp.sqrt(x) - jnp.sin(jnp.sqrt(x))) / (x * jnp.sqrt(x)),
        lambda x: poly(x, [1 / 6, -1 / 120, 1 / 5040, -1 / 362880, 1 / 39916800]),
    )


def zhilin_d(x2: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """D(θ) = (1 − g)/θ², g = θ sin θ / (2(1 − cos θ)) = (θ/2) cot(θ/2)  (Zhilin 3.14.15).

    Finite for |θ| < 2π; singular at |θ| = 2π (where det Z = ∞).
    """

    def exact(x):
        h = jnp.sqrt(x) / 2
        return (1 - h * jnp.cos(h) / jnp.sin(h)) / x

    return guarded(
        x2, exact, lambda x: poly(x, [1 / 12, 1 / 720, 1 / 30240, 1 / 1209600, 1 / 47900160])
    )


def half_sin_over(x2: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """sin(θ/2) / θ (vector part of the unit quaternion of rotation vector θ)."""
    return guarded(
        x2,
        lambda x: jnp.sin(jnp.sqrt(x) / 2) / jnp.sqrt(x),
        lambda x: poly(x, [1 / 2, -1 / 48, 1 / 3840, -1 / 645120, 1 / 185794560]),
    )


def half_cos(x2: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """cos(θ/2), as a function of θ² with a finite gradient at 0."""
    return guarded(
        x2,
        lambda x: jnp.cos(jnp.sqrt(x) / 2),
        lambda x: poly(x, [1.0, -1 / 8, 1 / 384, -1 / 46080, 1 / 10321920]),
    )
