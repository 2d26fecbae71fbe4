"""The attitude of the free rigid body in closed form (Euler–Poinsot): the quaternion from the
body angular momentum's direction and the precession angle ψ(t) about it, ψ by Gauss–Legendre
quadrature of its rate over at most one period (THEORY §6; Landau & Lifshitz §37; see
`rigidjax.analytic.euler_poinsot` for Ω(t) and its regimes)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import as_float, vector
from .._custom_types import Quat, QuatLike, RealScalarLike, TimesLike, Vec3Like
from ..rotations import quat
from .euler_poinsot import (
    _body_inputs,
    _omega_periodic,
    _omega_sep,
    _Plan,
    _plan,
    _sign,
    _unpermute,
)

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
    `n = (sin θ sin φ, sin θ cos φ, cos θ)` (THEORY §3 Euler-angle formula:
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
    inertia: Vec3Like,
    omega0: Vec3Like,
    q0: QuatLike | None,
    ts: TimesLike,
    t0: RealScalarLike = 0.0,
) -> Float[Array, "*#batch T 4"] | Quat:
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
