"""The free symmetric top (regular precession) and rotation about a fixed axis, in closed form.

Sources: Landau & Lifshitz, *Mechanics* §33, §35; THEORY §6. Conventions as in
`rigidjax.analytic.euler_poinsot`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import as_float, check_finite, floats, validate, vector, zero_vector
from .._custom_types import (
    Quat,
    QuatLike,
    RealLike,
    RealScalarLike,
    Scalar,
    ScalarLike,
    TimesLike,
    Vec3,
    Vec3Like,
)
from .._numerics import safe_sqrt
from ..rotations import quat
from .euler_poinsot import check_moments

# ----------------------------------------------------------------------------------------------
# Free symmetric top (Zegrya–Parshin 004 (12.7)–(12.8), (12.34)–(12.39); THEORY §6)
# ----------------------------------------------------------------------------------------------


__all__ = [
    "SymmetricTopPrecession",
    "fixed_axis_rotation",
    "symmetric_top",
    "symmetric_top_attitude",
    "symmetric_top_precession",
]


class SymmetricTopPrecession(NamedTuple):
    """Regular precession of a free symmetric top (see `symmetric_top_precession`)."""

    precession_rate: Scalar  # |M|/I1: rate of the symmetry axis (and of P) about the fixed M
    spin: Scalar  # Ω3, constant component of Ω along the symmetry axis, = (|M|/I3) cos θ
    body_rate: Scalar  # ω = Ω3 (I3 − I1)/I1: rate of (Ω1, Ω2) about the symmetry axis in the body
    nutation: Scalar  # θ ∈ [0, π]: constant angle between the symmetry axis and M


def _top_inputs(
    I1: ScalarLike, I3: ScalarLike, omega0: Vec3Like, *more: RealLike, check: bool = True
) -> list[Float[Array, "..."]]:
    """The arguments as floats of one dtype, checked: the moments `(I1, I1, I3)` by
    `check_moments` (finite, positive, and `I3 ≤ 2 I1` unless `check=False`), `omega0` and `ts`
    finite."""
    names = ("I1", "I3", "omega0", "ts")[: 3 + len(more)]
    out = floats(*zip((I1, I3, omega0, *more), names, strict=True))
    vector(out[2], 3, "omega0")
    I1, I3 = jnp.broadcast_arrays(out[0], out[1])
    moments = check_moments(jnp.stack([I1, I1, I3], axis=-1), "(I1, I1, I3)", check)
    out[0], out[1] = moments[..., 0], moments[..., 2]
    return out[:2] + [check_finite(x, n) for x, n in zip(out[2:], names[2:], strict=True)]


def symmetric_top_precession(
    I1: ScalarLike, I3: ScalarLike, omega0: Vec3Like, *, check: bool = True
) -> SymmetricTopPrecession:
    """Regular precession of the free symmetric top `I1 = I2 ≠ I3` (symmetry axis = body z):
    precession rate `|M|/I1`, spin `Ω3 = (|M|/I3) cos θ`, body rate `ω = Ω3 (I3 − I1)/I1` and the
    nutation angle θ between the symmetry axis and M, `tan θ = I1 |Ω⊥| / (I3 Ω3)` (Zegrya–Parshin
    004 (12.34)–(12.39)). Batch dims of the arguments broadcast; bad moments (NaN, ≤ 0, or
    `I3 > 2 I1`, the triangle inequality, unless `check=False`) or a non-finite `omega0` are an
    error naming the argument."""
    return _precession(*_top_inputs(I1, I3, omega0, check=check))


@jax.jit
def _precession(I1: Array, I3: Array, omega0: Array) -> SymmetricTopPrecession:
    perp = safe_sqrt(omega0[..., 0] ** 2 + omega0[..., 1] ** 2)
    w3 = omega0[..., 2]
    M = safe_sqrt(I1**2 * (omega0[..., 0] ** 2 + omega0[..., 1] ** 2) + I3**2 * w3**2)
    return SymmetricTopPrecession(
        precession_rate=M / I1,
        spin=w3,
        body_rate=w3 * (I3 - I1) / I1,
        nutation=jnp.arctan2(I1 * perp, I3 * w3),
    )


def symmetric_top(
    I1: ScalarLike,
    I3: ScalarLike,
    omega0: Vec3Like,
    ts: TimesLike,
    t0: RealScalarLike = 0.0,
    *,
    check: bool = True,
) -> Float[Array, "*#batch T 3"] | Vec3:
    """Body angular velocity `(..., T, 3)` of the free symmetric top `I1 = I2`, `I3` (symmetry
    axis = body z): `Ω3 = const`, `Ω1 + iΩ2 = (Ω1(t0) + iΩ2(t0)) e^{iω(t − t0)}`,
    `ω = Ω3 (I3 − I1)/I1` (from `I1 Ω̇1 = (I1 − I3) Ω2 Ω3`, `I1 Ω̇2 = (I3 − I1) Ω3 Ω1`; the sign
    agrees with `simulate`). `ts` (T,). Checked as `symmetric_top_precession`; `ts`, `t0` finite."""
    I1, I3, omega0, ts = _top_inputs(I1, I3, omega0, ts, check=check)
    return _top(I1, I3, omega0, ts, check_finite(as_float(t0, "t0").astype(ts.dtype), "t0"))


@jax.jit
def _top(I1: Array, I3: Array, omega0: Array, ts: Array, t0: Array) -> Array:
    t = jnp.atleast_1d(ts) - t0
    om = (omega0[..., 2] * (I3 - I1) / I1)[..., None] * t  # (..., T)
    c, s = jnp.cos(om), jnp.sin(om)
    w1, w2, w3 = (omega0[..., i : i + 1] for i in range(3))
    out = jnp.stack([w1 * c - w2 * s, w1 * s + w2 * c, jnp.broadcast_to(w3, c.shape)], axis=-1)
    return out[..., 0, :] if ts.ndim == 0 else out


def symmetric_top_attitude(
    I1: ScalarLike,
    I3: ScalarLike,
    omega0: Vec3Like,
    q0: QuatLike | None,
    ts: TimesLike,
    t0: RealScalarLike = 0.0,
    *,
    check: bool = True,
) -> Float[Array, "*#batch T 4"] | Quat:
    """Attitude `(..., T, 4)` of the free symmetric top (symmetry axis = body z): regular
    precession about the fixed angular momentum,
        `P(t) = R(M̂, (|M|/I1)(t − t0)) P0 R(e_z, −ω(t − t0))`,
    i.e. `q(t) = q(M_space (t − t0)/I1) ∘ q0 ∘ q(−ω (t − t0) e_z)` with `M_space = P0 I Ω0`.
    Check: the body angular velocity of this P is `(|M|/I1) n(t) − ω e_z` with `n = IΩ/|M|`
    rotating about e_z at the rate ω, which equals Ω(t) (`symmetric_top`). λ0 ≥ 0. Checked as
    `symmetric_top` (`check`); `q0` finite and non-zero."""
    I1, I3, omega0, ts = _top_inputs(I1, I3, omega0, ts, check=check)
    dtype = ts.dtype
    q0 = quat.identity(dtype=dtype) if q0 is None else vector(q0, 4, "q0").astype(dtype)
    t0 = check_finite(as_float(t0, "t0").astype(dtype), "t0")
    return _top_attitude(I1, I3, omega0, quat.normalize(q0), ts, t0)


@jax.jit
def _top_attitude(I1: Array, I3: Array, omega0: Array, q0: Array, ts: Array, t0: Array) -> Array:
    dtype = ts.dtype
    t = (jnp.atleast_1d(ts) - t0)[:, None]
    Ivec = jnp.stack(jnp.broadcast_arrays(I1, I1, I3), axis=-1)
    Ms = quat.rotate(q0, Ivec * omega0)
    om = omega0[..., 2] * (I3 - I1) / I1
    ez = jnp.asarray((0.0, 0.0, 1.0), dtype)
    qs = quat.from_rotvec((Ms / I1[..., None])[..., None, :] * t)
    qb = quat.from_rotvec(-(om[..., None, None] * t) * ez)
    out = quat.canonical(quat.mul(quat.mul(qs, q0[..., None, :]), qb))
    return out[..., 0, :] if ts.ndim == 0 else out


def fixed_axis_rotation(
    axis: Vec3Like,
    angle: ScalarLike | Callable[[Array], Array],
    ts: TimesLike,
    q0: QuatLike | None = None,
) -> Float[Array, "*#batch T 4"]:
    """Rotation about a space-fixed axis (Zhilin 3.13): `ω = θ̇(t) n`, `P(t) = exp(θ(t) n × E) P0`
    with `θ(t) = ∫₀ᵗ ω`. `angle`: a callable `θ(t)` (vectorised over `ts`, θ(0) = 0 expected) or a
    constant rate ω (then θ = ω t). `axis` `(..., 3)` is normalised. Returns quaternions
    `(..., T, 4)`, λ0 ≥ 0; the body angular velocity is `Ω = θ̇ P(t)ᵀ n`."""
    axis = validate(
        check_finite(vector(axis, 3, "axis"), "axis"),
        zero_vector,
        "axis must be non-zero (the direction of the fixed axis)",
    )
    ts = jnp.atleast_1d(as_float(ts, "ts"))
    dtype = jnp.result_type(axis, ts)
    axis, ts = axis.astype(dtype), ts.astype(dtype)
    n = axis / jnp.sqrt(jnp.sum(axis * axis, axis=-1, keepdims=True))
    if callable(angle):
        theta = jnp.asarray(angle(ts), dtype)
    else:
        theta = as_float(angle, "angle").astype(dtype)[..., None] * ts
    q0 = quat.identity(dtype=dtype) if q0 is None else quat.normalize(vector(q0, 4, "q0"))
    q = quat.from_rotvec(theta[..., None] * n[..., None, :])
    return quat.canonical(quat.mul(q, q0[..., None, :]))
