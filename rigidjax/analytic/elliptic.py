"""Jacobi elliptic functions and complete/incomplete elliptic integrals in pure JAX.

`sn`, `cn`, `dn`, `am` (`ellipj`), `K` (`ellipk`, `ellipkm1`) and `F` (`ellipkinc`), with SciPy's
parameter convention `m = k²`. Usable on their own: `jit`, `vmap`, `grad` work, float32 and float64
keep their dtype, leading batch dimensions broadcast, loops have a fixed number of steps.

Sources: Abramowitz & Stegun (A&S) 16.4 (arithmetic–geometric mean, descending Landen), 16.17
(addition theorems), 17.6 (AGM for K and F); THEORY §6.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, floats
from .._custom_types import Scalar, ScalarLike

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
def ellipj(u: ScalarLike, m: ScalarLike) -> tuple[Scalar, Scalar, Scalar, Scalar]:
    """Jacobi elliptic functions `(sn, cn, dn, am)(u|m)`, like `scipy.special.ellipj`.

    Parameter convention of A&S 16.1 (and SciPy): `m = k²`, 0 ≤ m ≤ 1;
    `u = ∫₀^am dθ/√(1 − m sin²θ)`, `sn = sin am`, `cn = cos am`, `dn = √(1 − m sn²)`.
    For m < 1 the descending AGM/Landen algorithm of A&S 16.4 with a fixed number of steps
    (accurate to a few ulps of `m` for any real `u`, error growing like `eps·|u|`); at m = 1
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
