"""The free rigid body in closed form (Euler–Poinsot): body angular velocity by Jacobi elliptic
functions in every regime (polhodes about the largest and the smallest axis, the separatrix,
symmetric tops, the sphere), the flip period and the time of the first flip (the attitude:
`rigidjax.analytic.poinsot_attitude`).

Pure JAX (`jit`, `vmap`, `grad`/`jacfwd`, float32/float64, leading batch dimensions broadcast).
Conventions (THEORY): `P` maps body vectors to space, quaternions scalar-first `(w, x, y, z)`
with the Hamilton product, `Ω` the body angular velocity and `M = I Ω` the body angular momentum.

Sources: Landau & Lifshitz, *Mechanics* §37; Zegrya–Parshin lectures (004, THEORY §6).
The separatrix, sign and phase handling, and the attitude were derived here (Celledoni et al. 2008
has sign errors, see Principia's `documentation/Celledoni.tex`); every formula is checked against
direct integration in the tests.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._checks import (
    Check,
    as_float,
    at,
    check_finite,
    first,
    floats,
    fmt,
    inertia_rtol,
    validate_all,
    vector,
)
from .._custom_types import RealScalarLike, Scalar, TimesLike, Vec3, Vec3Like
from .._numerics import safe_sqrt
from ._rest_point import euler_rate, omega_at_rest, rest_matrix
from .elliptic import _ellipj, _ellipk, _f_pi, _sech

# ----------------------------------------------------------------------------------------------
# Free rigid body (Euler–Poinsot)
# ----------------------------------------------------------------------------------------------
#
# Derivation (checked numerically in the tests). Label the principal axes so that I2 is the middle
# moment and the angular momentum circulates around axis 3 ("dn axis"); axis 1 is the "cn axis":
#   case (ii)  M² > 2E I_mid: (1, 2, 3) = (smallest, middle, largest), motion around the largest;
#   case (i)   M² < 2E I_mid: (1, 2, 3) = (largest, middle, smallest), motion around the smallest.
# With a = (I2 − I1)/(I3 − I1), b = (I3 − I2)/(I3 − I1) (a + b = 1, a ≥ 0, b > 0 in both cases)
#   P1 = (2E I3 − M²)/(I3 − I1) = I1 Ω1² + b I2 Ω2²      (≥ 0, no cancellation)
#   P3 = (M² − 2E I1)/(I3 − I1) = a I2 Ω2² + I3 Ω3²      (> 0)
#   bQ = (M² − 2E I2)/(I3 − I1) = b I3 Ω3² − a I1 Ω1²    (> 0 off the separatrix)
# Landau–Lifshitz §37 (for either labelling):
#   Ω1 = A1 cn τ, Ω2 = A2 sn τ, Ω3 = σ A3 dn τ,  A1² = P1/I1, A2² = P1/(b I2), A3² = P3/I3,
#   m = k² = a P1/(b P3), 1 − m = bQ/(b P3),  λ² = (I3 − I1)² b P3/(I1 I2 I3),  τ = u0 + λ t.
# σ = sign Ω3 (dn > 0). Substituting into I2 Ω̇2 = ±(I3 − I1) Ω3 Ω1 (the sign is the parity of
# the relabelling: Euler's equations are cyclic, an odd permutation reverses time) gives
#   λ = s σ |λ|,  s = parity of the ascending sort of the moments (same in both cases).
# Phase: instead of u0 = F(am0|m) the addition theorems (A&S 16.17.1–3) are used with
# (sn, cn, dn)(u0) = (Ω2/A2, Ω1/A1, |Ω3|/A3) at t = 0 and (S, C, D) = (sn, cn, dn)(λt):
#   cn(u0+v) = (c0 C − s0 d0 S D)/Δ,  sn(u0+v) = (s0 C D + c0 d0 S)/Δ,
#   dn(u0+v) = (d0 D − m s0 c0 S C)/Δ,  Δ = 1 − m s0² S² = d0² + m s0² C² (non-negative terms).
# Multiplied out, no amplitude appears in a denominator, Ω(0) = omega0 to rounding, and
# stationary rotations (P1 = 0) need no special case.
# Separatrix (bQ = 0, m = 1): Ω1 = σ1 A1 sech u, Ω2 = A2 tanh u, Ω3 = σ3 A3 sech u with both σ1
# and σ3 constant; flipping the sign of Ω1 (or Ω3) and reversing time maps solutions to solutions,
# so λ = s σ1 σ3 |λ|, sinh u0 = s0/c0, c0² = (I1 Ω1² + I3 Ω3²)/(P1 + P3).
# Degenerate inputs: equal moments give a = 0, m = 0 (sn, cn, dn = sin, cos, 1: the symmetric top);
# a sphere (all moments equal) or Ω = 0 gives Ω = const. Ties between moments are broken so that
# the tied axis with the larger |Ω| component is the "middle" one (keeps the attitude construction
# regular for steady rotation about an equatorial axis of a symmetric top).


__all__ = [
    "FreeBodyParameters",
    "check_moments",
    "flip_period",
    "free_rigid_body",
    "free_rigid_body_parameters",
    "time_of_first_flip",
]


class FreeBodyParameters(NamedTuple):
    """Constants of the Euler–Poinsot motion (see `free_rigid_body_parameters`)."""

    k2: Scalar  # elliptic parameter m = k²  (1 on the separatrix, 0 for a symmetric top / sphere)
    lam: Scalar  # |λ|: τ = u0 ± λ t  (0 for a sphere or Ω = 0)
    K: Scalar  # K(k²) (∞ on the separatrix)
    period: Scalar  # 4K/|λ|, the period of Ω(t) (∞ on the separatrix, for a sphere or Ω = 0)
    # +1 around the largest axis (M² > 2E I_mid), −1 around the smallest, 0 separatrix
    regime: Int[Array, "*#batch"]
    energy: Scalar  # kinetic energy T = ½ Ω·IΩ
    momentum: Scalar  # |M| = |IΩ|


_DUMMY_I = (1.0, 2.0, 3.0)


def _sep_tol(dtype) -> float:
    return 16 * float(jnp.finfo(dtype).eps)


def _swap(o: Array, i: int, j: int, cond: Array) -> Array:
    oi, oj = o[i], o[j]
    return o.at[i].set(jnp.where(cond, oj, oi)).at[j].set(jnp.where(cond, oi, oj))


def _sort_axes(I: Array, w: Array) -> Array:
    """Ascending order of the moments; among equal moments the larger |Ω| is put in the middle."""
    o = jnp.argsort(I)
    aw = jnp.abs(w)
    o = _swap(o, 0, 1, (I[o[0]] == I[o[1]]) & (aw[o[0]] > aw[o[1]]))
    return _swap(o, 1, 2, (I[o[1]] == I[o[2]]) & (aw[o[2]] > aw[o[1]]))


def _sign(x: Array) -> Array:
    return jnp.where(x < 0, -jnp.ones_like(x), jnp.ones_like(x))


class _Plan(NamedTuple):
    """Everything `_omega` needs, for ONE body (scalars and (3,) arrays)."""

    I: Array  # moments (a dummy for trivial cases)
    w: Array  # Ω0 (a dummy for trivial cases)
    w_orig: Array  # Ω0 as given
    trivial: Array  # sphere or Ω = 0: Ω is constant
    rest: Array  # Ω0 a rest point of Euler's equations where no branch below holds: `trivial`,
    # or a steady rotation on the separatrix (about the middle axis, in a symmetric top's plane)
    f: Array  # Euler's rate at Ω0 (`_rest_point.euler_rate`; zero where `rest`)
    F: Array  # its derivative in Ω where `rest`, else 0 (`_rest_point.rest_matrix`)
    sep: Array
    regime: Array
    M: Array
    two_e: Array
    # periodic branch (axes permuted by pp)
    pp: Array
    Ip: Array
    wp: Array
    a: Array
    b: Array
    P3: Array
    m: Array
    m1: Array
    lam_p: Array
    K: Array
    # separatrix branch (axes permuted by ps)
    ps: Array
    Is: Array
    A: Array  # (A1, A2, A3)
    sg: Array  # (σ1, 1, σ3)
    u0: Array
    lam_s: Array
    P1s: Array
    P3s: Array
    bs: Array


def _gaps_and_p(I: Array, w: Array) -> tuple[Array, Array, Array, Array]:
    """`a = (I2 − I1)/(I3 − I1)`, `b = (I3 − I2)/(I3 − I1)`, `P1 = I1 Ω1² + b I2 Ω2²` and
    `P3 = a I2 Ω2² + I3 Ω3²` for relabelled moments `I` and components `w` (the derivation
    above)."""
    I1, I2, I3 = I
    w1, w2, w3 = w
    a = (I2 - I1) / (I3 - I1)
    b = (I3 - I2) / (I3 - I1)
    return a, b, I1 * w1**2 + b * I2 * w2**2, a * I2 * w2**2 + I3 * w3**2


def _separatrix(I: Array, w: Array) -> tuple[Array, Array, Array]:
    """The axes in ascending order of the moments (`_sort_axes`), whether `M² = 2E I_mid` to
    16 ulps of the scale (the separatrix) and whether `M² > 2E I_mid` (motion about the largest
    axis)."""
    o = _sort_axes(I, w)
    Ilo, Imid, Ihi = I[o[0]], I[o[1]], I[o[2]]
    x_lo = Ilo * (Imid - Ilo) * w[o[0]] ** 2
    x_hi = Ihi * (Ihi - Imid) * w[o[2]] ** 2
    delta = x_hi - x_lo  # M² − 2E I_mid
    return o, jnp.abs(delta) <= _sep_tol(I.dtype) * (x_hi + x_lo), delta > 0


def _plan(I: Array, w: Array) -> _Plan:
    dtype = I.dtype
    dI = jnp.asarray(_DUMMY_I, dtype)
    zero = ~(jnp.sum((I * w) ** 2) > 0)
    sphere = ~(jnp.max(I) > jnp.min(I))
    trivial = zero | sphere
    f = euler_rate(I, w)
    I_orig, w_orig = I, w
    I = jnp.where(trivial, dI, I)
    w = jnp.where(trivial, jnp.asarray((0.5, 0.5, 1.0), dtype), w)

    o, sep, case_hi = _separatrix(I, w)
    # (I, w are the given ones wherever not `trivial`)
    rest = trivial | (jnp.all(f == 0) & sep)
    F = rest_matrix(I_orig, w_orig, rest)
    s = ((o[1] - o[0]) * (o[2] - o[0]) * (o[2] - o[1]) // 2).astype(dtype)  # parity ±1
    Ilo, Imid, Ihi = I[o[0]], I[o[1]], I[o[2]]
    regime = jnp.where(sep, 0, jnp.where(case_hi, 1, -1))
    M = jnp.sqrt(jnp.sum((I * w) ** 2))
    two_e = jnp.sum(I * w * w)

    # periodic branch
    pp = jnp.where(case_hi, o, o[::-1])
    Ip = jnp.where(sep, dI, I[pp])
    wp = jnp.where(sep, jnp.asarray((0.5, 0.5, 1.0), dtype), w[pp])
    I1, I2, I3 = Ip
    w1, w2, w3 = wp
    a, b, P1, P3 = _gaps_and_p(Ip, wp)
    bQ = b * I3 * w3**2 - a * I1 * w1**2
    m = a * P1 / (b * P3)
    m1 = jnp.maximum(bQ / (b * P3), jnp.finfo(dtype).tiny)
    lam_p = s * _sign(w3) * jnp.abs(I3 - I1) * jnp.sqrt(b * P3 / (I1 * I2 * I3))
    K = _ellipk(m, m1)

    # separatrix branch: order with the larger gap between 2 and 3 (b ≥ ½)
    ps = jnp.where(Ihi - Imid >= Imid - Ilo, o, o[::-1])
    Is = jnp.where(sep, I[ps], dI)
    ws = jnp.where(sep, w[ps], jnp.ones((3,), dtype))
    J1, J2, J3 = Is
    v1, v2, v3 = ws
    _, bs, P1s, P3s = _gaps_and_p(Is, ws)
    A = jnp.stack([jnp.sqrt(P1s / J1), jnp.sqrt(P1s / (bs * J2)), safe_sqrt(P3s / J3)])
    c0 = safe_sqrt((J1 * v1**2 + J3 * v3**2) / (P1s + P3s))
    has_c = c0 > 0
    x = v2 / (A[1] * jnp.where(has_c, c0, jnp.ones_like(c0)))
    u0 = jnp.where(has_c, jnp.arcsinh(x), _sign(v2) * jnp.inf)
    sg = jnp.stack([_sign(v1), jnp.ones_like(v1), _sign(v3)])
    lam_s = s * sg[0] * sg[2] * jnp.abs(J3 - J1) * safe_sqrt(bs * P3s / (J1 * J2 * J3))
    return _Plan(
        *(I, w, w_orig, trivial, rest, f, F, sep, regime, M, two_e),
        *(pp, Ip, wp, a, b, P3, m, m1, lam_p, K),
        *(ps, Is, A, sg, u0, lam_s, P1s, P3s, bs),
    )


def _omega_periodic(p: _Plan, t: Array, scd: tuple[Array, Array, Array] | None = None) -> Array:
    """Ω in the periodic branch, permuted axes, `t` any shape → (*t.shape, 3); `scd`: the
    `(sn, cn, dn)(λt)` if already computed."""
    I1, I2, I3 = p.Ip
    w1, w2, w3 = p.wp
    S, C, D = _ellipj(p.lam_p * t, p.m, p.m1)[:3] if scd is None else scd
    d0 = jnp.abs(w3) * jnp.sqrt(I3 / p.P3)
    den = (I3 * w3**2 + p.a * I2 * w2**2 * C * C) / p.P3
    r12 = jnp.sqrt(p.b * I2 / I1)  # A1/A2
    r3 = _sign(w3) * p.a * jnp.sqrt(I1 * I2 / (p.b * I3 * p.P3))
    o1 = (w1 * C - r12 * w2 * d0 * S * D) / den
    o2 = (w2 * C * D + w1 * d0 * S / r12) / den
    o3 = (w3 * D - r3 * w1 * w2 * S * C) / den
    return jnp.stack([o1, o2, o3], axis=-1)


def _omega_sep(p: _Plan, t: Array) -> Array:
    u = p.u0 + p.lam_s * t
    e = _sech(u)
    return jnp.stack([e, jnp.tanh(u), e], axis=-1) * (p.sg * p.A)


def _unpermute(x: Array, perm: Array) -> Array:
    return jnp.take(x, jnp.argsort(perm), axis=-1)


def _omega(p: _Plan, t: Array, per: Array | None = None) -> Array:
    """Body angular velocity at times `t` (any shape; Ω(0) = Ω0) → (*t.shape, 3); `per`: the
    periodic branch `_omega_periodic(p, t)` if already computed."""
    per = _unpermute(_omega_periodic(p, t) if per is None else per, p.pp)
    sep = _unpermute(_omega_sep(p, t), p.ps)
    out = jnp.where(p.sep, sep, per)
    return jnp.where(p.rest, omega_at_rest(p.w_orig, p.f, p.F, t), out)


def check_moments(I: Array, name: str = "inertia", check: bool = True) -> Array:
    """Principal moments `I (..., 3)` of a body, checked: finite, positive and, unless
    `check=False`, within the triangle inequality (the largest ≤ the sum of the other two,
    within `max(1e-9, 1000 eps)` of the largest, as `RigidBody`: no mass distribution has other
    moments). One error naming `name`, the offending moments and the fix (see
    `rigidjax._checks.validate_all`). `check=False` (as `RigidBody(..., check=False)`) admits
    such formal moments: Euler's equations and their closed form hold for any positive moments,
    and reference cases use them (I = (3, 5, 9) in Principia's tests)."""
    tol = inertia_rtol(I.dtype)

    def bad_finite(xp, v):
        return ~xp.all(xp.isfinite(v), axis=-1)

    def bad_positive(xp, v):
        return ~xp.all(v > 0, axis=-1)

    def bad_triangle(xp, v):
        s = xp.sort(v, axis=-1)
        return s[..., 2] - (s[..., 0] + s[..., 1]) > tol * s[..., 2]

    def detail(bad):
        def show(v):
            k = first(bad(np, v))
            return f", got {at(name, k)} = {fmt(v[k])}"

        return show

    fix = "; give three principal moments > 0 (of a tensor I: RigidBody(I).principal_moments)"
    checks = [
        Check(bad_finite, f"{name} must be finite", detail(bad_finite), fix),
        Check(bad_positive, f"{name} must be positive", detail(bad_positive), fix),
    ]
    if check:
        checks.append(
            Check(
                bad_triangle,
                f"{name} violates the triangle inequality (the largest principal moment exceeds "
                "the sum of the other two)",
                detail(bad_triangle),
                "; no rigid body has these moments: check the values and units, or pass "
                "check=False for a formal case (Euler's equations hold for any positive moments)",
            )
        )
    return validate_all(I, checks)


def _body_inputs(
    inertia: Vec3Like, omega0: Vec3Like, ts: TimesLike | None = None, check: bool = True
) -> list[Float[Array, "..."]]:
    """The arguments of the closed forms as floats of one dtype, checked: `inertia` by
    `check_moments` (the triangle inequality unless `check=False`), `omega0` and `ts` finite."""
    names = ("inertia", "omega0") + (() if ts is None else ("ts",))
    args = (inertia, omega0) + (() if ts is None else (ts,))
    out = floats(*zip(args, names, strict=True))
    out[0] = check_moments(vector(out[0], 3, "inertia"), check=check)
    vector(out[1], 3, "omega0")
    return [out[0]] + [check_finite(x, n) for x, n in zip(out[1:], names[1:], strict=True)]


def free_rigid_body(
    inertia: Vec3Like,
    omega0: Vec3Like,
    ts: TimesLike,
    t0: RealScalarLike = 0.0,
    *,
    check: bool = True,
) -> Float[Array, "*#batch T 3"] | Vec3:
    """Closed-form body angular velocity of the torque-free rigid body (Euler–Poinsot).

    `inertia`: principal moments `(..., 3)` in any order (positive; equal moments allowed);
    `omega0`: body angular velocity `(..., 3)` at time `t0`; `ts`: times `(T,)` (any finite
    values, before or after `t0`). Returns `Ω(ts)` with shape `(..., T, 3)`, `Ω(t0) = omega0` to
    rounding. Bad moments (NaN, ≤ 0, against the triangle inequality: `check_moments`; `check=False`
    admits the last) or a non-finite `omega0`, `ts` or `t0` are an error naming the argument.

    With `2E = Σ I_i Ω_i²`, `M² = Σ I_i² Ω_i²` and axes relabelled so that I2 is the middle moment
    (Landau–Lifshitz §37): for `M² > 2E I2` (motion around the largest axis, labelled 3)
        `Ω1 = A1 cn τ`, `Ω2 = A2 sn τ`, `Ω3 = ±A3 dn τ`,
        `A1² = (2E I3 − M²)/(I1(I3 − I1))`, `A2² = (2E I3 − M²)/(I2(I3 − I2))`,
        `A3² = (M² − 2E I1)/(I3(I3 − I1))`, `τ = u0 + λ t`,
        `λ² = (I3 − I2)(M² − 2E I1)/(I1 I2 I3)`,
        `k² = (I2 − I1)(2E I3 − M²)/((I3 − I2)(M² − 2E I1))`,
    and for `M² < 2E I2` the same with the labels 1 ↔ 3 swapped (motion around the smallest
    axis). On the separatrix `M² = 2E I2` (k = 1; chosen when |M² − 2E I2| is within 16 ulps of
    the scale): `sn → tanh`, `cn, dn → sech` (aperiodic). The sign of λ follows from Euler's
    equations and the signs of the components that never change sign; the phase u0 enters through
    the addition theorems of sn, cn, dn (A&S 16.17), so no incomplete integral is needed and the
    formula is differentiable everywhere off the separatrix (on it, at a point that is not a rest
    point, only the derivatives along it are the motion's; within ~1e-9 of it, relative, they
    lose accuracy: `free_rigid_body_attitude`). Equal moments (symmetric top) give
    k = 0 and the symmetric-top solution `Ω1 + iΩ2 ∝ e^{iωt}`; a spherical top, Ω = 0 and a
    steady rotation on the separatrix (about the middle axis, in a symmetric top's plane of equal
    moments) give a constant, whose first derivatives are those of the motion (its
    linearisation; at a sphere also the second: `_rest_point.omega_at_rest`). Derivation notes
    are in the module source.
    """
    inertia, omega0, ts = _body_inputs(inertia, omega0, ts, check)
    t0 = check_finite(as_float(t0, "t0").astype(ts.dtype), "t0")
    scalar = ts.ndim == 0
    ts1 = jnp.atleast_1d(ts)

    out = _free_rigid_body_jit(inertia, omega0, ts1, t0)
    return out[..., 0, :] if scalar else out


@jax.jit
def _free_rigid_body_jit(inertia, omega0, ts, t0):
    def one(I, w, t):
        return _omega(_plan(I, w), t - t0)

    return jnp.vectorize(one, signature="(3),(3),(t)->(t,3)")(inertia, omega0, ts)


def free_rigid_body_parameters(
    inertia: Vec3Like, omega0: Vec3Like, *, check: bool = True
) -> FreeBodyParameters:
    """`FreeBodyParameters(k2, lam, K, period, regime, energy, momentum)` of the Euler–Poinsot
    motion started at `omega0` (see `free_rigid_body` for the formulas); batch dims broadcast.

    `period = 4K(k²)/|λ|` is the period of Ω(t); half of it is the time between two flips of the
    Dzhanibekov (tennis-racket) effect. For a steady rotation about the largest or smallest axis
    (k = 0) it is the period of the small oscillations around it, `2π/|λ|`. `check`: as in
    `free_rigid_body`.
    """
    inertia, omega0 = _body_inputs(inertia, omega0, check=check)
    return FreeBodyParameters(*_parameters_jit(inertia, omega0))


@jax.jit
def _parameters_jit(inertia, omega0):
    def one(I, w):
        p = _plan(I, w)
        bad = p.sep | p.trivial
        k2 = jnp.where(p.sep, 1.0, jnp.where(p.trivial, 0.0, p.m))
        lam = jnp.where(p.trivial, 0.0, jnp.where(p.sep, jnp.abs(p.lam_s), jnp.abs(p.lam_p)))
        K = jnp.where(p.sep, jnp.inf, jnp.where(p.trivial, 0.5 * math.pi, p.K))
        period = jnp.where(bad, jnp.inf, 4 * p.K / jnp.abs(p.lam_p))
        triv = jnp.sum(I * w * w) == 0
        energy = 0.5 * jnp.where(triv, 0.0, jnp.sum(I * w * w))
        momentum = safe_sqrt(jnp.sum((I * w) ** 2))
        regime = jnp.where(p.trivial, 0, p.regime)
        return k2, lam, K, period, regime, energy, momentum

    return jnp.vectorize(one, signature="(3),(3)->(),(),(),(),(),(),()")(inertia, omega0)


def flip_period(inertia: Vec3Like, omega0: Vec3Like, *, check: bool = True) -> Scalar:
    """Period of the body angular velocity, `4K(k²)/|λ|` (see `free_rigid_body`); the time
    between two successive flips (sign changes of a component of cn or sn type, e.g. the
    middle-axis one) is half of it. ∞ on the separatrix, for a spherical top and for Ω = 0."""
    return free_rigid_body_parameters(inertia, omega0, check=check).period


def _first_sn_zero(s: Array, c: Array, p: _Plan) -> Array:
    """First t > 0 with `sn(v0 + λt) = 0` (periodic branch, λ = `p.lam_p`), given
    `(s, c) ∝ (sn v0, cn v0)` with a positive factor: the amplitude still to go to the next
    multiple of π is `φ = atan2(|s'|, −sign(s') c)`, `s' = s · sign λ`, and `t = F(φ|k²)/|λ|`;
    `s' = 0` (a zero at t = 0 itself) gives the next one, `2K/|λ|` later. F is taken from
    (sin φ, cos φ) themselves (`F(φ) = 2K − F(π − φ)` past π/2): close to the separatrix
    `dF/dφ = 1/Δ` is huge near φ = π/2, where φ itself would carry only eps/Δ of accuracy."""
    s = s * _sign(p.lam_p)
    at_zero = s == 0
    c = jnp.where(at_zero & (c == 0), jnp.ones_like(c), c)  # keeps the gradients finite
    r = jnp.sqrt(s * s + c * c)
    sin_phi, cos_phi = jnp.abs(s) / r, -_sign(s) * c / r
    f = _f_pi(jnp.zeros_like(r), sin_phi, jnp.abs(cos_phi), p.m, p.m1)[0]  # F(min(φ, π − φ))
    f = jnp.where(at_zero, 2 * p.K, jnp.where(cos_phi >= 0, f, 2 * p.K - f))
    return f / jnp.abs(p.lam_p)


def time_of_first_flip(inertia: Vec3Like, omega0: Vec3Like, *, check: bool = True) -> Scalar:
    """First time t > 0 at which the body angular-velocity component along the initially
    dominant axis changes sign, in closed form; ∞ if it never does. Batch dims broadcast.

    The initially dominant axis d is the principal axis with the largest |Ω0_d|; on a tie, the
    one listed first in `inertia`. With the labels of `free_rigid_body` (axis 3 the one the polhode
    encircles; Landau–Lifshitz §37) `Ω1 = A1 cn τ`, `Ω2 = A2 sn τ`, `Ω3 = ±A3 dn τ`, `τ = u0 + λt`:
    - d = 3: dn > 0 never vanishes: ∞ (also steady rotation about any principal axis, the
      symmetry axis of a symmetric top, a sphere, Ω = 0);
    - d = 2: the zeros are `sn(u0 + λt) = 0`;
    - d = 1: `cn(u0 + λt) = −k' sd(u0 + λt − K)` (A&S 16.8.1, `k'² = 1 − k²`), so the zeros are
      `sn(v0 + λt) = 0` with `(sn v0, cn v0) = (−cn u0, k' sn u0)/dn u0`.
    With `(s, c) ∝ (sn v0, cn v0)` read off Ω0 (`v0 = u0` for d = 2) and `s' = s · sign λ`, the
    amplitude to the next zero is `φ = atan2(|s'|, −sign(s') c)` and `t = F(φ|k²)/|λ|` (F:
    `ellipkinc`, A&S 17.2; `2K/|λ|` if `s' = 0`: a zero at t = 0 itself is not counted). A
    symmetric top (k = 0, the symmetry axis labelled 3) is the case `F(φ|0) = φ`: a transverse
    dominant component rotates with the rest of `Ω1 + iΩ2` and vanishes a finite time later.
    On the separatrix (`Ω2 = A2 tanh u`, `Ω1, Ω3 ∝ sech u`, `u = u0 + λt`) only the middle
    component can vanish, once, at `t = −u0/λ` if that is positive; otherwise ∞. Derived here
    from THEORY §6 and the formulas above; checked against `simulate` in the tests.
    Differentiable: finite gradients wherever the time is finite (on the separatrix itself only
    the derivative along it is exact), zero where it is ∞. `check`: as in `free_rigid_body`.
    """
    inertia, omega0 = _body_inputs(inertia, omega0, check=check)
    return _first_flip_jit(inertia, omega0)


@jax.jit
def _first_flip_jit(inertia, omega0):
    def one(I, w):
        p = _plan(I, w)
        d = jnp.argmax(jnp.abs(w))  # first of the largest |Ω0_i|
        jp = jnp.argmax(p.pp == d)  # its place among the (cn, sn, dn) axes of the periodic branch
        js = jnp.argmax(p.ps == d)  # ... and among (sech, tanh, sech) of the separatrix branch
        I1, I2, _ = p.Ip
        w1, w2, _ = p.wp
        r12w2 = jnp.sqrt(p.b * I2 / I1) * w2  # (A1/A2) Ω2: (r12w2, w1) ∝ (sn u0, cn u0)
        cn_type = jp == 0
        s = jnp.where(cn_type, -w1, r12w2)
        c = jnp.where(cn_type, jnp.sqrt(p.m1) * r12w2, w1)
        t_per = jnp.where(jp == 2, jnp.inf, _first_sn_zero(s, c, p))
        lam_s = jnp.where(p.lam_s == 0, jnp.ones_like(p.lam_s), p.lam_s)
        u0 = jnp.where(jnp.isfinite(p.u0), p.u0, _sign(lam_s))  # ±∞: no crossing ahead
        t_sep = -u0 / lam_s
        t_sep = jnp.where((t_sep > 0) & (p.lam_s != 0) & (js == 1), t_sep, jnp.inf)
        return jnp.where(p.trivial, jnp.inf, jnp.where(p.sep, t_sep, t_per))

    return jnp.vectorize(one, signature="(3),(3)->()")(inertia, omega0)
