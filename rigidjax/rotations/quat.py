"""Rodrigues–Hamilton parameters (unit quaternions), scalar-first `(λ0, λ1, λ2, λ3)`.

Conventions (THEORY §3): Hamilton product, `λ0 = cos(θ/2)`, `λ = sin(θ/2) m`; `q` and `−q` are
the same rotation. Functions that map a quaternion to a rotation accept any non-zero `q` and treat
it as `q/|q|` (like SciPy); `normalize` raises on a zero quaternion.
"""

from __future__ import annotations

from typing import Annotated

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, DTypeLike, Float, PRNGKeyArray, Real

from .._checks import as_float, check_shape, matrix, vector
from .._custom_types import (
    CMat22,
    CMat22Like,
    Mat33,
    Mat33Like,
    Quat,
    QuatLike,
    RealLike,
    Scalar,
    ScalarLike,
    Vec3,
    Vec3Like,
)
from . import _series


def _split(q: Quat) -> tuple[Scalar, Vec3]:
    return q[..., 0], q[..., 1:]


def _join(w: Scalar, v: Vec3) -> Quat:
    w, v = jnp.broadcast_arrays(w[..., None], v)
    return jnp.concatenate([w[..., :1], v], axis=-1)


def identity(shape: tuple[int, ...] = (), dtype: DTypeLike | None = None) -> Quat:
    """The identity rotation `(1, 0, 0, 0)` with leading shape `shape`."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    return jnp.zeros((*shape, 4), dtype).at[..., 0].set(1)


def mul(a: QuatLike, b: QuatLike) -> Quat:
    """Hamilton product `a ∘ b`: `λ0 = μ0ν0 − μ·ν`, `λ = μ0 ν + ν0 μ + μ × ν`
    (article 003 (68)–(69)).

    `to_matrix(mul(a, b)) = to_matrix(a) @ to_matrix(b)`.
    """
    a = vector(a, 4, "a")
    b = vector(b, 4, "b")
    a0, av = _split(a)
    b0, bv = _split(b)
    w = a0 * b0 - jnp.sum(av * bv, axis=-1)
    v = a0[..., None] * bv + b0[..., None] * av + jnp.cross(av, bv)
    return _join(w, v)


def conj(q: QuatLike) -> Quat:
    """Conjugate `(λ0, −λ)`: the inverse rotation for a unit quaternion."""
    q = vector(q, 4, "q")
    return q * jnp.array([1, -1, -1, -1], q.dtype)


def norm2(q: Real[ArrayLike, "*#batch 4"]) -> Scalar:
    """`|q|²` (no validation: for arrays already checked by the caller)."""
    return jnp.sum(q * q, axis=-1)


def _checked_norm2(q: Quat, name: str) -> Scalar:
    n2 = norm2(q)
    return eqx.error_if(
        n2,
        ~(n2 > 0),
        f"{name} is a zero (or non-finite) quaternion; a rotation needs |{name}| > 0",
    )


def normalize(q: QuatLike) -> Quat:
    """`q / |q|`; raises a clear error for a zero or non-finite quaternion."""
    q = vector(q, 4, "q")
    return q / jnp.sqrt(_checked_norm2(q, "q"))[..., None]


def canonical(q: QuatLike) -> Quat:
    """The representative of ±q with λ0 ≥ 0."""
    q = vector(q, 4, "q")
    return jnp.where(q[..., :1] < 0, -q, q)


def continuous(q: Real[ArrayLike, "*#batch T 4"]) -> Float[Array, "*batch T 4"]:
    """The samples `q (..., T, 4)` of a motion with their signs made continuous along the time
    axis (−2): `q_k ← s_k q_k` with `s_0 = 1` and `s_k = s_{k−1} sign(q_k · q_{k−1})`, so that
    consecutive samples are never more than 90° apart on S³ (the representative a continuous
    solution of `q̇ = ½ q ∘ (0, Ω)` takes, if the body turns by less than 180° between samples)."""
    q = vector(q, 4, "q")
    if q.ndim < 2:
        raise ValueError(f"q must have shape (..., T, 4), samples along axis -2; got {q.shape}")
    dots = jnp.sum(q[..., 1:, :] * q[..., :-1, :], axis=-1)
    flips = jnp.cumprod(jnp.where(dots < 0, -1, 1).astype(q.dtype), axis=-1)
    signs = jnp.concatenate([jnp.ones_like(flips[..., :1]), flips], axis=-1)
    return q * signs[..., None]


def rotate(q: QuatLike, v: Vec3Like) -> Vec3:
    """`P(q) v = v + 2 λ0 λ × v + 2 λ × (λ × v)` for unit `q` (article 003), divided by |q|²."""
    q = vector(q, 4, "q")
    v = vector(v, 3, "v")
    w, u = _split(q)
    s = 2 / _checked_norm2(q, "q")
    t = jnp.cross(jnp.broadcast_to(u, jnp.broadcast_shapes(u.shape, v.shape)), v)
    return v + s[..., None] * (w[..., None] * t + jnp.cross(u, t))


def from_rotvec(theta: Vec3Like) -> Quat:
    """`(cos(θ/2), sin(θ/2) θ/|θ|)`; exact and differentiable at θ = 0."""
    theta = vector(theta, 3, "theta")
    x2 = jnp.sum(theta * theta, axis=-1)
    return _join(_series.half_cos(x2), _series.half_sin_over(x2)[..., None] * theta)


def to_rotvec(q: QuatLike) -> Vec3:
    """Rotation vector with |θ| ≤ π: `θ = 2 atan2(|λ|, λ0) λ/|λ|` after choosing λ0 ≥ 0.

    Near θ = 0 uses `atan(y)/y = 1 − y²/3 + y⁴/5 − …`, so values and gradients stay finite.
    """
    q = canonical(q)
    w, v = _split(q)
    n2 = jnp.sum(v * v, axis=-1)
    small = n2 < jnp.asarray(1e-4, q.dtype) * w * w
    n2_safe = jnp.where(small, jnp.ones_like(n2), n2)
    w_safe = jnp.where(small, w, jnp.ones_like(w))
    y2 = n2 / jnp.where(small, w_safe * w_safe, jnp.ones_like(w))
    series = 2 / w_safe * (1 - y2 / 3 + y2**2 / 5 - y2**3 / 7 + y2**4 / 9)
    n = jnp.sqrt(n2_safe)
    exact = 2 * jnp.arctan2(n, w) / n
    return jnp.where(small, series, exact)[..., None] * v


def to_matrix(q: QuatLike) -> Mat33:
    """`P = E + 2(λ0 λ × E + (λ × E)²)/|q|²`; for unit q this is `2{λλ + (λ0² − ½)E + λ0 λ × E}`
    (Borisov–Mamaev; THEORY §3)."""
    q = vector(q, 4, "q")
    s = 2 / _checked_norm2(q, "q")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1 - s * (yy + zz), s * (xy - wz), s * (xz + wy)],
        [s * (xy + wz), 1 - s * (xx + zz), s * (yz - wx)],
        [s * (xz - wy), s * (yz + wx), 1 - s * (xx + yy)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def from_matrix(P: Mat33Like) -> Quat:
    """Unit quaternion (λ0 ≥ 0) of a rotation matrix by the largest-component method.

    Of the four squared components `4λ0² = 1 + tr P`, `4λi² = 1 + 2Pii − tr P` (THEORY §3), the
    largest (always ≥ 1/4) fixes the row `4λk λ` built from it and the off-diagonal sums and
    differences; normalising that row gives λ with no sign or near-π failure. A slightly
    non-orthogonal input gives the normalised quaternion of this construction.
    """
    P = matrix(P, "P")
    p00, p11, p22 = P[..., 0, 0], P[..., 1, 1], P[..., 2, 2]
    tr = p00 + p11 + p22
    d21, d02, d10 = (
        P[..., 2, 1] - P[..., 1, 2],
        P[..., 0, 2] - P[..., 2, 0],
        P[..., 1, 0] - P[..., 0, 1],
    )
    s01, s02, s12 = (
        P[..., 0, 1] + P[..., 1, 0],
        P[..., 0, 2] + P[..., 2, 0],
        P[..., 1, 2] + P[..., 2, 1],
    )
    t = jnp.stack([1 + tr, 1 + 2 * p00 - tr, 1 + 2 * p11 - tr, 1 + 2 * p22 - tr], axis=-1)
    candidates = jnp.stack(
        [
            jnp.stack([t[..., 0], d21, d02, d10], axis=-1),
            jnp.stack([d21, t[..., 1], s01, s02], axis=-1),
            jnp.stack([d02, s01, t[..., 2], s12], axis=-1),
            jnp.stack([d10, s02, s12, t[..., 3]], axis=-1),
        ],
        axis=-2,
    )
    k = jnp.argmax(t, axis=-1)
    c = jnp.take_along_axis(candidates, k[..., None, None], axis=-2)[..., 0, :]
    # c = 4 λk λ; normalising it directly avoids a square root of a possibly tiny number.
    return canonical(c / jnp.linalg.norm(c, axis=-1, keepdims=True))


def angle(q: QuatLike) -> Scalar:
    """Rotation angle ∈ [0, π] of `q`: `2 atan2(|λ|, |λ0|)`.

    The angle has a kink at the identity; there the gradient is the zero subgradient (finite).
    """
    q = vector(q, 4, "q")
    n2 = jnp.sum(q[..., 1:] ** 2, axis=-1)
    pos = n2 > 0
    n = jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, jnp.ones_like(n2))), jnp.zeros_like(n2))
    return 2 * jnp.arctan2(n, jnp.abs(q[..., 0]))


def random(key: PRNGKeyArray, shape: tuple[int, ...] = (), dtype: DTypeLike | None = None) -> Quat:
    """Uniformly distributed unit quaternions (λ0 ≥ 0): normalised standard Gaussian 4-vectors."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    g = jax.random.normal(key, (*shape, 4), dtype)
    return canonical(g / jnp.linalg.norm(g, axis=-1, keepdims=True))


def inv(q: QuatLike) -> Quat:
    """Inverse `q⁻¹ = conj(q)/|q|²` (equal to `conj(q)` for a unit quaternion)."""
    q = vector(q, 4, "q")
    return conj(q) / _checked_norm2(q, "q")[..., None]


def to_xyzw(q: QuatLike) -> Quat:
    """Scalar-last `(λ1, λ2, λ3, λ0)`: SciPy's `Rotation.as_quat()` / `from_quat` default order."""
    q = vector(q, 4, "q")
    return jnp.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def from_xyzw(q: QuatLike) -> Quat:
    """Scalar-first quaternion from scalar-last `(x, y, z, w)` (SciPy `as_quat()`, jaxlie xyzw)."""
    q = vector(q, 4, "q")
    return jnp.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def slerp(a: QuatLike, b: QuatLike, t: ScalarLike) -> Quat:
    """Shortest-path spherical interpolation `a ∘ exp(t log(a⁻¹ ∘ b))`, as SciPy's `Slerp`.

    `a`, `b` (..., 4) (treated as unit), `t` (...) broadcast against their leading dims. `b` is
    replaced by `−b` when `a·b < 0` (same rotation, shorter arc). For `t > ½` the equal form
    `b ∘ exp((t − 1) log(a⁻¹ ∘ b))` is used, so `t = 0` and `t = 1` return `a/|a|` and `±b/|b|`
    exactly. Built from the Taylor-guarded `to_rotvec`/`from_rotvec`: finite values and gradients
    for `a = ±b`. The path is discontinuous where `a·b` changes sign (a 180° relative
    rotation has two shortest arcs).
    """
    a = normalize(vector(a, 4, "a"))
    b = normalize(vector(b, 4, "b"))
    t = as_float(t, "t")
    b = jnp.where(jnp.sum(a * b, axis=-1, keepdims=True) < 0, -b, b)
    theta = to_rotvec(mul(conj(a), b))
    late = (t > 0.5)[..., None]
    base = jnp.where(late, b, a)
    s = jnp.where(late, t[..., None] - 1, t[..., None])
    return mul(base, from_rotvec(s * theta))


@jax.custom_jvp
def _top_eigvec(M: Float[Array, "*#batch 4 4"]) -> Quat:
    return jnp.linalg.eigh(M)[1][..., :, -1]


@_top_eigvec.defjvp
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

    `q` has shape `(..., N, 4)`: the set of N rotations lies along axis −2 (each treated as
    `q/|q|`, sign-invariant); `weights` `(..., N)`, non-negative, default all 1. Returns
    `(..., 4)`. Gradients are finite unless the largest eigenvalue is degenerate (mean not unique).
    """
    q = vector(q, 4, "q")
    if q.ndim < 2:
        raise ValueError(f"q must have shape (..., N, 4), got {tuple(q.shape)}")
    q = normalize(q)
    w = jnp.ones(q.shape[:-1], q.dtype) if weights is None else as_float(weights, "weights")
    M = jnp.einsum("...n,...ni,...nj->...ij", w, q, q)
    return canonical(_top_eigvec(M))


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
    float64.
    """
    q = normalize(vector(q, 4, "q"))
    l0, l1, l2, l3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    c = jax.lax.complex
    row0 = jnp.stack([c(l0, l3), c(-l2, l1)], axis=-1)
    row1 = jnp.stack([c(l2, l1), c(l0, -l3)], axis=-1)
    return jnp.stack([row0, row1], axis=-2)


def from_cayley_klein(U: CMat22Like) -> Quat:
    """Unit quaternion of a Cayley–Klein matrix (inverse of `to_cayley_klein`, sign kept).

    Averages the redundant entries, `λ0 = Re(α + δ)/2`, `λ1 = Im(β + γ)/2`, `λ2 = Re(γ − β)/2`,
    `λ3 = Im(α − δ)/2` (the orthogonal projection onto such matrices), then normalises.
    """
    U = _c2(U, "U")
    a, b, g, d = U[..., 0, 0], U[..., 0, 1], U[..., 1, 0], U[..., 1, 1]
    q = jnp.stack([jnp.real(a + d), jnp.imag(b + g), jnp.real(g - b), jnp.imag(a - d)], axis=-1)
    return normalize(q / 2)


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


def retract(q: QuatLike, delta: Vec3Like) -> Quat:
    """Move `q` by the body-frame rotation vector `delta`: `q ∘ exp(δ)` (a chart of SO(3) around q;
    a gradient with respect to a rotation lives in this 3-dimensional tangent space)."""
    return mul(q, from_rotvec(delta))


def local(q_ref: QuatLike, q: QuatLike) -> Vec3:
    """Inverse of `retract`: the body-frame rotation vector `δ = log(q_ref⁻¹ ∘ q)`, |δ| ≤ π."""
    q_ref = vector(q_ref, 4, "q_ref")
    return to_rotvec(mul(conj(q_ref) / norm2(q_ref)[..., None], q))
