"""Rodrigues–Hamilton parameters (unit quaternions), scalar-first `(λ0, λ1, λ2, λ3)`.

Conventions (THEORY.md §3): Hamilton product, `λ0 = cos(θ/2)`, `λ = sin(θ/2) m`; `q` and `−q` are
the same rotation. Functions that map a quaternion to a rotation accept any non-zero `q` and treat
it as `q/|q|` (like SciPy); `normalize` raises on a zero quaternion.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from . import _series
from ._util import matrix, vector

Quat = Float[Array, "*batch 4"]
Vec = Float[Array, "*batch 3"]
Mat = Float[Array, "*batch 3 3"]


def _split(q: Array) -> tuple[Array, Array]:
    return q[..., 0], q[..., 1:]


def _join(w: Array, v: Array) -> Array:
    w, v = jnp.broadcast_arrays(w[..., None], v)
    return jnp.concatenate([w[..., :1], v], axis=-1)


def identity(shape: tuple[int, ...] = (), dtype=None) -> Quat:
    """The identity rotation `(1, 0, 0, 0)` with leading shape `shape`."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    return jnp.zeros((*shape, 4), dtype).at[..., 0].set(1)


def mul(a: ArrayLike, b: ArrayLike) -> Quat:
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


def conj(q: ArrayLike) -> Quat:
    """Conjugate `(λ0, −λ)`: the inverse rotation for a unit quaternion."""
    q = vector(q, 4, "q")
    return q * jnp.array([1, -1, -1, -1], q.dtype)


def norm2(q: Quat) -> Array:
    return jnp.sum(q * q, axis=-1)


def _checked_norm2(q: Quat, name: str) -> Array:
    n2 = norm2(q)
    return eqx.error_if(
        n2,
        ~(n2 > 0),
        f"{name} is a zero (or non-finite) quaternion; a rotation needs |{name}| > 0",
    )


def normalize(q: ArrayLike) -> Quat:
    """`q / |q|`; raises a clear error for a zero or non-finite quaternion."""
    q = vector(q, 4, "q")
    return q / jnp.sqrt(_checked_norm2(q, "q"))[..., None]


def canonical(q: ArrayLike) -> Quat:
    """The representative of ±q with λ0 ≥ 0."""
    q = vector(q, 4, "q")
    return jnp.where(q[..., :1] < 0, -q, q)


def rotate(q: ArrayLike, v: ArrayLike) -> Vec:
    """`P(q) v = v + 2 λ0 λ × v + 2 λ × (λ × v)` for unit `q` (article 003), divided by |q|²."""
    q = vector(q, 4, "q")
    v = vector(v, 3, "v")
    w, u = _split(q)
    s = 2 / _checked_norm2(q, "q")
    t = jnp.cross(jnp.broadcast_to(u, jnp.broadcast_shapes(u.shape, v.shape)), v)
    return v + s[..., None] * (w[..., None] * t + jnp.cross(u, t))


def from_rotvec(theta: ArrayLike) -> Quat:
    """`(cos(θ/2), sin(θ/2) θ/|θ|)`; exact and differentiable at θ = 0."""
    theta = vector(theta, 3, "theta")
    x2 = jnp.sum(theta * theta, axis=-1)
    return _join(_series.half_cos(x2), _series.half_sin_over(x2)[..., None] * theta)


def to_rotvec(q: ArrayLike) -> Vec:
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


def to_matrix(q: ArrayLike) -> Mat:
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


def from_matrix(P: ArrayLike) -> Quat:
    """Unit quaternion (λ0 ≥ 0) of a rotation matrix by the largest-component method.

    Of the four squared components `4λ0² = 1 + tr P`, `4λi² = 1 + 2Pii − tr P` (THEORY §3), the
    largest (always ≥ 1/4) fixes the row `4λk λ` built from it and the off-diagonal sums and
    differences; normalising that row gives λ with no sign or near-π failure. A slightly non-orthogonal input gives the
    normalised nearest quaternion of this construction.
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


def angle(q: ArrayLike) -> Array:
    """Rotation angle ∈ [0, π] of `q`: `2 atan2(|λ|, |λ0|)`."""
    q = vector(q, 4, "q")
    return 2 * jnp.arctan2(jnp.linalg.norm(q[..., 1:], axis=-1), jnp.abs(q[..., 0]))


def random(key: PRNGKeyArray, shape: tuple[int, ...] = (), dtype=None) -> Quat:
    """Uniformly distributed unit quaternions (λ0 ≥ 0): normalised standard Gaussian 4-vectors."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    g = jax.random.normal(key, (*shape, 4), dtype)
    return canonical(g / jnp.linalg.norm(g, axis=-1, keepdims=True))
