"""The free rigid body at a rest point of Euler's equations, where Ω stays Ω0 but its
derivatives in Ω0 and the moments do not: the sphere, Ω0 = 0, and the steady rotations on the
separatrix (about the middle axis, in the plane of a symmetric top's equal moments), which the
elliptic branches of `rigidjax.analytic.euler_poinsot` give as constants. Value exact, first
derivatives those of the motion (its linearisation), at a sphere also the second (THEORY §6;
the docs' theory page, "Exact and structure-preserving solvers")."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._numerics import guarded, poly
from ..rotations import quat
from ..rotations._series import one_minus_cos_over, theta_minus_sin_over


def euler_rate(I: Array, w: Array) -> Array:
    """Euler's equations `Ω̇ = I⁻¹ (IΩ × Ω)` for principal moments `I (3,)` (THEORY §6), written
    with `(I − I1)Ω × Ω` (the same: Ω × Ω = 0), so that a sphere's rate is exactly zero while its
    derivatives in the moments are not."""
    return jnp.cross((I - I[0]) * w, w) / I


def rest_matrix(I: Array, w: Array, rest: Array) -> Array:
    """`F = ∂f/∂Ω` at `w` (f = `euler_rate`) where `rest`, zero elsewhere (so that the unused
    branch stays finite)."""
    F = jax.jacfwd(euler_rate, argnums=1)(I, w)
    return jnp.where(rest, F, jnp.zeros_like(F))


def rest_time(F: Array, t: Array) -> Array:
    """The times `t` of the linearisation at a rest point (`F`: `rest_matrix`), capped where
    cosh(√s t), s = tr(F²)/2, would come within a factor e^{0.1 √s|t|} of overflowing
    (√s|t| = 639 in float64, 80 in float32): the derivatives there are those at the cap."""
    s = 0.5 * jnp.trace(F @ F)
    cap = 0.9 * math.log(float(jnp.finfo(t.dtype).max))
    big = s * t * t > cap**2
    return jnp.where(big, jnp.sign(t) * cap / jnp.sqrt(jnp.where(big, s, jnp.ones_like(s))), t)


def _cosh_series(x: Array) -> tuple[Array, Array]:
    """`c(x) = Σ xᵏ/(2k + 2)!` and `d(x) = Σ xᵏ/(2k + 3)!`: `(cosh √x − 1)/x` and
    `(sinh √x − √x)/x^{3/2}` for x > 0, their trigonometric continuations `(1 − cos y)/y²` and
    `(y − sin y)/y³`, y² = −x, for x ≤ 0; finite with finite derivatives at 0."""
    pos = x > 0
    xp = jnp.where(pos, x, jnp.zeros_like(x))
    xn = jnp.where(pos, jnp.zeros_like(x), -x)
    c = guarded(
        xp,
        lambda v: 2 * jnp.sinh(jnp.sqrt(v) / 2) ** 2 / v,
        lambda v: poly(v, [1 / 2, 1 / 24, 1 / 720, 1 / 40320, 1 / 3628800]),
    )
    d = guarded(
        xp,
        lambda v: (jnp.sinh(jnp.sqrt(v)) - jnp.sqrt(v)) / (v * jnp.sqrt(v)),
        lambda v: poly(v, [1 / 6, 1 / 120, 1 / 5040, 1 / 362880, 1 / 39916800]),
    )
    return (
        jnp.where(pos, c, one_minus_cos_over(xn)),
        jnp.where(pos, d, theta_minus_sin_over(xn)),
    )


def omega_at_rest(w: Array, f: Array, F: Array, t: Array) -> Array:
    """Ω at times `t` (any shape) from a rest point `w` of Euler's equations (f = `euler_rate`
    there, F = `rest_matrix`), where it is constant: `w + Φ(t) f` (f is zero there, not its
    derivatives) and `Φ(t) = ∫₀ᵗ exp(Fτ) dτ = t E + t² c(st²) F + t³ d(st²) F²`
    (`_cosh_series`), F = ∂f/∂Ω at w, s = tr(F²)/2: at every rest point tr F = 0 and det F = 0
    (it is a multiple of Ω1Ω2Ω3 times the three differences of the moments), so F³ = sF
    (Cayley–Hamilton). The value is w; the first derivatives in the moments and w are those of
    the motion (its linearisation `δΩ̇ = F δΩ + δf`), growing like cosh(√s t) about the middle
    axis (capped before they overflow: `rest_time`); at a sphere (F = 0) also the second
    derivatives (the terms of order tᵏ are products of k factors that vanish there)."""
    t = rest_time(F, t)
    c, d = _cosh_series(0.5 * jnp.trace(F @ F) * t * t)
    ff = F @ f
    t, c, d = t[..., None], c[..., None], d[..., None]
    return w + t * f + t * t * c * ff + t**3 * d * (F @ ff)


def attitude_at_rest(w: Array, f: Array, F: Array, rest: Array, q0: Array, t: Array) -> Array:
    """q at times `t (T,)` from a rest point `w` of Euler's equations (used where `rest`; f, F
    and Ω as in `omega_at_rest`): `q0 ∘ exp(tw) ∘ exp(ξ(t))`, ξ the rotation that the drift
    `δΩ = Ω − w` adds, `ξ̇ = δΩ − w × ξ` to first order (`_drift`). The value is `q0 ∘ exp(tw)`
    (ξ = 0), the first derivatives in the moments and w those of the motion (capped as
    `rest_time`)."""
    xi = _drift(F, jnp.where(rest, w, jnp.zeros_like(w)), f, rest_time(F, t))
    spin = quat.mul(q0, quat._from_rotvec(t[:, None] * w))
    return quat.mul(spin, quat._from_rotvec(xi))


@jax.custom_jvp
def _drift(F: Array, w: Array, f: Array, t: Array) -> Array:
    """The rotation vectors `ξ(t) (T, 3)` that the drift of Ω away from a rest point w adds to
    the attitude, to first order in `f = f(w) = 0`: `ż = A z + (f, 0)`, z = (δΩ, ξ), z(0) = 0,
    `A = [[F, 0], [E, −[w×]]]` (`δΩ̇ = F δΩ + f`, `ξ̇ = δΩ − w × ξ`), so `ξ(t) = G(t) f` with
    G the (ξ, f) block of `exp([[A, (E, 0)], [0, 0]] t)` (9 × 9; Van Loan 1978, IEEE Trans.
    Automat. Control 23(3), "Computing integrals involving the matrix exponential"). Its value
    is 0 (the exponential is taken only for derivatives: `dξ = G df`), written as 0 times the
    inputs so that it carries their batch axes under `vmap` (a constant does not, and the
    linearisation of the rule then fails where the inputs are batched along different axes)."""
    return 0 * (t[:, None] * (f + w + F[0]))


@_drift.defjvp
def _drift_jvp(primals, tangents):
    F, w, f, t = primals
    eye, zero = jnp.eye(3, dtype=f.dtype), jnp.zeros((3, 3), f.dtype)
    wx = jnp.cross(w, -eye)  # columns w × e_j: the matrix of w × (·)
    a = jnp.block([[F, zero, eye], [eye, -wx, zero], [zero, zero, zero]])
    g = jax.scipy.linalg.expm(t[:, None, None] * a)[:, 3:6, 6:9]
    return _drift(F, w, f, t), g @ tangents[2]
