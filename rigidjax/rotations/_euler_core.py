"""The angle machinery that Euler (`euler`) and generalized Davenport angles (`davenport`) share:
angles → quaternion as a product of half-angle turns (`_compose`, `_mul_components` for basis
axes), rotation → angles by the direct quaternion method of Bernardes & Viollet (2022, the
algorithm of SciPy; `_angles`), the gimbal-lock threshold, and the checked angle argument
(`_angles_arg`). Conventions: `rigidjax.euler`'s docstring.
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Sequence
from typing import Any, TypeAlias

import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, DTypeLike, Float

from .._checks import as_float
from .._custom_types import Quat, RealLike, Scalar, Vec3
from . import _quat_core, _validation


def gimbal_tol(dtype: DTypeLike) -> float:
    """Gimbal-lock threshold on the middle angle (radians, distance to 0/π or ±π/2).

    1e-7 in float64 (SciPy's value); 1e-5 in float32, where rounding of the quaternion alone
    moves an exactly locked middle angle by ~1e-7.
    """
    return 1e-7 if jnp.finfo(dtype).eps < 1e-10 else 1e-5


Axis: TypeAlias = Vec3 | np.ndarray
"""A unit axis: traced or given as an array (Davenport), or a NumPy constant (a basis axis)."""


def _basis(k: int, dtype: DTypeLike) -> np.ndarray:
    """Basis vector `e_k`, a NumPy constant (known when tracing: `_angles` folds it)."""
    return np.eye(3, dtype=np.dtype(dtype))[k]


def _axis_quat(n: Vec3, t: Scalar) -> Quat:
    """Quaternion `(cos(t/2), sin(t/2) n)` of the turn by t about the unit axis n."""
    h = t / 2
    v = jnp.sin(h)[..., None] * n
    c = jnp.broadcast_to(jnp.cos(h)[..., None], v.shape[:-1] + (1,))
    return jnp.concatenate([c, v], axis=-1)


def _compose(angles: Vec3, n1: Vec3, n2: Vec3, n3: Vec3) -> Quat:
    """`Q(α n1) Q(β n2) Q(γ n3)` as a quaternion (intrinsic order of the factors)."""
    q1 = _axis_quat(n1, angles[..., 0])
    q2 = _axis_quat(n2, angles[..., 1])
    q3 = _axis_quat(n3, angles[..., 2])
    return _quat_core.mul(_quat_core.mul(q1, q2), q3)


def _safe_norm(x: Scalar, y: Scalar) -> Scalar:
    """`hypot(x, y)` with gradient 0 (not NaN) at the origin."""
    r2 = x * x + y * y
    pos = r2 > 0
    return lax.select(pos, jnp.sqrt(lax.select(pos, r2, jnp.ones_like(r2))), jnp.zeros_like(r2))


def _wrap(x: Scalar) -> Scalar:
    """Shift an angle in (−3π, 3π) into [−π, π] (SciPy's wrapping)."""
    two_pi = 2 * jnp.pi
    return lax.select(x < -jnp.pi, x + two_pi, lax.select(x > jnp.pi, x - two_pi, x))


_SNAP = 8
"""`sin λ = n3 · (n1 × n2)` within this many ulps of 0 is 0: for n3 = ±n1 (proper Euler axes)
its rounding's sign would flip the middle axis, and the angles out of their range (SciPy's)."""


def _angles(q: Quat, n1: Axis, n2: Axis, n3: Axis, intrinsic: bool) -> Vec3:
    """Bernardes & Viollet (2022) for `q = Q(ψ3 n3) Q(ψ2 n2) Q(ψ1 n1)` (extrinsic order n1, n2, n3,
    unit axes with n2 ⟂ n1, n3). Returns `(ψ1, ψ2, ψ3)`, or `(ψ3, ψ2, ψ1)` if `intrinsic`.

    `λ` is the angle from n1 to n3 about n2; the rotation `Q(λ n2)` turns the problem into a
    proper-Euler one, whose half sum/difference angles are `atan2(b, a)`, `atan2(d, c)`.
    Double-`where` guards keep the gradients finite at gimbal lock. Axes given as NumPy arrays
    (a sequence's basis axes) are folded while tracing (`_fixed_axes`).
    """
    if isinstance(n1, np.ndarray) and isinstance(n2, np.ndarray) and isinstance(n3, np.ndarray):
        lam, flip, (a, b, c, d) = _fixed_axes(q, n1, n2, n3)
    else:
        n12 = jnp.cross(n1, n2)
        sin = jnp.sum(n3 * n12, -1)  # 0 but for rounding where n3 = ±n1 (snapped: see below)
        sin = jnp.where(jnp.abs(sin) <= _SNAP * jnp.finfo(sin.dtype).eps, 0.0, sin)
        lam = jnp.arctan2(sin, jnp.sum(n3 * n1, -1))
        flip = lam < 0
        n2 = jnp.where(flip[..., None], -n2, n2)
        n12 = jnp.where(flip[..., None], -n12, n12)
        lam = jnp.abs(lam)
        qt = _quat_core.mul(_axis_quat(n2, lam), q)
        v = qt[..., 1:]
        a = qt[..., 0]
        b = jnp.sum(v * n1, -1)
        c = jnp.sum(v * n2, -1)
        d = jnp.sum(v * n12, -1)

    mid = 2 * jnp.arctan2(_safe_norm(c, d), _safe_norm(a, b))
    tol = gimbal_tol(q.dtype)
    lock0 = mid <= tol
    lockpi = mid >= jnp.pi - tol
    lock = lock0 | lockpi
    zero, one = jnp.zeros_like(a), jnp.ones_like(a)
    half_sum = jnp.arctan2(lax.select(lockpi, zero, b), lax.select(lockpi, one, a))
    half_diff = jnp.arctan2(lax.select(lock0, zero, d), lax.select(lock0, one, c))
    if intrinsic:  # output order (ψ3, ψ2, ψ1): the output's third angle ψ1 is set to 0
        single = lax.select(lock0, 2 * half_sum, 2 * half_diff)
        first = lax.select(lock, zero, half_sum - half_diff)
        third = lax.select(lock, single, half_sum + half_diff)
    else:
        single = lax.select(lock0, 2 * half_sum, -2 * half_diff)
        first = lax.select(lock, single, half_sum - half_diff)
        third = lax.select(lock, zero, half_sum + half_diff)
    mid = mid - lam
    if isinstance(flip, bool):  # axes known when tracing
        mid = -mid if flip else mid
    else:
        mid = lax.select(flip, -mid, mid)
    out = (third, mid, first) if intrinsic else (first, mid, third)
    return jnp.stack([_wrap(x) for x in out], axis=-1)


def _fixed_axes(q: Quat, n1: np.ndarray, n2: np.ndarray, n3: np.ndarray) -> tuple:
    """`_angles`' λ, its sign and `(a, b, c, d)` for axes known when tracing: λ, the turn
    `Q(λ n2)` and the projections computed in NumPy, so that only the products with q's
    components are traced (a basis axis picks a component: no cross products or sums)."""
    n12 = np.cross(n1, n2)
    sin = float(n3 @ n12)
    eps = np.finfo(np.result_type(n3.dtype, np.float16)).eps  # (basis axes: exact)
    lam = float(np.arctan2(0.0 if abs(sin) <= _SNAP * eps else sin, n3 @ n1))
    flip = lam < 0
    n2, n12, lam = (-n2, -n12, -lam) if flip else (n2, n12, lam)
    qs: list[Array | None] = list(jnp.unstack(q, axis=-1))
    if lam != 0:  # proper Euler angles: λ = 0, the turn is the identity
        turn = [np.cos(lam / 2), *(np.sin(lam / 2) * n2)]
        qs = _mul_components([float(x) if x else None for x in turn], qs)

    def dot(n: np.ndarray) -> Array:  # Σ n_i v_i over n_i ≠ 0, v = qt[1:]
        terms = [(x if n[i] == 1 else -x if n[i] == -1 else float(n[i]) * x)
                 for i, x in enumerate(qs[1:]) if n[i] and x is not None]  # fmt: skip
        return functools.reduce(operator.add, terms)

    assert qs[0] is not None
    return lam, flip, (qs[0], dot(n1), dot(n2), dot(n12))


# Hamilton product (a ∘ b)_r = Σ sign a_i b_j over the (sign, i, j) of row r
_HAMILTON = (
    ((1, 0, 0), (-1, 1, 1), (-1, 2, 2), (-1, 3, 3)),
    ((1, 0, 1), (1, 1, 0), (1, 2, 3), (-1, 3, 2)),
    ((1, 0, 2), (-1, 1, 3), (1, 2, 0), (1, 3, 1)),
    ((1, 0, 3), (1, 1, 2), (-1, 2, 1), (1, 3, 0)),
)


def _mul_components(
    a: Sequence[Array | float | None], b: Sequence[Array | float | None]
) -> list[Any]:
    """Hamilton product of quaternions given as four components (arrays, or Python numbers
    for constants), `None` for an exact zero (the zero terms of basis-axis factors are skipped,
    not multiplied)."""
    out: list[Any] = []
    for row in _HAMILTON:
        acc = None
        for sign, i, j in row:
            ai, bj = a[i], b[j]
            if ai is None or bj is None:
                continue
            t = ai * bj
            acc = (t if sign > 0 else -t) if acc is None else (acc + t if sign > 0 else acc - t)
        out.append(acc)
    return out


def _angles_arg(
    angles: RealLike,
    n: int = 3,
    degrees: bool = False,
    name: str = "angles",
    seq: str | None = None,
) -> Float[Array, "*batch k"]:
    """Angles `(..., n)` (a scalar for n = 1), checked to be finite, in radians; a wrong last
    dimension is SciPy's ValueError (naming `seq`, if given)."""
    a = as_float(angles, name)
    if n == 1 and a.ndim == 0:
        a = a[None]
    if a.ndim == 0 or a.shape[-1] != n:
        got = a.shape[-1] if a.ndim else "a scalar"
        raise ValueError(
            f"{name} must have shape (..., {n}), got {tuple(a.shape)}"
            if seq is None
            else "Expected last dimension of `angles` to match number of sequence axes specified, "
            f"got {got}. ({name} must have shape (..., {n}) for seq={seq!r})"
        )
    a = _validation.check_finite(a, name, 1)
    return jnp.deg2rad(a) if degrees else a
