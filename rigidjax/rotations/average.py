"""Rotation averages: the chordal L2 mean of a weighted set of quaternions (Markley et al. 2007)
and the differentiable top eigenvector of a symmetric 4×4 matrix it rests on (also used by
`align.align_vectors`, Davenport's q-method)."""

from __future__ import annotations

from typing import Annotated, Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import as_float, vector
from .._custom_types import Quat, RealLike
from . import _validation as _v
from ._quat_core import _unit, canonical

__all__ = ["mean", "top_eigvec"]


@jax.custom_jvp
def top_eigvec(M: Float[Array, "*#batch 4 4"]) -> Quat:
    """Unit eigenvector of the largest eigenvalue of a symmetric `M (..., 4, 4)` (its sign is
    `eigh`'s). The derivative needs only that eigenvalue to be simple."""
    return jnp.linalg.eigh(M)[1][..., :, -1]


@top_eigvec.defjvp
def _top_eigvec_jvp(primals, tangents):
    # dv = Σ_{i≠top} v_i (v_iᵀ dM v) / (λ_top − λ_i): only the top eigenvalue must be simple, so
    # degenerate lower eigenvalues (e.g. all rotations equal) do not give NaN gradients.
    (M,), (dM,) = primals, tangents
    w, V = jnp.linalg.eigh(M)
    top = V[..., :, -1]
    gap = w[..., -1:] - w
    ok = gap > 0
    proj = jnp.einsum("...ki,...kl,...l->...i", V, dM, top)
    coef = jnp.where(ok, proj / jnp.where(ok, gap, jnp.ones_like(gap)), jnp.zeros_like(gap))
    return top, jnp.einsum("...ki,...i->...k", V, coef)


def mean(
    q: Annotated[RealLike, "*#batch N 4"],
    weights: Annotated[RealLike, "*#batch N"] | None = None,
) -> Quat:
    """Rotation average (Markley et al. 2007, as SciPy `Rotation.mean`): the unit eigenvector of
    the largest eigenvalue of `M = Σ_n w_n q_n q_nᵀ`, returned with λ0 ≥ 0.

    `q` has shape `(..., N, 4)`, N ≥ 1: the set of N rotations lies along axis −2 (each finite,
    non-zero, treated as `q/|q|`, sign-invariant); `weights` `(..., N)`, finite, non-negative and
    not all zero in a set, default all 1. Returns `(..., 4)`. Gradients are finite unless the
    largest eigenvalue is degenerate (mean not unique).
    """
    q = vector(q, 4, "q")
    if q.ndim < 2:
        raise ValueError(f"q must have shape (..., N, 4), got {tuple(q.shape)}")
    if q.shape[-2] == 0:
        raise ValueError(
            f"q must hold at least one rotation (N ≥ 1 along axis -2), got shape {q.shape}: the "
            "mean of an empty set is undefined"
        )
    q = _unit(q, "q")
    if weights is None:
        w = jnp.ones(q.shape[:-1], q.dtype)
    else:
        w = as_float(weights, "weights")
        if w.ndim < 1 or w.shape[-1] != q.shape[-2]:
            raise ValueError(
                f"weights must have shape (..., N) with N = {q.shape[-2]} (one weight per "
                f"rotation of q, shape {q.shape}), got {w.shape}"
            )
        w = _v.validate_all(w, _weight_checks("weights"))
    M = jnp.einsum("...n,...ni,...nj->...ij", w, q, q)
    return canonical(top_eigvec(M))


def _weight_checks(name: str) -> list[_v.Check]:
    """Weights `(..., N)` of a set: finite, non-negative, not all zero."""

    def negative(xp: Any, w: Any) -> Any:
        return w < 0

    def all_zero(xp: Any, w: Any) -> Any:
        return ~(xp.sum(w, axis=-1) > 0)

    def at_negative(w: np.ndarray) -> str:
        k = _v.first(negative(np, w))
        return f", got {_v.at(name, k)} = {w[k]:.6g}"

    def at_zero(w: np.ndarray) -> str:
        k = _v.first(all_zero(np, w))
        return f", got {_v.at(name, k)} = {_v.fmt(w[k])}"

    return [
        _v.finite_check(name, 0),
        _v.Check(
            negative,
            f"{name} must be non-negative",
            at_negative,
            "; a weight is the importance of its rotation (0 leaves it out)",
        ),
        _v.Check(
            all_zero,
            f"{name} must not all be zero in a set",
            at_zero,
            "; the mean of no rotation is undefined: give some rotation of each set a weight > 0",
        ),
    ]
