"""The attitude of the free rigid body in closed form (Euler–Poinsot): the quaternion from the
body angular momentum's direction and the precession angle ψ(t) about it, ψ in closed form by the
elliptic integral of the third kind (THEORY §6; Landau & Lifshitz §37; see
`rigidjax.analytic.euler_poinsot` for Ω(t) and its regimes). `free_body_flow` is the exact step
map of (Ω, q) used by `rigidjax.solvers.ExactFreeBody`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import as_float, check_finite, vector
from .._custom_types import Quat, QuatLike, RealScalarLike, TimesLike, Vec3Like
from ..rotations import quat
from ._rest_point import attitude_at_rest
from .elliptic import _ellipj_reduced, _f_pi
from .euler_poinsot import (
    _body_inputs,
    _omega,
    _omega_periodic,
    _omega_sep,
    _Plan,
    _plan,
    _sign,
    _unpermute,
)

__all__ = ["free_body_flow", "free_rigid_body_attitude"]

# Quaternions of the cyclic relabellings C_j = [e_{j+1}, e_{j+2}, e_j] (columns): C_j maps the
# standard z axis to body axis j (C_2 = E; C_0, C_1: ±120° about (1, 1, 1)).
_Q_CYCLIC = ((0.5, 0.5, 0.5, 0.5), (0.5, -0.5, -0.5, -0.5), (1.0, 0.0, 0.0, 0.0))


def _euler_zxz_quat(psi: Array, n: Array, phi: Array | None = None) -> Array:
    """Quaternion of `Rz(ψ) Rx(θ) Rz(φ)` with θ, φ the polar angles of the unit vector
    `n = (sin θ sin φ, sin θ cos φ, cos θ)` (THEORY §3 Euler-angle formula:
    `λ0 = cos(θ/2) cos((ψ+φ)/2)`, `λ1 = sin(θ/2) cos((ψ−φ)/2)`, `λ2 = sin(θ/2) sin((ψ−φ)/2)`,
    `λ3 = cos(θ/2) sin((ψ+φ)/2)`). `phi`: φ itself, on a chosen branch (default `atan2`)."""
    half_t = 0.5 * jnp.arctan2(jnp.sqrt(n[..., 0] ** 2 + n[..., 1] ** 2), n[..., 2])
    phi = jnp.arctan2(n[..., 0], n[..., 1]) if phi is None else phi
    ct, st = jnp.cos(half_t), jnp.sin(half_t)
    sp, dp = 0.5 * (psi + phi), 0.5 * (psi - phi)
    return jnp.stack([ct * jnp.cos(sp), st * jnp.cos(dp), st * jnp.sin(dp), ct * jnp.sin(sp)], -1)


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
    `q(t) = q0 ∘ q_C ∘ q_E(0, θ0, φ0)⁻¹ ∘ q_E(ψ(t), θ(t), φ(t)) ∘ q_C⁻¹` (q_E: ZXZ Euler angles),
    made canonical (λ0 ≥ 0); see `_flow`."""
    return quat.canonical(_flow(p, q0, t)[1])


def _psi_exact(p: _Plan, t: Array) -> tuple[Array, Array]:
    """Precession angle ψ(t) = ∫₀ᵗ ψ̇ in the periodic branch in closed form (exact to rounding).

    With axis 1 the reference ("cn") axis, `ψ̇ = M (2E − I1 Ω1²)/(M² − I1² Ω1²)`; since
    `M² − 2E I1 = (I3 − I1) P3` and `M² − I1² Ω1² = I3 P3 (1 + ν² sn² τ)`, `ν² = I1 P1/(I3 P3)`
    (`Ω1 = A1 cn τ`, `A1² = P1/I1`, `M² − I1² A1² = I3 P3`):
        `ψ̇ = M/I1 − (M (I3 − I1)/(I1 I3)) / (1 + ν² sn² τ)`,  τ = u0 + λt,
    and `∫ du/(1 + ν² sn² u) = Π(−ν²; am u|m)` (A&S 17.2.14, third kind, negative characteristic:
    no singularity), so
        `ψ(t) = (M/I1) t − (M (I3 − I1)/(I1 I3 λ)) [Π(−ν²; am(u0 + λt)|m) − Π(−ν²; am u0|m)]`,
    used for ν² > 1; for ν² ≤ 1 the same with `ΔΠ = λt − Δ(F − Π)`,
        `ψ(t) = (M/I3) t + (M (I3 − I1)/(I1 I3 λ)) Δ(F − Π)`,
    whose two terms never cancel (with I1 ≪ I3, M t/I1 would lose log10(I3/I1) digits), and
    `elliptic._f_pi` keeps the digits of Π for large ν² and of F − Π for small.
    The amplitudes are taken as `jπ + φ` with |φ| ≤ π/2 given by `(sin φ, cos φ)`, both accurate
    also close to the separatrix (m → 1), where `dΠ/dφ ~ 1/dn` is large near φ = ±π/2: at t = 0
    `(sin, cos) ∝ ((A1/A2) Ω2, Ω1)`, `u0 = 2j0 K + F(φ0|m)` by Carlson's R_F (`elliptic._f_pi`,
    which also gives Π), and `am(u0 + λt)` from `elliptic._ellipj_reduced` (quarter periods and
    duplication, cn accurate to ulps of dn). Also returns `_omega_periodic(p, t)` (the Jacobi
    functions of λt are evaluated in the same call). Cf. Celledoni, Fassò, Säfström, Zanna 2008
    (with Principia's corrections, `documentation/Celledoni.tex`): the same third-kind integral."""
    I1, I2, I3 = p.Ip
    w1, w2, _ = p.wp
    P1 = I1 * w1**2 + p.b * I2 * w2**2
    nu2 = I1 * P1 / (I3 * p.P3)
    s0 = jnp.sqrt(p.b * I2 / I1) * w2
    flat = (s0 == 0) & (w1 == 0)  # steady rotation about axis 3: ψ does not depend on am u0
    c0 = jnp.where(flat, jnp.ones_like(w1), w1)
    r0 = jnp.sqrt(s0 * s0 + c0 * c0)
    # am u0 = j0 π + φ0r, |φ0r| ≤ π/2
    back = c0 < 0
    j0 = jnp.where(back, jnp.where(s0 >= 0, 1.0, -1.0), 0.0).astype(t.dtype)
    flip = jnp.where(back, -1.0, 1.0).astype(t.dtype)
    f0, pi0, r0 = _f_pi(
        -nu2,
        jnp.stack([flip * s0 / r0, jnp.ones_like(r0)]),
        jnp.stack([flip * c0 / r0, jnp.zeros_like(r0)]),
        p.m,
        p.m1,
    )
    u0 = 2 * j0 * p.K + f0[0]
    # one call for am(u0 + λt) and for (sn, cn, dn)(λt) of the addition theorems (`_omega`)
    vt = p.lam_p * t
    j, s, c, d = _ellipj_reduced(jnp.stack([u0 + vt, vt]), p.m, p.m1, p.K)
    _, pi1, r1 = _f_pi(-nu2, s[0], c[0], p.m, p.m1)
    coef = p.M * (I3 - I1) / (I1 * I3 * p.lam_p)
    d_pi = 2 * (j[0] - j0) * pi0[1] + pi1 - pi0[0]
    d_r = 2 * (j[0] - j0) * r0[1] + r1 - r0[0]  # ΔF − ΔΠ, with ΔF = λt
    psi = jnp.where(nu2 > 1, p.M / I1 * t - coef * d_pi, p.M / I3 * t + coef * d_r)
    sign = 1 - 2 * jnp.remainder(j[1], 2)
    return psi, _omega_periodic(p, t, (sign * s[1], sign * c[1], d[1]))


def _flow(p: _Plan, q0: Array, t: Array) -> tuple[Array, Array]:
    """The exact Euler–Poinsot flow from `(Ω0, q0)` (Ω0 in the plan) over times `t (T,)`:
    `(Ω(t) (T, 3), q(t) (T, 4))`, q continuous in t with `q(0) = q0` to rounding (not made
    canonical). The attitude construction is that of `free_rigid_body_attitude`, with ψ in closed
    form (`_psi_exact`, `_psi_sep`) and the trivial case (sphere, Ω = 0) `q0 ∘ exp(tΩ0)`."""
    psi_p, om_p = _psi_exact(p, t)
    # Ω of the (possibly dummy, never zero) non-trivial branches, so that the angles stay regular
    om = jnp.where(p.sep, _unpermute(_omega_sep(p, t), p.ps), _unpermute(om_p, p.pp))  # (T, 3)
    j = jnp.where(p.sep, p.ps[0], p.pp[0])  # reference body axis e
    cyc = (j + jnp.arange(1, 4)) % 3  # (j+1, j+2, j)
    n = jnp.take(p.I * om / p.M, cyc, axis=-1)
    n0 = jnp.take(p.I * p.w / p.M, cyc, axis=-1)
    qc = jnp.asarray(_Q_CYCLIC, t.dtype)[j]
    psi = jnp.where(p.sep, _psi_sep(p, t), psi_p)
    # φ on the branch through φ0: n(t) never crosses the plane ⟂ to the "dn" axis, so its
    # polar angle about e stays within π of φ0 (and q stays continuous in t)
    phi0 = jnp.arctan2(n0[0], n0[1])
    d = jnp.arctan2(n[..., 0], n[..., 1]) - phi0
    phi = phi0 + jnp.arctan2(jnp.sin(d), jnp.cos(d))
    qe = _euler_zxz_quat(psi, n, phi)
    qe0 = _euler_zxz_quat(jnp.zeros((), t.dtype), n0, phi0)
    left = quat.mul(quat.mul(q0, qc), quat.conj(qe0))
    q = quat.mul(quat.mul(left, qe), quat.conj(qc))
    return _omega(p, t, om_p), jnp.where(
        p.rest, attitude_at_rest(p.w_orig, p.f, p.F, p.rest, q0, t), q
    )


def free_body_flow(inertia: Array, omega0: Array, q0: Array, h: Array) -> tuple[Array, Array]:
    """One exact step of the torque-free rigid body, for ONE body (use `jnp.vectorize`/`vmap` for
    batches): principal moments `inertia (3,)`, body angular velocity `omega0 (3,)`, unit
    quaternion `q0 (4,)` (P body → space) and a time step `h` (any real, scalar) →
    `(Ω(h) (3,), q(h) (4,))`, exact to rounding in every regime (the Euler–Poinsot solution of
    `free_rigid_body` and the attitude of `free_rigid_body_attitude` with ψ in closed form),
    q continuous in h. No input checks: the building block of `rigidjax.solvers.ExactFreeBody`.
    Derivatives: as `free_rigid_body_attitude`'s."""
    om, q = _flow(_plan(inertia, omega0), q0, jnp.reshape(h, (1,)))
    return om[0], q[0]


def free_rigid_body_attitude(
    inertia: Vec3Like,
    omega0: Vec3Like,
    q0: QuatLike | None,
    ts: TimesLike,
    t0: RealScalarLike = 0.0,
    *,
    check: bool = True,
) -> Float[Array, "*#batch T 4"] | Quat:
    """Attitude quaternions `(..., T, 4)` (scalar-first, λ0 ≥ 0, P maps body → space) of the
    torque-free rigid body with principal moments `inertia`, body angular velocity `omega0` and
    attitude `q0` (identity if None) at time `t0`. Checked as `free_rigid_body` (`check`).

    Construction (derived here; cf. Landau–Lifshitz §37). M is fixed in space. Take a body axis e
    that the body momentum direction n(t) = IΩ/|M| never reaches: the "cn axis" of
    `free_rigid_body` (the smallest axis when the motion goes around the largest one and vice
    versa). Let B(t) be a rotation with B n = e_z that depends on n(t) alone: with e as the z
    axis, `B = R_x(θ) R_z(φ)` for the polar angles (θ, φ) of n about e (θ ∈ (0, π) strictly,
    since n never reaches ±e). Then `P(t) = G R_z(ψ(t)) B(t)` with G constant maps n to the fixed
    direction of M — ZXZ Euler angles (ψ, θ, φ) with space Z along M — and `Ṗ = P (Ω × E)` iff
        `ψ̇ = (Ω·n − (Ω·e)(n·e))/(1 − (n·e)²) = |M| (2E − I_e Ω_e²)/(M² − I_e² Ω_e²)`
    (Landau–Lifshitz (37.15) for e = axis 3). ψ̇ > 0, and ψ is in closed form by the incomplete
    elliptic integral of the third kind with a negative characteristic (`_psi_exact`; Π by
    Carlson's symmetric integrals), exact to rounding, close to the separatrix too (the
    amplitudes are carried with cn accurate to ulps of dn, see `_psi_exact`: ψ 4e-14 off a
    40-digit quadrature for I = (1, 2, 3), Ω0 = (δ, 1, δ) over 4 s, δ = 1e-4 … 1e-14). On the
    separatrix the integral is elementary (see `_psi_sep`). Finally `G = P0 B(0)ᵀ`.

    Derivatives are the motion's, with two limits: on the separatrix itself, away from a rest
    point, only those along it; and close to it the derivatives lose accuracy, as `u0` and
    `am(u0 + λt)` grow sensitive in opposite ways (I = (1, 2, 3), Ω0 = (ε, 1.5, ε), t ≤ 3,
    against Richardson-extrapolated central differences: relative errors 2e-8 at ε = 1e-4,
    6e-7 at 1e-6, 1e-4 at 1e-8, 6e-3 at 1e-10, of order 1 at 1e-12). Close to a sphere
    (moments g apart) the derivatives with respect to the moments lose accuracy as about
    eps/g (I = (1, 1 + g, 1 + 2g): 1e-9 at g = 1e-7, 1e-3 at 1e-13); at a sphere they are exact.
    """
    inertia, omega0, ts = _body_inputs(inertia, omega0, ts, check)
    dtype = ts.dtype
    q0 = quat.identity(dtype=dtype) if q0 is None else vector(q0, 4, "q0").astype(dtype)
    q0 = quat.normalize(q0)
    t0 = check_finite(as_float(t0, "t0").astype(dtype), "t0")
    scalar = ts.ndim == 0
    ts1 = jnp.atleast_1d(ts)

    out = _attitude_jit(inertia, omega0, q0, ts1, t0)
    return out[..., 0, :] if scalar else out


@jax.jit
def _attitude_jit(inertia, omega0, q0, ts, t0):
    def one(I, w, q, t):
        return _attitude(_plan(I, w), q, t - t0)

    return jnp.vectorize(one, signature="(3),(3),(4),(t)->(t,4)")(inertia, omega0, q0, ts)
