"""Numerical guards shared by the formulas: Taylor series at removable singularities with the
double-`where` trick, so values AND gradients stay finite (jax#1052)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax.numpy as jnp
from jaxtyping import Array, DTypeLike, Float


def small_threshold(dtype: DTypeLike) -> float:
    """Below this value of θ² the truncated Taylor series is used instead of the closed form.

    Four-term series are accurate to ~x⁴/9! there; the closed forms lose ~eps/x to cancellation
    just above it, so the threshold depends on the precision.
    """
    return 1e-2 if jnp.finfo(dtype).eps < 1e-10 else 1e-1


def guarded(
    x2: Float[Array, "*shape"],
    exact: Callable[[Array], Array],
    series: Callable[[Array], Array],
) -> Float[Array, "*shape"]:
    """Evaluate f(x²) by `series` near 0 and `exact` elsewhere, with finite values AND gradients.

    The double-`where` trick: the exact branch is fed a harmless value where it is not selected,
    so its (discarded) derivative cannot be NaN (jax#1052).
    """
    small = x2 < small_threshold(x2.dtype)
    x2_safe = jnp.where(small, jnp.ones_like(x2), x2)
    return jnp.where(small, series(x2), exact(x2_safe))


def poly(x: Float[Array, "*shape"], coeffs: Sequence[float]) -> Float[Array, "*shape"]:
    """Horner evaluation of Σ coeffs[k] x^k."""
    out = jnp.full_like(x, coeffs[-1])
    for c in reversed(coeffs[:-1]):
        out = out * x + c
    return out


def safe_sqrt(x: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """`√max(x, 0)` with a finite (zero) gradient at and below 0 (double-`where`)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, jnp.ones_like(x))), jnp.zeros_like(x))


def cross3(a: Float[Array, "*#batch 3"], b: Float[Array, "*#batch 3"]) -> Float[Array, "*batch 3"]:
    """`a × b` from the components read in one `unstack` each (`jnp.cross` indexes them one by
    one: a larger program to trace and differentiate)."""
    a0, a1, a2 = jnp.unstack(a, axis=-1)
    b0, b1, b2 = jnp.unstack(b, axis=-1)
    return jnp.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def cofactors(
    M: Float[Array, "*batch 3 3"],
) -> tuple[Float[Array, "*batch 3 3"], Float[Array, "*batch"]]:
    """The cofactor matrix of a 3×3 `M` (its rows the cross products of the rows of M,
    `cof(M) = det(M) M⁻ᵀ`) and `det M = r0 · (r1 × r2)`."""
    r0, r1, r2 = jnp.unstack(M, axis=-2)
    c0 = cross3(r1, r2)
    return jnp.stack([c0, cross3(r2, r0), cross3(r0, r1)], axis=-2), jnp.sum(r0 * c0, axis=-1)


def inv3(M: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """Inverse of a 3×3 matrix by cofactors, `M⁻¹ = cof(M)ᵀ/det M`; a small program to compile
    and to vectorise over a batch, unlike a pivoted LU."""
    cof, det = cofactors(M)
    return cof.T / det
