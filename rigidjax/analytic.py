"""Closed-form (analytic) solutions: Jacobi elliptic functions, the free rigid body (Euler–Poinsot),
the free symmetric top and rotation about a fixed axis.

Everything here is pure JAX: `jit`, `vmap`, `grad`/`jacfwd` work, float32 and float64 keep their
dtype, and leading batch dimensions broadcast. Loops have a fixed number of steps (no data-dependent
control flow), so the functions trace once per shape.

Conventions (THEORY.md): `P` maps body vectors to space, quaternions are scalar-first `(w, x, y, z)`
with the Hamilton product, `Ω` is the body angular velocity and `M = I Ω` the body angular momentum.

Sources. Jacobi functions: Abramowitz & Stegun (A&S) 16.4 (arithmetic–geometric mean, descending
Landen), 16.17 (addition theorems), 17.6 (AGM for K and F). Free rigid body: Landau & Lifshitz,
*Mechanics* §37; Zegrya–Parshin lectures (seed 004, THEORY.md §6). The separatrix, sign and phase
handling, and the attitude were derived here (Celledoni et al. 2008 has sign errors, see Principia's
`documentation/Celledoni.tex`); every formula is checked against direct integration in
`tests/test_analytic.py`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from . import quat
from ._util import as_float, vector

__all__ = [
    "FreeBodyParameters",
    "SymmetricTopPrecession",
    "am",
    "cn",
    "dn",
    "ellipj",
    "ellipk",
    "ellipkinc",
    "ellipkm1",
    "fixed_axis_rotation",
    "flip_period",
    "free_rigid_body",
    "free_rigid_body_attitude",
    "free_rigid_body_parameters",
    "sn",
    "symmetric_top",
    "symmetric_top_attitude",
    "symmetric_top_precession",
    "time_of_first_flip",
]

# Arithmetic–geometric mean steps. From b0 = √(1 − m) the ratio b/a first grows like 2√(b/a) per
# step, then c/a falls quadratically: 14 steps reach c/a < 1e-20 for any 1 − m ≥ 1e-300 (13 are
# needed at 1e-300, 9 at 1e-16). Extra steps are exact no-ops (c = 0): one count for all dtypes.
_AGM_STEPS = 14


def _floats(*xs: ArrayLike, names: tuple[str, ...]) -> list[Array]:
    arrs = [as_float(x, n) for x, n in zip(xs, names, strict=True)]
    dtype = jnp.result_type(*arrs)
    return [a.astype(dtype) for a in arrs]


def _agm(m: Array, m1: Array) -> tuple[Array, Array]:
    """AGM sequences of A&S 16.4.2: `a0 = 1`, `b0 = √m1` (`m1 = 1 − m`), `a_n = (a + b)/2`,
    `b_n = √(a b)`, `c_n = (a − b)/2`; returns `a_1..a_N` and `c_1..c_N` stacked on a leading
    axis. `c0 = √m` is never used, so derivatives stay finite at m = 0. A `lax.scan` (not an
    unrolled loop) keeps the compiled program small."""
    m, m1 = jnp.broadcast_arrays(m, m1)

    def step(ab, _):
        a, b = ab
        an, c = 0.5 * (a + b), 0.5 * (a - b)
        return (an, jnp.sqrt(a * b)), (an, c)

    _, (As, Cs) = jax.lax.scan(step, (jnp.ones_like(m), jnp.sqrt(m1)), None, length=_AGM_STEPS)
    return As, Cs


def _ellipj(u: Array, m: Array, m1: Array) -> tuple[Array, Array, Array, Array]:
    """sn, cn, dn, am for 0 ≤ m < 1 by the descending AGM algorithm (A&S 16.4.3):
    `φ_N = 2^N a_N u`, `φ_{n−1} = ½(φ_n + arcsin((c_n/a_n) sin φ_n))`, `am = φ_0`,
    `sn = sin φ_0`, `cn = cos φ_0`; `dn = √(m1 + m cn²)` (= √(1 − m sn²), a sum of non-negative
    terms, so no cancellation near m = 1). `m1 = 1 − m` is passed separately so that it can be given
    more accurately than `1 − m` (near the separatrix of the rigid body)."""
    As, Cs = _agm(m, m1)
    k = Cs / As
    phi = (2.0**_AGM_STEPS) * As[-1] * u

    def step(phi, kn):
        return 0.5 * (phi + jnp.arcsin(kn * jnp.sin(phi))), None

    phi, _ = jax.lax.scan(
        step,
        phi,
        jnp.broadcast_to(k[:, *(None,) * (phi.ndim - k.ndim + 1)], (k.shape[0], *phi.shape)),
        reverse=True,
    )
    c = jnp.cos(phi)
    return jnp.sin(phi), c, jnp.sqrt(m1 + m * c * c), phi


def _ellipk(m: Array, m1: Array) -> Array:
    """`K(m) = π / (2 AGM(1, √(1 − m)))` (A&S 17.6)."""
    As, _ = _agm(m, m1)
    return (0.5 * math.pi) / As[-1]


def _ellipf(phi: Array, m: Array, m1: Array) -> Array:
    """Incomplete integral of the first kind `F(φ|m) = ∫₀^φ dθ/√(1 − m sin²θ)` for any real φ and
    0 ≤ m < 1, by running the descending algorithm of `_ellipj` backwards (ascending Landen):
    `sin(2φ_{n−1} − φ_n) = (c_n/a_n) sin φ_n` solved for φ_n gives
    `φ_n = 2φ_{n−1} − atan2(k sin 2φ_{n−1}, 1 + k cos 2φ_{n−1})`, `k = c_n/a_n < 1`; then
    `F = φ_N / (2^N a_N)`. No quadrant bookkeeping is needed and the map is smooth in φ and m."""
    As, Cs = _agm(m, m1)
    k = Cs / As
    phi = jnp.broadcast_to(phi, jnp.broadcast_shapes(phi.shape, m.shape, m1.shape))

    def step(phi, kn):
        t = 2 * phi
        return t - jnp.arctan2(kn * jnp.sin(t), 1 + kn * jnp.cos(t)), None

    phi, _ = jax.lax.scan(
        step,
        phi,
        jnp.broadcast_to(k[:, *(None,) * (phi.ndim - k.ndim + 1)], (k.shape[0], *phi.shape)),
    )
    return phi / ((2.0**_AGM_STEPS) * As[-1])


def _sech(x: Array) -> Array:
    """`1/cosh x = 2e^{−|x|}/(1 + e^{−2|x|})`: no overflow, value and derivative 0 at ±∞."""
    e = jnp.exp(-jnp.abs(x))
    return 2 * e / (1 + e * e)


def _split_m(m: Array) -> tuple[Array, Array, Array, Array]:
    """Masks for m = 1 and m outside [0, 1], and a safe m (with 1 − m) for the AGM branch."""
    one = m == 1
    bad = ~((m >= 0) & (m <= 1))
    ms = jnp.where(one | bad, jnp.asarray(0.5, m.dtype), m)
    return one, bad, ms, 1 - ms


@jax.jit
def ellipj(u: ArrayLike, m: ArrayLike) -> tuple[Array, Array, Array, Array]:
    """Jacobi elliptic functions `(sn, cn, dn, am)(u|m)`, like `scipy.special.ellipj`.

    Parameter convention of A&S 16.1 (and SciPy): `m = k²`, 0 ≤ m ≤ 1;
    `u = ∫₀^am dθ/√(1 − m sin²θ)`, `sn = sin am`, `cn = cos am`, `dn = √(1 − m sn²)`.
    For m < 1 the descending AGM/Landen algorithm of A&S 16.4 with a fixed number of steps
    (accurate to a few ulps of `m` for any real `u`, error growing like `eps·|u|`); at m = 1
    `sn = tanh u`, `cn = dn = sech u`, `am = gd u = 2 atan(tanh(u/2))`. NaN outside [0, 1].
    Differentiable in u and in m on [0, 1).
    """
    u, m = _floats(u, m, names=("u", "m"))
    one, bad, ms, m1 = _split_m(m)
    s, c, d, ph = _ellipj(u, ms, m1)
    th, se = jnp.tanh(u), _sech(u)
    gd = 2 * jnp.arctan(jnp.tanh(0.5 * u))
    nan = jnp.asarray(jnp.nan, s.dtype)
    out = []
    for x, x1 in ((s, th), (c, se), (d, se), (ph, gd)):
        out.append(jnp.where(bad, nan, jnp.where(one, x1, x)))
    return tuple(out)


def sn(u: ArrayLike, m: ArrayLike) -> Array:
    """Jacobi `sn(u|m)` (see `ellipj`)."""
    return ellipj(u, m)[0]


def cn(u: ArrayLike, m: ArrayLike) -> Array:
    """Jacobi `cn(u|m)` (see `ellipj`)."""
    return ellipj(u, m)[1]


def dn(u: ArrayLike, m: ArrayLike) -> Array:
    """Jacobi `dn(u|m)` (see `ellipj`)."""
    return ellipj(u, m)[2]


def am(u: ArrayLike, m: ArrayLike) -> Array:
    """Jacobi amplitude `am(u|m)`, the inverse of `ellipkinc` in φ (see `ellipj`)."""
    return ellipj(u, m)[3]


@jax.jit
def ellipk(m: ArrayLike) -> Array:
    """Complete elliptic integral of the first kind `K(m) = ∫₀^{π/2} dθ/√(1 − m sin²θ)`
    `= π / (2 AGM(1, √(1 − m)))` (A&S 17.6), like `scipy.special.ellipk`; `K(1) = ∞`, NaN for
    m > 1 or m < 0 (SciPy extends to m < 0; this does not)."""
    m = as_float(m, "m")
    one, bad, ms, m1 = _split_m(m)
    k = _ellipk(ms, m1)
    return jnp.where(bad, jnp.nan, jnp.where(one, jnp.inf, k))


@jax.jit
def ellipkm1(p: ArrayLike) -> Array:
    """`K(1 − p)` accurate for small `p` (the complementary parameter), like
    `scipy.special.ellipkm1`: the AGM starts from `√p` directly. `p` in (0, 1]; ∞ at p = 0."""
    p = as_float(p, "p")
    zero = p == 0
    bad = ~((p >= 0) & (p <= 1))
    ps = jnp.where(zero | bad, jnp.asarray(0.5, p.dtype), p)
    k = _ellipk(1 - ps, ps)
    return jnp.where(bad, jnp.nan, jnp.where(zero, jnp.inf, k))


@jax.jit
def ellipkinc(phi: ArrayLike, m: ArrayLike) -> Array:
    """Incomplete elliptic integral of the first kind `F(φ|m) = ∫₀^φ dθ/√(1 − m sin²θ)`, like
    `scipy.special.ellipkinc`, for any real φ (`F(φ + π) = F(φ) + 2K`) and 0 ≤ m ≤ 1
    (`F(φ|1) = asinh(tan φ)` for |φ| < π/2, ±∞ beyond). Ascending Landen transformation (the
    inverse of A&S 16.4, see `_ellipf`); the inverse of `am`."""
    phi, m = _floats(phi, m, names=("phi", "m"))
    one, bad, ms, m1 = _split_m(m)
    f = _ellipf(phi, ms, m1)
    inside = jnp.abs(phi) < 0.5 * math.pi
    f1 = jnp.where(
        inside,
        jnp.arcsinh(jnp.tan(jnp.where(inside, phi, jnp.zeros_like(phi)))),
        jnp.sign(phi) * jnp.inf,
    )
    return jnp.where(bad, jnp.nan, jnp.where(one, f1, f))


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


class FreeBodyParameters(NamedTuple):
    """Constants of the Euler–Poinsot motion (see `free_rigid_body_parameters`)."""

    k2: Array  # elliptic parameter m = k²  (1 on the separatrix, 0 for a symmetric top / sphere)
    lam: Array  # |λ|: τ = u0 ± λ t  (0 for a sphere or Ω = 0)
    K: Array  # K(k²) (∞ on the separatrix)
    period: Array  # 4K/|λ|, the period of Ω(t) (∞ on the separatrix, for a sphere or Ω = 0)
    regime: (
        Array  # +1 around the largest axis (M² > 2E I_mid), −1 around the smallest, 0 separatrix
    )
    energy: Array  # kinetic energy T = ½ Ω·IΩ
    momentum: Array  # |M| = |IΩ|


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


def _safe_sqrt(x: Array) -> Array:
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, jnp.ones_like(x))), jnp.zeros_like(x))


def _sign(x: Array) -> Array:
    return jnp.where(x < 0, -jnp.ones_like(x), jnp.ones_like(x))


class _Plan(NamedTuple):
    """Everything `_omega` needs, for ONE body (scalars and (3,) arrays)."""

    I: Array  # moments (a dummy for trivial cases)
    w: Array  # Ω0 (a dummy for trivial cases)
    w_orig: Array  # Ω0 as given
    trivial: Array  # sphere or Ω = 0: Ω is constant
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


def _plan(I: Array, w: Array) -> _Plan:
    dtype = I.dtype
    dI = jnp.asarray(_DUMMY_I, dtype)
    zero = ~(jnp.sum((I * w) ** 2) > 0)
    sphere = ~(jnp.max(I) > jnp.min(I))
    trivial = zero | sphere
    w_orig = w
    I = jnp.where(trivial, dI, I)
    w = jnp.where(trivial, jnp.asarray((0.5, 0.5, 1.0), dtype), w)

    o = _sort_axes(I, w)
    s = ((o[1] - o[0]) * (o[2] - o[0]) * (o[2] - o[1]) // 2).astype(dtype)  # parity ±1
    Ilo, Imid, Ihi = I[o[0]], I[o[1]], I[o[2]]
    wlo, whi = w[o[0]], w[o[2]]
    x_lo = Ilo * (Imid - Ilo) * wlo**2
    x_hi = Ihi * (Ihi - Imid) * whi**2
    delta = x_hi - x_lo  # M² − 2E I_mid
    sep = jnp.abs(delta) <= _sep_tol(dtype) * (x_hi + x_lo)
    case_hi = delta > 0
    regime = jnp.where(sep, 0, jnp.where(case_hi, 1, -1))
    M = jnp.sqrt(jnp.sum((I * w) ** 2))
    two_e = jnp.sum(I * w * w)

    # periodic branch
    pp = jnp.where(case_hi, o, o[::-1])
    Ip = jnp.where(sep, dI, I[pp])
    wp = jnp.where(sep, jnp.asarray((0.5, 0.5, 1.0), dtype), w[pp])
    I1, I2, I3 = Ip
    w1, w2, w3 = wp
    a = (I2 - I1) / (I3 - I1)
    b = (I3 - I2) / (I3 - I1)
    P1 = I1 * w1**2 + b * I2 * w2**2
    P3 = a * I2 * w2**2 + I3 * w3**2
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
    bs = (J3 - J2) / (J3 - J1)
    as_ = (J2 - J1) / (J3 - J1)
    P1s = J1 * v1**2 + bs * J2 * v2**2
    P3s = as_ * J2 * v2**2 + J3 * v3**2
    A = jnp.stack([jnp.sqrt(P1s / J1), jnp.sqrt(P1s / (bs * J2)), _safe_sqrt(P3s / J3)])
    c0 = _safe_sqrt((J1 * v1**2 + J3 * v3**2) / (P1s + P3s))
    has_c = c0 > 0
    x = v2 / (A[1] * jnp.where(has_c, c0, jnp.ones_like(c0)))
    u0 = jnp.where(has_c, jnp.arcsinh(x), _sign(v2) * jnp.inf)
    sg = jnp.stack([_sign(v1), jnp.ones_like(v1), _sign(v3)])
    lam_s = s * sg[0] * sg[2] * jnp.abs(J3 - J1) * _safe_sqrt(bs * P3s / (J1 * J2 * J3))
    return _Plan(
        *(I, w, w_orig, trivial, sep, regime, M, two_e),
        *(pp, Ip, wp, a, b, P3, m, m1, lam_p, K),
        *(ps, Is, A, sg, u0, lam_s, P1s, P3s, bs),
    )


def _omega_periodic(p: _Plan, t: Array) -> Array:
    """Ω in the periodic branch, permuted axes, `t` any shape → (*t.shape, 3)."""
    I1, I2, I3 = p.Ip
    w1, w2, w3 = p.wp
    S, C, D = _ellipj(p.lam_p * t, p.m, p.m1)[:3]
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
    return jnp.where(p.trivial, jnp.broadcast_to(p.w_orig, out.shape), out)


def _body_inputs(inertia, omega0, ts=None):
    names = ("inertia", "omega0") + (() if ts is None else ("ts",))
    args = (inertia, omega0) + (() if ts is None else (ts,))
    out = _floats(*args, names=names)
    vector(out[0], 3, "inertia")
    vector(out[1], 3, "omega0")
    return out


def free_rigid_body(
    inertia: ArrayLike, omega0: ArrayLike, ts: ArrayLike, t0: ArrayLike = 0.0
) -> Float[Array, "... T 3"]:
    """Closed-form body angular velocity of the torque-free rigid body (Euler–Poinsot).

    `inertia`: principal moments `(..., 3)` in any order (positive; equal moments allowed);
    `omega0`: body angular velocity `(..., 3)` at time `t0`; `ts`: times `(T,)` (any real values,
    before or after `t0`). Returns `Ω(ts)` with shape `(..., T, 3)`, `Ω(t0) = omega0` to rounding.

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
    formula is differentiable everywhere off the separatrix. Equal moments (symmetric top) give
    k = 0 and the symmetric-top solution `Ω1 + iΩ2 ∝ e^{iωt}`; a spherical top or Ω = 0 gives a
    constant. Derivation notes are in the module source.
    """
    inertia, omega0, ts = _body_inputs(inertia, omega0, ts)
    t0 = as_float(t0, "t0").astype(ts.dtype)
    scalar = ts.ndim == 0
    ts1 = jnp.atleast_1d(ts)

    out = _free_rigid_body_jit(inertia, omega0, ts1, t0)
    return out[..., 0, :] if scalar else out


@jax.jit
def _free_rigid_body_jit(inertia, omega0, ts, t0):
    def one(I, w, t):
        return _omega(_plan(I, w), t - t0)

    return jnp.vectorize(one, signature="(3),(3),(t)->(t,3)")(inertia, omega0, ts)


def free_rigid_body_parameters(inertia: ArrayLike, omega0: ArrayLike) -> FreeBodyParameters:
    """`FreeBodyParameters(k2, lam, K, period, regime, energy, momentum)` of the Euler–Poinsot
    motion started at `omega0` (see `free_rigid_body` for the formulas); batch dims broadcast.

    `period = 4K(k²)/|λ|` is the period of Ω(t); half of it is the time between two flips of the
    Dzhanibekov (tennis-racket) effect. For a steady rotation about the largest or smallest axis
    (k = 0) it is the period of the small oscillations around it, `2π/|λ|`.
    """
    inertia, omega0 = _body_inputs(inertia, omega0)

    def one(I, w):
        p = _plan(I, w)
        bad = p.sep | p.trivial
        k2 = jnp.where(p.sep, 1.0, jnp.where(p.trivial, 0.0, p.m))
        lam = jnp.where(p.trivial, 0.0, jnp.where(p.sep, jnp.abs(p.lam_s), jnp.abs(p.lam_p)))
        K = jnp.where(p.sep, jnp.inf, jnp.where(p.trivial, 0.5 * math.pi, p.K))
        period = jnp.where(bad, jnp.inf, 4 * p.K / jnp.abs(p.lam_p))
        triv = jnp.sum(I * w * w) == 0
        energy = 0.5 * jnp.where(triv, 0.0, jnp.sum(I * w * w))
        momentum = _safe_sqrt(jnp.sum((I * w) ** 2))
        regime = jnp.where(p.trivial, 0, p.regime)
        return k2, lam, K, period, regime, energy, momentum

    out = jax.jit(jnp.vectorize(one, signature="(3),(3)->(),(),(),(),(),(),()"))(inertia, omega0)
    return FreeBodyParameters(*out)


def flip_period(inertia: ArrayLike, omega0: ArrayLike) -> Array:
    """Period of the body angular velocity, `4K(k²)/|λ|` (see `free_rigid_body`); the time
    between two successive flips (sign changes of the middle-axis component) is half of it.
    ∞ on the separatrix, for a spherical top and for Ω = 0."""
    return free_rigid_body_parameters(inertia, omega0).period


def time_of_first_flip(inertia: ArrayLike, omega0: ArrayLike) -> Array:
    """First time t > 0 at which the middle-axis component of Ω changes sign (the first flip of
    the tennis-racket effect), in closed form; ∞ if it never does (steady rotations, the
    separatrix after its single crossing, spheres, Ω = 0). A zero at t = 0 itself is not counted.

    Ω_mid = A2 sn(u0 + λt) vanishes where the argument is a multiple of 2K. With
    `s0 = sn u0 · sign λ` and `c0 = cn u0`, the amplitude of the next zero ahead is
    `φ = atan2(|s0|, −sign(s0) c0)` and `t = F(φ|k²)/|λ|` (F: `ellipkinc`); if `s0 = 0` the next
    zero is a half period `2K/|λ|` away. On the separatrix `t = −u0/λ` when positive.
    """
    inertia, omega0 = _body_inputs(inertia, omega0)

    def one(I, w):
        p = _plan(I, w)
        I1, I2, I3 = p.Ip
        w1, w2, _ = p.wp
        still = (w1 == 0) & (w2 == 0)  # rotation about the dn axis: Ω_mid ≡ 0
        w1 = jnp.where(still, jnp.ones_like(w1), w1)
        s0 = w2 * _sign(p.lam_p)
        r12 = jnp.sqrt(p.b * I2 / I1)
        phi = jnp.arctan2(jnp.abs(s0) * r12, -_sign(s0) * w1)
        lam = jnp.abs(p.lam_p)
        t_per = jnp.where(s0 == 0, 2 * p.K, _ellipf(phi, p.m, p.m1)) / lam
        t_per = jnp.where(still, jnp.inf, t_per)
        lam_s = jnp.where(p.lam_s == 0, 1.0, p.lam_s)
        u0 = jnp.where(jnp.isfinite(p.u0), p.u0, _sign(lam_s))  # ±∞: no crossing ahead
        t_sep = -u0 / lam_s
        t_sep = jnp.where((t_sep > 0) & (p.lam_s != 0), t_sep, jnp.inf)
        return jnp.where(p.trivial, jnp.inf, jnp.where(p.sep, t_sep, t_per))

    return jax.jit(jnp.vectorize(one, signature="(3),(3)->()"))(inertia, omega0)


# Composite Gauss–Legendre rule on [0, 1]: _GL_PANELS panels of _GL_NODES nodes. The precession
# rate is analytic in a strip of half-width ~1/|λ| around the real t axis and is integrated over at
# most one period 2K/|λ| (K ≤ ~20 in float64 off the separatrix); panels of ≤ 2.5/|λ| with 16
# nodes give ≲1e-12 relative error (measured: 1e-13 at the Principia case k² = 0.99996).
_GL_PANELS = 16
_GL_NODES = 16


def _gauss_legendre(dtype) -> tuple[Array, Array]:
    x, wts = np.polynomial.legendre.leggauss(_GL_NODES)
    x, wts = 0.5 * (x + 1), 0.5 * wts
    left = np.arange(_GL_PANELS)[:, None] / _GL_PANELS
    nodes = (left + x[None, :] / _GL_PANELS).reshape(-1)
    weights = np.tile(wts / _GL_PANELS, _GL_PANELS)
    return jnp.asarray(nodes, dtype), jnp.asarray(weights, dtype)


def _precession_rate(Ip: Array, Om: Array, M: Array) -> Array:
    """ψ̇ = M (2E − I1 Ω1²)/(M² − I1² Ω1²) with axis 1 (index 0 of the permuted axes) the reference
    body axis, written as `M (I2Ω2² + I3Ω3²)/(I2²Ω2² + I3²Ω3²)` (no cancellation)."""
    o2, o3 = Om[..., 1] ** 2, Om[..., 2] ** 2
    return M * (Ip[1] * o2 + Ip[2] * o3) / (Ip[1] ** 2 * o2 + Ip[2] ** 2 * o3)


# Quaternions of the cyclic relabellings C_j = [e_{j+1}, e_{j+2}, e_j] (columns): C_j maps the
# standard z axis to body axis j (C_2 = E; C_0, C_1: ±120° about (1, 1, 1)).
_Q_CYCLIC = ((0.5, 0.5, 0.5, 0.5), (0.5, -0.5, -0.5, -0.5), (1.0, 0.0, 0.0, 0.0))


def _euler_zxz_quat(psi: Array, n: Array) -> Array:
    """Quaternion of `Rz(ψ) Rx(θ) Rz(φ)` with θ, φ the polar angles of the unit vector
    `n = (sin θ sin φ, sin θ cos φ, cos θ)` (THEORY.md §3 Euler-angle formula:
    `λ0 = cos(θ/2) cos((ψ+φ)/2)`, `λ1 = sin(θ/2) cos((ψ−φ)/2)`, `λ2 = sin(θ/2) sin((ψ−φ)/2)`,
    `λ3 = cos(θ/2) sin((ψ+φ)/2)`)."""
    half_t = 0.5 * jnp.arctan2(jnp.sqrt(n[..., 0] ** 2 + n[..., 1] ** 2), n[..., 2])
    phi = jnp.arctan2(n[..., 0], n[..., 1])
    ct, st = jnp.cos(half_t), jnp.sin(half_t)
    sp, dp = 0.5 * (psi + phi), 0.5 * (psi - phi)
    return jnp.stack([ct * jnp.cos(sp), st * jnp.cos(dp), st * jnp.sin(dp), ct * jnp.sin(sp)], -1)


def _psi_periodic(p: _Plan, t: Array) -> tuple[Array, Array]:
    """Precession angle ψ(t) = ∫₀ᵗ ψ̇ in the periodic branch: whole periods T_ψ = 2K/|λ| of the
    rate (which has that period) times their integral, plus a composite Gauss–Legendre integral
    over the remainder τ ∈ [0, T_ψ). `t` (T,); also returns `_omega_periodic(p, t)` (T, 3),
    evaluated in the same call as the quadrature nodes."""
    x, wq = _gauss_legendre(t.dtype)
    Tpsi = 2 * p.K / jnp.abs(p.lam_p)
    n = jnp.floor(t / Tpsi)
    tau = t - n * Tpsi
    spans = jnp.concatenate([tau, Tpsi[None]])  # (T + 1,)
    T = t.shape[0]
    om = _omega_periodic(p, jnp.concatenate([t, (spans[:, None] * x).reshape(-1)]))
    rate = _precession_rate(p.Ip, om[T:].reshape(T + 1, x.shape[0], 3), p.M)
    integrals = spans * jnp.sum(wq * rate, axis=-1)
    return n * integrals[-1] + integrals[:-1], om[:T]


def _psi_sep(p: _Plan, t: Array) -> Array:
    """ψ(t) on the separatrix in closed form. With w = tanh u = Ω2/A2 the rate is
    `ψ̇ = 2E/M − ((M² − 2E I1)/(I1 M)) / (1 + ν² w²)`, `ν² = I1 P1/(I3 P3)`, and
    `∫ du/(1 + ν² tanh² u) = (u + ν atan(ν tanh u))/(1 + ν²)`, so
    `ψ = (2E/M) t − sign(λ(I3 − I1)) (I2 A2/M) [atan(ν tanh u) − atan(ν tanh u0)]`."""
    J1, J2, J3 = p.Is
    ok = p.P3s > 0  # P3 = 0 only for steady rotation (then λ = 0 and the bracket vanishes)
    nu = jnp.sqrt(J1 * p.P1s / (J3 * jnp.where(ok, p.P3s, jnp.ones_like(p.P3s))))
    u = p.u0 + p.lam_s * t
    bracket = jnp.arctan(nu * jnp.tanh(u)) - jnp.arctan(nu * jnp.tanh(p.u0))
    sgn = _sign(p.lam_s) * _sign(J3 - J1)
    corr = jnp.where(ok, sgn * J2 * p.A[1] / p.M * bracket, jnp.zeros_like(bracket))
    return p.two_e / p.M * t - corr


def _attitude(p: _Plan, q0: Array, t: Array) -> Array:
    """`P(t) = P0 C B(0)ᵀ R_z(ψ(t)) B(t) Cᵀ`-type construction of `free_rigid_body_attitude`:
    with `n_c` = n in the relabelled axes (reference axis e last) and (θ, φ) its polar angles,
    `q(t) = q0 ∘ q_C ∘ q_E(0, θ0, φ0)⁻¹ ∘ q_E(ψ(t), θ(t), φ(t)) ∘ q_C⁻¹` (q_E: ZXZ Euler angles)."""
    psi_p, om_p = _psi_periodic(p, t)
    # Ω of the (possibly dummy, never zero) non-trivial branches, so that the angles stay regular
    om = jnp.where(p.sep, _unpermute(_omega_sep(p, t), p.ps), _unpermute(om_p, p.pp))  # (T, 3)
    j = jnp.where(p.sep, p.ps[0], p.pp[0])  # reference body axis e
    cyc = (j + jnp.arange(1, 4)) % 3  # (j+1, j+2, j)
    n = jnp.take(p.I * om / p.M, cyc, axis=-1)
    n0 = jnp.take(p.I * p.w / p.M, cyc, axis=-1)
    qc = jnp.asarray(_Q_CYCLIC, t.dtype)[j]
    psi = jnp.where(p.sep, _psi_sep(p, t), psi_p)
    qe = _euler_zxz_quat(psi, n)
    qe0 = _euler_zxz_quat(jnp.zeros((), t.dtype), n0)
    left = quat.mul(quat.mul(q0, qc), quat.conj(qe0))
    q = quat.mul(quat.mul(left, qe), quat.conj(qc))
    q_triv = quat.mul(q0, quat.from_rotvec(t[:, None] * p.w_orig))
    return quat.canonical(jnp.where(p.trivial, q_triv, q))


def free_rigid_body_attitude(
    inertia: ArrayLike,
    omega0: ArrayLike,
    q0: ArrayLike | None,
    ts: ArrayLike,
    t0: ArrayLike = 0.0,
) -> Float[Array, "... T 4"]:
    """Attitude quaternions `(..., T, 4)` (scalar-first, λ0 ≥ 0, P maps body → space) of the
    torque-free rigid body with principal moments `inertia`, body angular velocity `omega0` and
    attitude `q0` (identity if None) at time `t0`.

    Construction (derived here; cf. Landau–Lifshitz §37). M is fixed in space. Take a body axis e
    that the body momentum direction n(t) = IΩ/|M| never reaches: the "cn axis" of
    `free_rigid_body` (the smallest axis when the motion goes around the largest one and vice
    versa). Let B(t) be a rotation with B n = e_z that depends on n(t) alone: with e as the z
    axis, `B = R_x(θ) R_z(φ)` for the polar angles (θ, φ) of n about e (θ ∈ (0, π) strictly,
    since n never reaches ±e). Then `P(t) = G R_z(ψ(t)) B(t)` with G constant maps n to the fixed
    direction of M — ZXZ Euler angles (ψ, θ, φ) with space Z along M — and `Ṗ = P (Ω × E)` iff
        `ψ̇ = (Ω·n − (Ω·e)(n·e))/(1 − (n·e)²) = |M| (2E − I_e Ω_e²)/(M² − I_e² Ω_e²)`
    (Landau–Lifshitz (37.15) for e = axis 3). ψ̇ > 0 and, with period 2K/|λ|, ψ is whole periods
    of it plus a composite Gauss–Legendre integral (16 panels × 16 nodes) over the remainder —
    accurate to ~1e-12 relative (the alternative is the incomplete elliptic integral of the third
    kind). On the separatrix the integral is elementary (see `_psi_sep`). Finally `G = P0 B(0)ᵀ`.
    Cost: 256 Ω evaluations per output time.
    """
    inertia, omega0, ts = _body_inputs(inertia, omega0, ts)
    dtype = ts.dtype
    q0 = quat.identity(dtype=dtype) if q0 is None else vector(q0, 4, "q0").astype(dtype)
    q0 = quat.normalize(q0)
    t0 = as_float(t0, "t0").astype(dtype)
    scalar = ts.ndim == 0
    ts1 = jnp.atleast_1d(ts)

    out = _attitude_jit(inertia, omega0, q0, ts1, t0)
    return out[..., 0, :] if scalar else out


@jax.jit
def _attitude_jit(inertia, omega0, q0, ts, t0):
    def one(I, w, q, t):
        return _attitude(_plan(I, w), q, t - t0)

    return jnp.vectorize(one, signature="(3),(3),(4),(t)->(t,4)")(inertia, omega0, q0, ts)


# ----------------------------------------------------------------------------------------------
# Free symmetric top (Zegrya–Parshin 004 (12.7)–(12.8), (12.34)–(12.39); THEORY.md §6)
# ----------------------------------------------------------------------------------------------


class SymmetricTopPrecession(NamedTuple):
    """Regular precession of a free symmetric top (see `symmetric_top_precession`)."""

    precession_rate: Array  # |M|/I1: rate of the symmetry axis (and of P) about the fixed M
    spin: Array  # Ω3, constant component of Ω along the symmetry axis, = (|M|/I3) cos θ
    body_rate: Array  # ω = Ω3 (I3 − I1)/I1: rate of (Ω1, Ω2) about the symmetry axis in the body
    nutation: Array  # θ ∈ [0, π]: constant angle between the symmetry axis and M


def _top_inputs(I1, I3, omega0, *more):
    names = ("I1", "I3", "omega0", "ts", "q0")[: 3 + len(more)]
    out = _floats(I1, I3, omega0, *more, names=names)
    vector(out[2], 3, "omega0")
    return out


@jax.jit
def symmetric_top_precession(
    I1: ArrayLike, I3: ArrayLike, omega0: ArrayLike
) -> SymmetricTopPrecession:
    """Regular precession of the free symmetric top `I1 = I2 ≠ I3` (symmetry axis = body z):
    precession rate `|M|/I1`, spin `Ω3 = (|M|/I3) cos θ`, body rate `ω = Ω3 (I3 − I1)/I1` and the
    nutation angle θ between the symmetry axis and M, `tan θ = I1 |Ω⊥| / (I3 Ω3)` (Zegrya–Parshin
    004 (12.34)–(12.39)). Batch dims of the arguments broadcast."""
    I1, I3, omega0 = _top_inputs(I1, I3, omega0)
    perp = _safe_sqrt(omega0[..., 0] ** 2 + omega0[..., 1] ** 2)
    w3 = omega0[..., 2]
    M = _safe_sqrt(I1**2 * (omega0[..., 0] ** 2 + omega0[..., 1] ** 2) + I3**2 * w3**2)
    return SymmetricTopPrecession(
        precession_rate=M / I1,
        spin=w3,
        body_rate=w3 * (I3 - I1) / I1,
        nutation=jnp.arctan2(I1 * perp, I3 * w3),
    )


@jax.jit
def symmetric_top(
    I1: ArrayLike, I3: ArrayLike, omega0: ArrayLike, ts: ArrayLike, t0: ArrayLike = 0.0
) -> Float[Array, "... T 3"]:
    """Body angular velocity `(..., T, 3)` of the free symmetric top `I1 = I2`, `I3` (symmetry
    axis = body z): `Ω3 = const`, `Ω1 + iΩ2 = (Ω1(t0) + iΩ2(t0)) e^{iω(t − t0)}`,
    `ω = Ω3 (I3 − I1)/I1` (from `I1 Ω̇1 = (I1 − I3) Ω2 Ω3`, `I1 Ω̇2 = (I3 − I1) Ω3 Ω1`; the sign
    agrees with `simulate`). `ts` (T,)."""
    I1, I3, omega0, ts = _top_inputs(I1, I3, omega0, ts)
    t = jnp.atleast_1d(ts) - as_float(t0, "t0").astype(ts.dtype)
    om = (omega0[..., 2] * (I3 - I1) / I1)[..., None] * t  # (..., T)
    c, s = jnp.cos(om), jnp.sin(om)
    w1, w2, w3 = (omega0[..., i : i + 1] for i in range(3))
    out = jnp.stack([w1 * c - w2 * s, w1 * s + w2 * c, jnp.broadcast_to(w3, c.shape)], axis=-1)
    return out[..., 0, :] if ts.ndim == 0 else out


@jax.jit
def symmetric_top_attitude(
    I1: ArrayLike,
    I3: ArrayLike,
    omega0: ArrayLike,
    q0: ArrayLike | None,
    ts: ArrayLike,
    t0: ArrayLike = 0.0,
) -> Float[Array, "... T 4"]:
    """Attitude `(..., T, 4)` of the free symmetric top (symmetry axis = body z): regular
    precession about the fixed angular momentum,
        `P(t) = R(M̂, (|M|/I1)(t − t0)) P0 R(e_z, −ω(t − t0))`,
    i.e. `q(t) = q(M_space (t − t0)/I1) ∘ q0 ∘ q(−ω (t − t0) e_z)` with `M_space = P0 I Ω0`.
    Check: the body angular velocity of this P is `(|M|/I1) n(t) − ω e_z` with `n = IΩ/|M|`
    rotating about e_z at the rate ω, which equals Ω(t) (`symmetric_top`). λ0 ≥ 0."""
    I1, I3, omega0, ts = _top_inputs(I1, I3, omega0, ts)
    dtype = ts.dtype
    q0 = quat.identity(dtype=dtype) if q0 is None else vector(q0, 4, "q0").astype(dtype)
    q0 = quat.normalize(q0)
    t = (jnp.atleast_1d(ts) - as_float(t0, "t0").astype(dtype))[:, None]
    Ivec = jnp.stack(jnp.broadcast_arrays(I1, I1, I3), axis=-1)
    Ms = quat.rotate(q0, Ivec * omega0)
    om = omega0[..., 2] * (I3 - I1) / I1
    ez = jnp.asarray((0.0, 0.0, 1.0), dtype)
    qs = quat.from_rotvec((Ms / I1[..., None])[..., None, :] * t)
    qb = quat.from_rotvec(-(om[..., None, None] * t) * ez)
    out = quat.canonical(quat.mul(quat.mul(qs, q0[..., None, :]), qb))
    return out[..., 0, :] if ts.ndim == 0 else out


def fixed_axis_rotation(
    axis: ArrayLike,
    angle: ArrayLike | Callable[[Array], Array],
    ts: ArrayLike,
    q0: ArrayLike | None = None,
) -> Float[Array, "... T 4"]:
    """Rotation about a space-fixed axis (Zhilin 3.13): `ω = θ̇(t) n`, `P(t) = exp(θ(t) n × E) P0`
    with `θ(t) = ∫₀ᵗ ω`. `angle`: a callable `θ(t)` (vectorised over `ts`, θ(0) = 0 expected) or a
    constant rate ω (then θ = ω t). `axis` `(..., 3)` is normalised. Returns quaternions
    `(..., T, 4)`, λ0 ≥ 0; the body angular velocity is `Ω = θ̇ P(t)ᵀ n`."""
    axis = vector(axis, 3, "axis")
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
