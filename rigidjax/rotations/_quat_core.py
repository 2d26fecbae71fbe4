"""The quaternion primitives behind `rigidjax.quat`: the algebra (`mul`, `conj`, `rotate`, …), the
rotation-vector and matrix maps with their checks and derivatives, and the private helpers
(`_unit`, `_from_rotvec`, `_to_rotvec`, `_quat_of_matrix`, …) that the other parametrisations and
`quat`'s companion modules (`align`, `average`, `cayley_klein`, `groups`, `interop`, `powers`)
build on. Imports nothing of `rotations` but its validation, series and compilation helpers, so
every module of the package can import it without a circle; `quat` assembles the public names.
Conventions and the checks' contract: `rigidjax.quat`'s docstring.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, DTypeLike, Float, PRNGKeyArray, Real

from .._checks import as_float, broadcast_batch, concrete_value, is_concrete, matrix, vector
from .._custom_types import (
    Mat33,
    Mat33Like,
    Quat,
    QuatLike,
    Scalar,
    ScalarLike,
    Vec3,
    Vec3Like,
)
from .._numerics import cofactors
from . import _series
from . import _validation as _v
from ._compiled import compiled


def _split(q: Quat) -> tuple[Scalar, Vec3]:
    return q[..., 0], q[..., 1:]


def _join(w: Scalar, v: Vec3) -> Quat:
    w, v = jnp.broadcast_arrays(w[..., None], v)
    return jnp.concatenate([w[..., :1], v], axis=-1)


def _unit(q: Quat, name: str) -> Quat:
    """`q/|q|` of a checked quaternion `q` (see `_v.check_quat`)."""
    return q / jnp.sqrt(_v.check_quat(q, name, norm2(q)))[..., None]


def identity(shape: tuple[int, ...] = (), dtype: DTypeLike | None = None) -> Quat:
    """The identity rotation `(1, 0, 0, 0)` with leading shape `shape` (a constant: nothing to
    compile)."""
    q = np.zeros((*shape, 4), jnp.result_type(float) if dtype is None else dtype)
    q[..., 0] = 1
    return jnp.asarray(q)


def mul(a: QuatLike, b: QuatLike) -> Quat:
    """Hamilton product `a ∘ b`: `λ0 = μ0ν0 − μ·ν`, `λ = μ0 ν + ν0 μ + μ × ν`
    (article 003 (68)–(69)).

    `to_matrix(mul(a, b)) = to_matrix(a) @ to_matrix(b)`.
    """
    a = vector(a, 4, "a")
    b = vector(b, 4, "b")
    broadcast_batch(a=a.shape[:-1], b=b.shape[:-1])
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
    """`|q|²`, with the one check of the algebra: `q` finite and non-zero."""
    return _v.check_quat(q, name, norm2(q))


def normalize(q: QuatLike) -> Quat:
    """`q / |q|`; raises a clear error for a zero or non-finite quaternion."""
    q = vector(q, 4, "q")
    return _unit(q, "q")


def canonical(q: QuatLike) -> Quat:
    """The representative of ±q that SciPy's `as_quat(canonical=True)` returns: λ0 > 0, or, for
    a 180° rotation (λ0 = 0), the first non-zero of λ1, λ2, λ3 positive."""
    q = vector(q, 4, "q")
    w, x, y, z = jnp.unstack(q, axis=-1)
    flip = (w < 0) | ((w == 0) & ((x < 0) | ((x == 0) & ((y < 0) | ((y == 0) & (z < 0))))))
    return jnp.where(flip[..., None], -q, q)


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
    broadcast_batch(q=q.shape[:-1], v=v.shape[:-1])
    w, u = _split(q)
    s = 2 / _checked_norm2(q, "q")
    t = jnp.cross(jnp.broadcast_to(u, jnp.broadcast_shapes(u.shape, v.shape)), v)
    return v + s[..., None] * (w[..., None] * t + jnp.cross(u, t))


def _from_rotvec(theta: Vec3) -> Quat:
    x2 = jnp.sum(theta * theta, axis=-1)
    return _join(_series.half_cos(x2), _series.half_sin_over(x2)[..., None] * theta)


def from_rotvec(theta: Vec3Like, degrees: bool = False) -> Quat:
    """`(cos(θ/2), sin(θ/2) θ/|θ|)`; exact and differentiable at θ = 0. `theta` must be finite;
    `degrees=True` reads it in degrees (as SciPy's `Rotation.from_rotvec`)."""
    theta = _v.check_finite(vector(theta, 3, "theta"), "theta", 1)
    return _from_rotvec(jnp.deg2rad(theta) if degrees else theta)


def _to_rotvec(q: Quat) -> Vec3:
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


def to_rotvec(q: QuatLike, degrees: bool = False) -> Vec3:
    """Rotation vector with |θ| ≤ π: `θ = 2 atan2(|λ|, λ0) λ/|λ|` of `canonical(q)` (at θ = π
    the first non-zero component of θ is positive). `q` must be finite and non-zero;
    `degrees=True` returns degrees (as SciPy's `Rotation.as_rotvec`).

    Near θ = 0 uses `atan(y)/y = 1 − y²/3 + y⁴/5 − …`, so values and gradients stay finite.
    """
    theta = _to_rotvec(_v.check_quat(vector(q, 4, "q"), "q"))
    return jnp.rad2deg(theta) if degrees else theta


def _to_matrix(q: Quat, n2: Scalar) -> Mat33:
    """`to_matrix` of a quaternion with `|q|² = n2`."""
    s = 2 / n2
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


def to_matrix(q: QuatLike) -> Mat33:
    """`P = E + 2(λ0 λ × E + (λ × E)²)/|q|²`; for unit q this is `2{λλ + (λ0² − ½)E + λ0 λ × E}`
    (Borisov–Mamaev; THEORY §3). `q` must be finite and non-zero. One compiled program per
    shape and dtype, its check made in NumPy when the value of `q` is known."""
    q = vector(q, 4, "q")
    checked = concrete_value(q) is not None
    if checked:
        _v.check_quat(q, "q")
    return _to_matrix_compiled(q, checked=checked)


@compiled(1)
def _to_matrix_compiled(q: Quat, checked: bool) -> Mat33:
    """`to_matrix` of `q`, checked at run time unless `checked` already."""
    return _to_matrix(q, norm2(q) if checked else _checked_norm2(q, "q"))


def _from_orthogonal(P: Mat33) -> Quat:
    """The largest-component construction of `from_matrix` (no checks)."""
    # the nine entries in one `unstack` (an index each would be a slice and a squeeze: twice
    # the program to trace and differentiate)
    (p00, p01, p02, p10, p11, p12, p20, p21, p22) = jnp.unstack(
        P.reshape(*P.shape[:-2], 9), axis=-1
    )
    tr = p00 + p11 + p22
    d21, d02, d10 = p21 - p12, p02 - p20, p10 - p01
    s01, s02, s12 = p01 + p10, p02 + p20, p12 + p21
    t = [1 + tr, 1 + 2 * p00 - tr, 1 + 2 * p11 - tr, 1 + 2 * p22 - tr]
    candidates = [
        jnp.stack([t[0], d21, d02, d10], axis=-1),
        jnp.stack([d21, t[1], s01, s02], axis=-1),
        jnp.stack([d02, s01, t[2], s12], axis=-1),
        jnp.stack([d10, s02, s12, t[3]], axis=-1),
    ]
    k = jnp.argmax(jnp.stack(t, axis=-1), axis=-1)[..., None]
    # the row of the largest t_k, chosen by `where` (a gather compiles, and differentiates,
    # several times slower)
    c = candidates[3]
    for i in (2, 1, 0):
        c = jnp.where(k == i, candidates[i], c)
    # c = 4 λk λ; normalising it directly avoids a square root of a possibly tiny number.
    return canonical(c / jnp.linalg.norm(c, axis=-1, keepdims=True))


def _polar(P: Mat33) -> Mat33:
    """Orthogonal polar factor `U Vᵀ` of `P = U S Vᵀ` (det P > 0): Newton's iteration
    `X ← (γX + (γX)⁻ᵀ)/2` with determinant scaling `γ = |det X|^(−1/3)` (Higham 1986), to rounding
    in 8 steps for condition numbers up to ~1e4 (1e-11 at 1e8). `X⁻ᵀ = cof X / det X`, where the
    rows of the cofactor matrix are cross products of the rows of X."""
    return jax.lax.fori_loop(0, 8, _polar_step, P)


def _polar_value(P: Mat33) -> Mat33:
    """`_polar(P)`'s value, its iteration stopped once a step moves no entry by more than 8 eps
    (the entries of the limit are at most 1; at most 8 steps, as `_polar`): measured, a
    rotation to rounding takes 1 step, one perturbed by 1e-9 2, by 1e-6 3, by 0.1 5. Not
    differentiable (a `while_loop`): derivatives are `_polar`'s."""

    def moving(c: tuple) -> Array:
        return (c[0] < 8) & c[2]

    def step(c: tuple) -> tuple:
        k, X, _ = c
        Y = _polar_step(k, X)
        return k + 1, Y, jnp.any(jnp.abs(Y - X) > 8 * jnp.finfo(X.dtype).eps)

    return jax.lax.while_loop(moving, step, (0, P, jnp.array(True)))[1]


def _polar_step(_: Any, X: Mat33) -> Mat33:
    C, det = cofactors(X)
    d = det[..., None, None]
    g = jnp.cbrt(jnp.abs(d))
    return 0.5 * (X / g + C * (g / d))


def _is_orthogonal(xp: Any, P: Any) -> Any:
    """`|P Pᵀ − E| ≤ 100 eps` entrywise (a rotation to rounding); `xp` is NumPy or jax.numpy."""
    G = P @ xp.swapaxes(P, -1, -2) - xp.eye(3, dtype=P.dtype)
    return xp.all(xp.abs(G) <= 100 * xp.finfo(P.dtype).eps, axis=(-2, -1))


@jax.custom_jvp
def _orthogonalised(P: Mat33) -> Mat33:
    """`P` itself if it is orthogonal to rounding, else its polar factor (as SciPy's
    `Rotation.from_matrix`, which takes the SVD `U Vᵀ`). The derivative is always that of the
    polar factor (at a rotation: the projection of `dP` on the tangent space), consistent with the
    value off SO(3)."""
    orthogonal = _is_orthogonal(jnp, jax.lax.stop_gradient(P))[..., None, None]
    return jnp.where(orthogonal, P, _polar_value(jax.lax.stop_gradient(P)))


@_orthogonalised.defjvp
def _orthogonalised_jvp(primals, tangents):
    (P,), (dP,) = primals, tangents
    _, dX = jax.jvp(_polar, (P,), (dP,))
    return _orthogonalised(P), dX


@jax.custom_jvp
def _quat_of_rotation(P: Mat33) -> Quat:
    """`_from_orthogonal` of matrices known to be orthogonal to rounding, with the derivative of
    the quaternion on SO(3): for the projection `P Ω×` of `dP` on the tangent space (that of the
    polar factor at a rotation, `Ω× = skew(Pᵀ dP)`), `dq = ½ q ∘ (0, Ω)` (the body-frame
    kinematics, Borisov–Mamaev 001), without tracing the construction's derivative."""
    return _from_orthogonal(P)


@_quat_of_rotation.defjvp
def _quat_of_rotation_jvp(primals, tangents):
    (P,), (dP,) = primals, tangents
    q = _quat_of_rotation(P)
    A = jnp.swapaxes(P, -1, -2) @ dP
    a = jnp.unstack(A.reshape(*A.shape[:-2], 9), axis=-1)
    half_omega = 0.25 * jnp.stack([a[7] - a[5], a[2] - a[6], a[3] - a[1]], axis=-1)
    return q, mul(q, jnp.concatenate([jnp.zeros_like(half_omega[..., :1]), half_omega], -1))


def _matrix_mode(P: Mat33, name: str) -> str:
    """How `_quat_of_matrix` takes `P`: with its value known now (`concrete_value`), checked here
    in NumPy (errors naming `name`) and `"rotation"` if every matrix is orthogonal to rounding
    (and `P` is concrete or a first-order derivative's tracer), else `"orthogonalise"`;
    `"traced"` (under jit/vmap) checked at run time."""
    Pn = concrete_value(P)
    if Pn is None:
        return "traced"
    _v.check_matrix(P, name)
    # `_quat_of_rotation`'s tangent holds the first derivative only: higher derivatives
    # (the tracer of a tracer, e.g. `jax.hessian`) go through the Newton iteration
    first_order = is_concrete(getattr(P, "primal", P))
    return "rotation" if first_order and np.all(_is_orthogonal(np, Pn)) else "orthogonalise"


def _quat_of_matrix(P: Mat33, name: str, mode: str) -> Quat:
    """`from_matrix` of `P` taken as `_matrix_mode` says: checked (errors naming `name`) and
    orthogonalised. Called inside the jitted cores of the public maps."""
    if mode == "assume_valid":
        return _from_orthogonal(P)
    if mode == "rotation":
        return _quat_of_rotation(P)
    if mode == "traced":
        P = _v.check_matrix(P, name)
    return _from_orthogonal(_orthogonalised(P))


_quat_of_matrix_jit = compiled(2)(_quat_of_matrix)


def _from_matrix(P: Mat33, name: str) -> Quat:
    """`from_matrix` of `P`, checked (errors naming `name`) and orthogonalised, compiled."""
    return _quat_of_matrix_jit(P, name=name, mode=_matrix_mode(P, name))


def from_matrix(P: Mat33Like, *, assume_valid: bool = False) -> Quat:
    """Unit quaternion (`canonical`: λ0 ≥ 0, SciPy's sign at λ0 = 0) of a rotation matrix by the
    largest-component method.

    Of the four squared components `4λ0² = 1 + tr P`, `4λi² = 1 + 2Pii − tr P` (THEORY §3), the
    largest (always ≥ 1/4) fixes the row `4λk λ` built from it and the off-diagonal sums and
    differences; normalising that row gives λ with no sign or near-π failure.

    As SciPy's `Rotation.from_matrix`: a non-finite `P` or one with det P ≤ 0 (a reflection or a
    degenerate frame) is an error; a matrix with det > 0 that is not orthogonal to rounding (an
    integrator's output) is replaced by its nearest rotation, the polar factor `U Vᵀ` of its SVD
    (computed by a Newton iteration, with finite derivatives). `assume_valid=True` (as in SciPy)
    skips both for matrices known to be rotations (e.g. inside an integrator's vector field).
    One compiled program per shape and dtype (also under `jacfwd`/`jacrev`), its checks made in
    NumPy when the value of `P` is known.
    """
    P = matrix(P, "P")
    mode = "assume_valid" if assume_valid else _matrix_mode(P, "P")
    return _quat_of_matrix_jit(P, name="P", mode=mode)


def angle(q: QuatLike) -> Scalar:
    """Rotation angle ∈ [0, π] of `q`: `2 atan2(|λ|, |λ0|)`.

    The angle has a kink at the identity; there the gradient is the zero subgradient (finite).
    `q` must be finite and non-zero.
    """
    return _angle(_v.check_quat(vector(q, 4, "q"), "q"))


def _angle(q: Quat) -> Scalar:
    n2 = jnp.sum(q[..., 1:] ** 2, axis=-1)
    pos = n2 > 0
    n = jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, jnp.ones_like(n2))), jnp.zeros_like(n2))
    return 2 * jnp.arctan2(n, jnp.abs(q[..., 0]))


def random(
    key: PRNGKeyArray, shape: int | tuple[int, ...] = (), dtype: DTypeLike | None = None
) -> Quat:
    """Uniformly distributed unit quaternions (λ0 ≥ 0): normalised standard Gaussian 4-vectors;
    `shape` the batch's (an int `n`: `(n,)`, as SciPy's `Rotation.random(n)`)."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
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
    rotation has two shortest arcs). `a`, `b` must be finite and non-zero, `t` finite.
    """
    a = _unit(vector(a, 4, "a"), "a")
    b = _unit(vector(b, 4, "b"), "b")
    t = _v.check_finite(as_float(t, "t"), "t", 0)
    broadcast_batch(a=a.shape[:-1], b=b.shape[:-1], t=t.shape)
    b = jnp.where(jnp.sum(a * b, axis=-1, keepdims=True) < 0, -b, b)
    theta = _to_rotvec(mul(conj(a), b))
    late = (t > 0.5)[..., None]
    base = jnp.where(late, b, a)
    s = jnp.where(late, t[..., None] - 1, t[..., None])
    return mul(base, _from_rotvec(s * theta))


def retract(q: QuatLike, delta: Vec3Like) -> Quat:
    """Move `q` by the body-frame rotation vector `delta`: `q ∘ exp(δ)` (a chart of SO(3) around q;
    a gradient with respect to a rotation lives in this 3-dimensional tangent space)."""
    return mul(q, _from_rotvec(vector(delta, 3, "delta")))


def local(q_ref: QuatLike, q: QuatLike) -> Vec3:
    """Inverse of `retract`: the body-frame rotation vector `δ = log(q_ref⁻¹ ∘ q)`, |δ| ≤ π."""
    q_ref = vector(q_ref, 4, "q_ref")
    return _to_rotvec(mul(conj(q_ref) / norm2(q_ref)[..., None], q))
