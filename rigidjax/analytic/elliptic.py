"""Jacobi elliptic functions and complete/incomplete elliptic integrals in pure JAX.

`sn`, `cn`, `dn`, `am` (`ellipj`), `K` (`ellipk`, `ellipkm1`) and `F` (`ellipkinc`), with SciPy's
parameter convention `m = k²`. Usable on their own: `jit`, `vmap`, `grad` work, float32 and float64
keep their dtype, leading batch dimensions broadcast, loops have a fixed number of steps.

Sources: Abramowitz & Stegun (A&S) 16.4 (arithmetic–geometric mean, Landen), 16.8 (quarter
periods), 16.17 (addition theorems), 16.22 (Maclaurin series), 17.6 (AGM for K and F); Fukushima
2009 (duplication without cancellation); THEORY §6.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, floats
from .._custom_types import Scalar, ScalarLike

__all__ = ["am", "cn", "dn", "ellipj", "ellipk", "ellipkinc", "ellipkm1", "ellippi", "sn"]

# Arithmetic–geometric mean steps. From b0 = √(1 − m) the ratio b/a first grows like 2√(b/a) per
# step, then c/a falls quadratically: 14 steps reach c/a < 1e-20 for any 1 − m ≥ 1e-300 (13 are
# needed at 1e-300, 9 at 1e-16). Extra steps are exact no-ops (c = 0): one count for all dtypes.
_AGM_STEPS = 14


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


# Doublings of `_ellipj_reduced`: an argument |w| ≤ K/2 ≤ 174 (1 − m ≥ 1e-300) is halved 18 times
# to |h| ≤ 7e-4, where three Maclaurin terms of sn and of 1 − cn are exact to rounding (the next
# terms are h⁶ ≤ 1e-19 of the first).
_DOUBLINGS = 18


def _ellipj_doubling(w: Array, m: Array, m1: Array) -> tuple[Array, Array, Array]:
    """`(sn, cn, dn)(w|m)` for |w| ≤ K/2, each to a few ulps RELATIVE to itself, by duplication
    from `h = w/2^N` (Maclaurin series, A&S 16.22) with the duplication formulas written without
    cancellation (cf. Fukushima 2009, Celest. Mech. Dyn. Astr. 105, "conditional duplication"):
    `sn 2u = 2 s c d/Δ`, `1 − cn 2u = 2 s² d²/Δ` while `1 − cn < ½`, then
    `cn 2u = (m c⁴ + 2 m1 c² − m1)/(m1 + m c² (2 − c²))`, with `d² = m1 + m c²` and
    `Δ = 1 − m s⁴ = d² + m s² c²` (sums of non-negative terms; `cn 2u` has no cancellation for
    |2u| ≤ K/2, where `m c⁴ ≥ √m1·O(1) ≫ m1`)."""
    h = w / 2.0**_DOUBLINGS
    h2 = h * h
    s = h * (1 - h2 * ((1 + m) / 6 - h2 * (1 + m * (14 + m)) / 120))
    x = h2 * (0.5 - h2 * ((1 + 4 * m) / 24 - h2 * (1 + m * (44 + 16 * m)) / 720))

    def step(sxc, _):
        s, x, c = sxc
        c2 = c * c
        d2 = m1 + m * c2
        s2 = s * s
        den = d2 + m * s2 * c2
        x2 = 2 * s2 * d2 / den
        c_2 = (m * c2 * c2 + 2 * m1 * c2 - m1) / (m1 + m * c2 * (2 - c2))
        small = x < 0.5
        s_2 = 2 * s * c * jnp.sqrt(d2) / den
        return (s_2, jnp.where(small, x2, 1 - c_2), jnp.where(small, 1 - x2, c_2)), None

    (s, _, c), _ = jax.lax.scan(step, (s, x, 1 - x), None, length=_DOUBLINGS)
    return s, c, jnp.sqrt(m1 + m * c * c)


def _ellipj_reduced(
    u: Array, m: Array, m1: Array, K: Array | None = None
) -> tuple[Array, Array, Array, Array]:
    """`(j, s, c, d)` with `u = 2jK + r`, |r| ≤ K, `(s, c, d) = (sn, cn, dn)(r|m)` (c ≥ 0), so
    that `am u = jπ + atan2(s, c)`, `sn u = (−1)ʲ s`, `cn u = (−1)ʲ c`, `dn u = d`, for 0 ≤ m < 1.
    s and d are accurate to a few ulps relative and c to a few ulps of d (errors growing like
    `eps·|u|` from the reduction): the accuracy that `Π(n; am u|m)` needs close to m = 1, where
    `dΠ/dφ ~ 1/dn` is large near `r = ±K` (an amplitude accurate only to ulps of π, as from the
    descending Landen algorithm, costs a factor `1/√m1` there). For |r| ≤ K/2 the duplication of
    `_ellipj_doubling`; beyond it the reflection `sn(K − v) = cd v`, `cn(K − v) = √m1 sd v`,
    `dn(K − v) = √m1 nd v` (A&S 16.8) with `v = K − |r|` ∈ [0, K/2]. `K`: K(m) if known."""
    K = _ellipk(m, m1) if K is None else K
    j = jnp.round(u / (2 * K))
    r = u - 2 * j * K
    near = jnp.abs(r) <= 0.5 * K
    s, c, d = _ellipj_doubling(jnp.where(near, r, K - jnp.abs(r)), m, m1)
    k1 = jnp.sqrt(m1)
    cr = jnp.where(near, c, k1 * s / d)
    # sn(K − v) = cd v, as √(1 − cn²(K − v)): the same value (cn ≤ cn(K/2) ≈ m1^¼ there), and
    # derivatives without the cancellation of (c/d)' = −s (d² − m c²)/d², d² − m c² = m1
    far = jnp.sign(r) * jnp.sqrt(jnp.where(near, 0.5, (1 - cr) * (1 + cr)))
    return j, jnp.where(near, s, far), cr, jnp.where(near, d, k1 / d)


def _ellipj(u: Array, m: Array, m1: Array) -> tuple[Array, Array, Array, Array]:
    """sn, cn, dn, am for 0 ≤ m < 1 from `_ellipj_reduced`. `m1 = 1 − m` is passed separately so
    that it can be given more accurately than `1 − m` (near the separatrix of the rigid body)."""
    j, s, c, d = _ellipj_reduced(u, m, m1)
    sign = 1 - 2 * jnp.remainder(j, 2)
    return sign * s, sign * c, d, j * math.pi + jnp.arctan2(s, c)


def _ellipk(m: Array, m1: Array) -> Array:
    """`K(m) = π / (2 AGM(1, √(1 − m)))` (A&S 17.6)."""
    As, _ = _agm(m, m1)
    return (0.5 * math.pi) / As[-1]


def _ellipf(phi: Array, m: Array, m1: Array) -> Array:
    """Incomplete integral of the first kind `F(φ|m) = ∫₀^φ dθ/√(1 − m sin²θ)` for any real φ and
    0 ≤ m < 1, by running the descending Landen algorithm of A&S 16.4.3
    (`φ_{n−1} = ½(φ_n + arcsin((c_n/a_n) sin φ_n))`) backwards (ascending Landen):
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
def ellipj(u: ScalarLike, m: ScalarLike) -> tuple[Scalar, Scalar, Scalar, Scalar]:
    """Jacobi elliptic functions `(sn, cn, dn, am)(u|m)`, like `scipy.special.ellipj`.

    Parameter convention of A&S 16.1 (and SciPy): `m = k²`, 0 ≤ m ≤ 1;
    `u = ∫₀^am dθ/√(1 − m sin²θ)`, `sn = sin am`, `cn = cos am`, `dn = √(1 − m sn²)`.
    For m < 1 the reduction to |u| ≤ K/2 by the quarter periods and duplication from a small
    argument (`_ellipj_reduced`: sn, dn and the amplitude's distance from the nearest odd
    multiple of π/2 accurate to a few ulps relative, also as m → 1; errors growing like
    `eps·|u|`); at m = 1
    `sn = tanh u`, `cn = dn = sech u`, `am = gd u = 2 atan(tanh(u/2))`. NaN outside [0, 1].
    Differentiable in u and in m on [0, 1).
    """
    u, m = floats((u, "u"), (m, "m"))
    one, bad, ms, m1 = _split_m(m)
    s, c, d, ph = _ellipj(u, ms, m1)
    th, se = jnp.tanh(u), _sech(u)
    gd = 2 * jnp.arctan(jnp.tanh(0.5 * u))
    nan = jnp.asarray(jnp.nan, s.dtype)

    def pick(x: Array, x1: Array) -> Array:
        return jnp.where(bad, nan, jnp.where(one, x1, x))

    return pick(s, th), pick(c, se), pick(d, se), pick(ph, gd)


def sn(u: ScalarLike, m: ScalarLike) -> Scalar:
    """Jacobi `sn(u|m)` (see `ellipj`)."""
    return ellipj(u, m)[0]


def cn(u: ScalarLike, m: ScalarLike) -> Scalar:
    """Jacobi `cn(u|m)` (see `ellipj`)."""
    return ellipj(u, m)[1]


def dn(u: ScalarLike, m: ScalarLike) -> Scalar:
    """Jacobi `dn(u|m)` (see `ellipj`)."""
    return ellipj(u, m)[2]


def am(u: ScalarLike, m: ScalarLike) -> Scalar:
    """Jacobi amplitude `am(u|m)`, the inverse of `ellipkinc` in φ (see `ellipj`)."""
    return ellipj(u, m)[3]


@jax.jit
def ellipk(m: ScalarLike) -> Scalar:
    """Complete elliptic integral of the first kind `K(m) = ∫₀^{π/2} dθ/√(1 − m sin²θ)`
    `= π / (2 AGM(1, √(1 − m)))` (A&S 17.6), like `scipy.special.ellipk`; `K(1) = ∞`, NaN for
    m > 1 or m < 0 (SciPy extends to m < 0; this does not)."""
    m = as_float(m, "m")
    one, bad, ms, m1 = _split_m(m)
    k = _ellipk(ms, m1)
    return jnp.where(bad, jnp.nan, jnp.where(one, jnp.inf, k))


@jax.jit
def ellipkm1(p: ScalarLike) -> Scalar:
    """`K(1 − p)` accurate for small `p` (the complementary parameter), like
    `scipy.special.ellipkm1`: the AGM starts from `√p` directly. `p` in (0, 1]; ∞ at p = 0."""
    p = as_float(p, "p")
    zero = p == 0
    bad = ~((p >= 0) & (p <= 1))
    ps = jnp.where(zero | bad, jnp.asarray(0.5, p.dtype), p)
    k = _ellipk(1 - ps, ps)
    return jnp.where(bad, jnp.nan, jnp.where(zero, jnp.inf, k))


@jax.jit
def ellipkinc(phi: ScalarLike, m: ScalarLike) -> Scalar:
    """Incomplete elliptic integral of the first kind `F(φ|m) = ∫₀^φ dθ/√(1 − m sin²θ)`, like
    `scipy.special.ellipkinc`, for any real φ (`F(φ + π) = F(φ) + 2K`) and 0 ≤ m ≤ 1
    (`F(φ|1) = asinh(tan φ)` for |φ| < π/2, ±∞ beyond). Ascending Landen transformation (the
    inverse of A&S 16.4, see `_ellipf`); the inverse of `am`."""
    phi, m = floats((phi, "phi"), (m, "m"))
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
# Carlson's symmetric integrals R_F, R_J and the integral of the third kind Π
# ----------------------------------------------------------------------------------------------

# Duplication steps (Carlson 1995, §2): after M steps the arguments agree to a relative spread
# 4^−M · (A0 − x)/A_M, and the fifth-order series then errs by about that spread to the sixth
# power. A_M ≥ ~1/R_F², and R_F ≤ ~K(m) ≤ 370 for 1 − m ≥ 1e-300, so 18 steps leave a spread
# below 1e-4 (series error < 1e-24) for every argument the free rigid body produces. Extra steps
# are harmless; a fixed count keeps `jit`/`grad` simple.
_CARLSON_STEPS = 18


def _rc1(e: Array) -> Array:
    """`R_C(1, 1 + e) = atan(√e)/√e` for e ≥ 0 (DLMF 19.2.19), by its series
    `Σ (−e)^k/(2k + 1)` for e < 1e-3 (DLMF 19.6.15); finite gradients at 0."""
    small = e < 1e-3
    r = jnp.sqrt(jnp.where(small, jnp.ones_like(e), e))
    series = 1 + e * (-1 / 3 + e * (1 / 5 + e * (-1 / 7 + e * (1 / 9 + e * (-1 / 11)))))
    return jnp.where(small, series, jnp.arctan(r) / r)


def _carlson_fj(sx: Array, sy: Array, sz: Array, sp: Array) -> tuple[Array, Array]:
    """`(R_F(x, y, z), R_J(x, y, z, p))` from the square roots `√x, √y, √z, √p` (x, y, z ≥ 0, at
    most one of them 0, and p ≥ max(x, y, z): then every R_C term has e ≥ 0), by Carlson's
    duplication algorithm (Carlson 1995, Numer. Algorithms 10, algorithms for R_F and R_J; DLMF
    19.36.i). The square roots are taken as inputs so that an
    argument 0 (x = cos²φ at φ = π/2) has finite derivatives; after the first step every argument
    is positive."""
    sx, sy, sz, sp = jnp.broadcast_arrays(sx, sy, sz, sp)
    x, y, z, p = sx * sx, sy * sy, sz * sz, sp * sp
    a_f = (x + y + z) / 3
    a_j = (x + y + z + 2 * p) / 5
    delta = (p - x) * (p - y) * (p - z)

    def step(carry, m):
        sx, sy, sz, sp, x, y, z, p, af, aj, acc = carry
        lam = sx * sy + sx * sz + sy * sz
        d = (sp + sx) * (sp + sy) * (sp + sz)
        four_m = 4.0**-m
        e = four_m**3 * delta / (d * d)
        acc = acc + four_m * _rc1(e) / d
        x, y, z, p = (x + lam) / 4, (y + lam) / 4, (z + lam) / 4, (p + lam) / 4
        af, aj = (af + lam) / 4, (aj + lam) / 4
        return (jnp.sqrt(x), jnp.sqrt(y), jnp.sqrt(z), jnp.sqrt(p), x, y, z, p, af, aj, acc), None

    init = (sx, sy, sz, sp, x, y, z, p, a_f, a_j, jnp.zeros_like(x))
    steps = jnp.arange(_CARLSON_STEPS, dtype=x.dtype)
    (*_, af, aj, acc), _ = jax.lax.scan(step, init, steps)
    scale = 4.0**-_CARLSON_STEPS
    # R_F: Carlson 1995 (2.2)-(2.3)
    X, Y = scale * (a_f - x) / af, scale * (a_f - y) / af
    Z = -X - Y
    e2, e3 = X * Y - Z * Z, X * Y * Z
    rf = (1 - e2 / 10 + e3 / 14 + e2 * e2 / 24 - 3 * e2 * e3 / 44) / jnp.sqrt(af)
    # R_J: Carlson 1995 (2.19)-(2.21)
    X, Y, Z = (scale * (a_j - v) / aj for v in (x, y, z))
    P = -(X + Y + Z) / 2
    e2 = X * Y + X * Z + Y * Z - 3 * P * P
    e3 = X * Y * Z + 2 * e2 * P + 4 * P**3
    e4 = (2 * X * Y * Z + e2 * P + 3 * P**3) * P
    e5 = X * Y * Z * P * P
    series = (
        1 - 3 * e2 / 14 + e3 / 6 + 9 * e2 * e2 / 88 - 3 * e4 / 22 - 9 * e2 * e3 / 52 + 3 * e5 / 26
    )
    rj = scale * series / (aj * jnp.sqrt(aj)) + 6 * acc
    return rf, rj


def _f_pi(n: Array, s: Array, c: Array, m: Array, m1: Array) -> tuple[Array, Array, Array]:
    """`(F(φ|m), Π(n; φ|m), F − Π)` for |φ| ≤ π/2 given by `s = sin φ` and `c = cos φ ≥ 0`,
    n ≤ 0, 0 ≤ m < 1: `F = s R_F(c², Δ², 1)`, `Δ² = 1 − m s² = m1 + m c²` (DLMF 19.25.5), and for
    n ≥ −1 `F − Π = −(n/3) s³ R_J(c², Δ², 1, 1 − n s²)` (DLMF 19.25.14), so that both Π and
    F − Π keep their digits. For n < −1 the sum `F + (n/3) s³ R_J` cancels (Π ~ F/√(1 − n s²):
    all digits lost at n ~ −1/eps), so there Π comes from the characteristic ω² = m/n ∈ (−1, 0]
    (DLMF 19.7.8, `Π(n) + Π(ω²) = F + √c' R_C(…)`, whose R_C term is elementary here: its
    arguments differ by `s² (1 − n)(1 − ω²)`):
        `Π = −(ω²/3) s³ R_J(c², Δ², 1, 1 − ω² s²) + atan2(g s, c Δ)/g`,  `g² = (1 − n)(1 − ω²)`,
    two positive terms. Taking s and c (not φ) keeps Π accurate where Δ is tiny (φ near ±π/2,
    m near 1) if c is accurate there."""
    big = n < -1
    ns = jnp.where(big, n, -2 * jnp.ones_like(n))
    w2 = jnp.where(big, m / ns, n)  # the characteristic that R_J sees
    delta = jnp.sqrt(m1 + m * c * c)
    rf, rj = _carlson_fj(c, delta, jnp.ones_like(c), jnp.sqrt(1 - w2 * s * s))
    f = s * rf
    g = jnp.sqrt((1 - ns) * (1 - m / ns))
    far = -(w2 / 3) * s**3 * rj + jnp.arctan2(g * s, c * delta) / g
    near = -(n / 3) * s**3 * rj  # F − Π
    return f, jnp.where(big, far, f - near), jnp.where(big, f - far, near)


@jax.jit
def ellippi(n: ScalarLike, phi: ScalarLike, m: ScalarLike) -> Scalar:
    """Incomplete elliptic integral of the third kind
    `Π(n; φ|m) = ∫₀^φ dθ / ((1 − n sin²θ) √(1 − m sin²θ))` for any real φ, n ≤ 0 (the
    characteristic of the free rigid body's precession angle) and 0 ≤ m < 1 (A&S 17.2.14–15
    convention: characteristic n, parameter m; DLMF's Π(φ, α², k) with α² = n, k² = m), by
    Carlson's R_F and R_J (`_f_pi`) and `Π(n; jπ + φ) = Π(n; φ) + 2jΠ(n|m)` (DLMF 19.25.2 for
    the complete integral). NaN outside that range. Differentiable in n, φ and m."""
    n, phi, m = floats((n, "n"), (phi, "phi"), (m, "m"))
    n, phi, m = jnp.broadcast_arrays(n, phi, m)
    bad = ~((m >= 0) & (m < 1) & (n <= 0))
    ms = jnp.where(bad, jnp.zeros_like(m), m)
    ns = jnp.where(bad, jnp.zeros_like(n), n)
    j = jnp.round(phi / math.pi)
    phr = phi - j * math.pi
    # (φ reduced, complete) stacked on a leading axis
    s = jnp.stack([jnp.sin(phr), jnp.ones_like(phr)])
    c = jnp.stack([jnp.abs(jnp.cos(phr)), jnp.zeros_like(phr)])
    pis = _f_pi(ns, s, c, ms, 1 - ms)[1]
    return jnp.where(bad, jnp.nan, 2 * j * pis[1] + pis[0])
