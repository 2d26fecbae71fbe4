"""Cayley–Klein parameters and SU(2): the complex 2×2 forms of a rotation (Borisov–Mamaev
(001); THEORY §3). Also available as `rigidjax.quat.to_cayley_klein`, ... ."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, DTypeLike

from .._checks import as_float, check_shape, vector
from .._custom_types import CMat22, CMat22Like, Quat, QuatLike, Vec3, Vec3Like
from . import _validation as v
from ._quat_core import _unit, norm2

__all__ = [
    "from_cayley_klein",
    "from_su2",
    "pauli",
    "sigma_to_vec",
    "su2_act",
    "to_cayley_klein",
    "to_su2",
    "vec_to_sigma",
]


def _complex_dtype(dtype: DTypeLike) -> jnp.dtype:
    return jnp.result_type(dtype, jnp.complex64)


def _c2(x: CMat22Like, name: str) -> CMat22:
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.complexfloating):
        x = as_float(x, name)
        x = x.astype(_complex_dtype(x.dtype))
    check_shape(x, (2, 2), name)
    return x


def to_cayley_klein(q: QuatLike) -> CMat22:
    """Cayley–Klein matrix `[[α, β], [γ, δ]]`, `α = λ0 + iλ3`, `β = −λ2 + iλ1`, `γ = λ2 + iλ1`,
    `δ = λ0 − iλ3`, `αδ − βγ = 1` (Borisov–Mamaev (001); `q` treated as `q/|q|`).

    It is the complex conjugate of `to_su2(q)`. complex64 for float32 input, complex128 for
    float64. `q` must be finite and non-zero.
    """
    q = _unit(vector(q, 4, "q"), "q")
    l0, l1, l2, l3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    c = jax.lax.complex
    row0 = jnp.stack([c(l0, l3), c(-l2, l1)], axis=-1)
    row1 = jnp.stack([c(l2, l1), c(l0, -l3)], axis=-1)
    return jnp.stack([row0, row1], axis=-2)


def from_cayley_klein(U: CMat22Like) -> Quat:
    """Unit quaternion of a Cayley–Klein matrix (inverse of `to_cayley_klein`, sign kept).

    Averages the redundant entries, `λ0 = Re(α + δ)/2`, `λ1 = Im(β + γ)/2`, `λ2 = Re(γ − β)/2`,
    `λ3 = Im(α − δ)/2` (the orthogonal projection onto such matrices), then normalises. `U` must
    be finite, with a non-zero projection.
    """
    U = v.check_finite(_c2(U, "U"), "U", 2)
    a, b, g, d = U[..., 0, 0], U[..., 0, 1], U[..., 1, 0], U[..., 1, 1]
    q = jnp.stack([jnp.real(a + d), jnp.imag(b + g), jnp.real(g - b), jnp.imag(a - d)], axis=-1)
    bad = v.quat_checks("U")[1].bad

    def detail(qn: np.ndarray) -> str:
        k = v.first(bad(np, qn))
        return f": {v.at('U', k)} = {v.fmt(np.asarray(U)[k])}"

    zero = v.Check(
        bad,
        "U has no rotation part: its projection (λ0, λ1, λ2, λ3) onto Cayley–Klein matrices is "
        "zero",
        detail,
        "; a Cayley–Klein matrix [[α, β], [−β̄, ᾱ]] needs |α|² + |β|² > 0",
    )
    return q / jnp.sqrt(v.validate_all(q, [zero], norm2(q)))[..., None]


def pauli(dtype: DTypeLike | None = None) -> Complex[Array, "3 2 2"]:
    """The Pauli matrices `σ1 = [[0, 1], [1, 0]]`, `σ2 = [[0, −i], [i, 0]]`,
    `σ3 = [[1, 0], [0, −1]]`, stacked `(3, 2, 2)`."""
    dtype = _complex_dtype(jnp.result_type(float) if dtype is None else dtype)
    return jnp.array([[[0, 1], [1, 0]], [[0, -1j], [1j, 0]], [[1, 0], [0, -1]]], dtype)


def vec_to_sigma(r: Vec3Like) -> CMat22:
    """`r·σ = [[r3, r1 − i r2], [r1 + i r2, −r3]]` (Hermitian, traceless)."""
    r = vector(r, 3, "r")
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    c = jax.lax.complex
    row0 = jnp.stack([c(z, jnp.zeros_like(z)), c(x, -y)], axis=-1)
    row1 = jnp.stack([c(x, y), c(-z, jnp.zeros_like(z))], axis=-1)
    return jnp.stack([row0, row1], axis=-2)


def sigma_to_vec(S: CMat22Like) -> Vec3:
    """`r` with `r·σ` the Hermitian traceless part of `S`: `r_k = Re tr(S σ_k)/2`."""
    S = _c2(S, "S")
    return jnp.stack(
        [
            jnp.real(S[..., 0, 1] + S[..., 1, 0]) / 2,
            jnp.imag(S[..., 1, 0] - S[..., 0, 1]) / 2,
            jnp.real(S[..., 0, 0] - S[..., 1, 1]) / 2,
        ],
        axis=-1,
    )


def to_su2(q: QuatLike) -> CMat22:
    """Physics SU(2) matrix `U = λ0 σ0 − i λ·σ` (`q` treated as `q/|q|`; THEORY §3).

    It acts by `U (r·σ) Uᴴ = (P r)·σ` (see `su2_act`) and is the complex conjugate of
    `to_cayley_klein(q)`. Exercise 002's `cos φ σ0 + i sin φ (h·σ)` equals `to_su2` of the turn by
    −2φ about h: with these Pauli matrices it is the inverse (passive) rotation.
    """
    return jnp.conj(to_cayley_klein(q))


def from_su2(U: CMat22Like) -> Quat:
    """Unit quaternion (sign kept) of `U = λ0 σ0 − i λ·σ`; inverse of `to_su2`."""
    return from_cayley_klein(jnp.conj(_c2(U, "U")))


def su2_act(U: CMat22Like, r: Vec3Like) -> Vec3:
    """`r'` with `r'·σ = U (r·σ) Uᴴ`; equals `rotate(from_su2(U), r)` for `U` in SU(2)."""
    U = _c2(U, "U")
    S = vec_to_sigma(r)
    return sigma_to_vec(U @ S @ jnp.conj(jnp.swapaxes(U, -1, -2)))
