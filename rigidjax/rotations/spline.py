"""C²-continuous attitude interpolation, as SciPy's `RotationSpline` (the algorithm of
N. Mayorov, "Smooth Attitude Interpolation", scipy#10051; scipy/spatial/transform/
_rotation_spline.py).

On segment k, `q(t) = q_k ∘ exp(θ(τ))`, `τ = t − t_k`, with a cubic rotation vector
`θ(τ) = a τ³ + b τ² + ω_k τ` that ends at `θ_k = log(q_k⁻¹ ∘ q_{k+1})`:

    a = (−2θ_k + Δ ω_k + Δ θ̇_k)/Δ³,  b = (3θ_k − 2Δ ω_k − Δ θ̇_k)/Δ²,  θ̇_k = A(θ_k) ω_{k+1},

Δ = t_{k+1} − t_k. The body angular rate is `ω = A⁻¹(θ) θ̇` with `A(θ) = E + ½ θ× + k(θ) (θ×)²`,
`k = (1 − (θ/2) cot(θ/2))/θ²` (`so3.Z(−θ)`), `A⁻¹ = E − ((1 − cos θ)/θ²) θ× + ((θ − sin θ)/θ³)
(θ×)²`, and the angular acceleration is

    ε = A⁻¹(θ) θ̈ + (θ·θ̇)(k1 θ × θ̇ + k2 θ × (θ × θ̇)) + k3 θ̇ × (θ × θ̇),

`k1 = (2(1 − cos θ) − θ sin θ)/θ⁴`, `k2 = (3 sin θ − θ cos θ − 2θ)/θ⁵`, `k3 = (θ − sin θ)/θ³`.
Continuity of the angular acceleration at the inner keys gives, for the inner rates ω_1…ω_{N−2}
(the end rates are fixed at `ω_0 = θ_0/Δ_0`, `ω_{N−1} = θ_{N−2}/Δ_{N−2}`), a block-tridiagonal
system whose right-hand side depends on the rates through the nonlinear term; SciPy solves it by
fixed-point iteration (at most 10 sweeps, stopping when every change is below
`1e-9 (1 + |ω|)`), and so does this module, with the same stopping rule, so that both agree to
rounding. Each sweep is a block Thomas solve (the system is block diagonally dominant).
"""

from __future__ import annotations

import math
import numbers

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import as_float, integer
from .._custom_types import Mat33, QuatLike, RealLike, Vec3
from .._numerics import inv3, poly
from . import _series
from . import _validation as _v
from ._quat_core import _from_rotvec, _to_rotvec, conj, mul
from .slerp import _with_last_sign, key_frames

__all__ = ["RotationSpline"]

# Taylor coefficients (in θ²) of k1 and k2 of the nonlinear term
_K1 = [(-1) ** j * (2 * j + 2) / math.factorial(2 * j + 4) for j in range(8)]
_K2 = [(-1) ** (j + 1) * (2 * j + 2) / math.factorial(2 * j + 5) for j in range(8)]


def _guarded(x2: Array, exact, coeffs: list[float]) -> Array:
    small = x2 < 0.25  # |θ| < ½: 8 terms are exact to rounding; the closed forms lose ≤ 1e-13
    safe = jnp.where(small, jnp.ones_like(x2), x2)
    return jnp.where(small, poly(x2, coeffs), exact(safe))


def _k1(x2: Array) -> Array:
    def exact(x: Array) -> Array:
        t = jnp.sqrt(x)
        return (4 * jnp.sin(t / 2) ** 2 - t * jnp.sin(t)) / (x * x)

    return _guarded(x2, exact, _K1)


def _k2(x2: Array) -> Array:
    def exact(x: Array) -> Array:
        t = jnp.sqrt(x)
        return (3 * jnp.sin(t) - t * jnp.cos(t) - 2 * t) / (x * x * t)

    return _guarded(x2, exact, _K2)


def _hat(v: Vec3) -> Mat33:
    z = jnp.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return jnp.stack(
        [jnp.stack([z, -w, y], -1), jnp.stack([w, z, -x], -1), jnp.stack([-y, x, z], -1)], -2
    )


def _rate_to_rotvec_dot(theta: Vec3) -> Mat33:
    """`A(θ)`: `θ̇ = A(θ) ω` (body rate; Zhilin's `Z(−θ)`)."""
    S = _hat(theta)
    k = _series.zhilin_d(jnp.sum(theta * theta, -1))[..., None, None]
    return jnp.eye(3, dtype=theta.dtype) + 0.5 * S + k * (S @ S)


def _rotvec_dot_to_rate(theta: Vec3) -> Mat33:
    """`A⁻¹(θ)`: `ω = A⁻¹(θ) θ̇` (Zhilin's `Z⁻¹(−θ)`)."""
    S = _hat(theta)
    x2 = jnp.sum(theta * theta, -1)
    k1 = _series.one_minus_cos_over(x2)[..., None, None]
    k2 = _series.theta_minus_sin_over(x2)[..., None, None]
    return jnp.eye(3, dtype=theta.dtype) - k1 * S + k2 * (S @ S)


def _nonlinear(theta: Vec3, theta_dot: Vec3) -> Vec3:
    """The term of the angular acceleration quadratic in θ̇ (module docstring)."""
    x2 = jnp.sum(theta * theta, -1)[..., None]
    dp = jnp.sum(theta * theta_dot, -1)[..., None]
    cp = jnp.cross(theta, theta_dot)
    ccp = jnp.cross(theta, cp)
    dccp = jnp.cross(theta_dot, cp)
    k3 = _series.theta_minus_sin_over(x2)
    return dp * (_k1(x2) * cp + _k2(x2) * ccp) + k3 * dccp


def _mv(A: Mat33, v: Vec3) -> Vec3:
    return jnp.einsum("...ij,...j->...i", A, v)


def _block_thomas(L: Array, D: Array, U: Array, r: Array) -> Array:
    """Solve the block-tridiagonal system `L_i x_{i−1} + D_i x_i + U_i x_{i+1} = r_i` (blocks
    3×3, `L_0`, `U_{m−1}` unused) by block Gaussian elimination without pivoting (the system is
    block diagonally dominant: the diagonal blocks are `4(1/Δ_k + 1/Δ_{k+1}) E`)."""

    def forward(carry, blocks):
        c_prev, d_prev = carry
        Li, Di, Ui, ri = blocks
        M_inv = inv3(Di - Li @ c_prev)
        c = M_inv @ Ui
        d = M_inv @ (ri - Li @ d_prev)
        return (c, d), (c, d)

    zero = (jnp.zeros_like(D[0]), jnp.zeros_like(r[0]))
    _, (C, Dp) = jax.lax.scan(forward, zero, (L, D, U, r))

    def backward(x_next, cd):
        c, d = cd
        x = d - c @ x_next
        return x, x

    _, X = jax.lax.scan(backward, jnp.zeros_like(r[0]), (C, Dp), reverse=True)
    return X


def _solve_rates(
    dt: Float[Array, " M"], rotvecs: Float[Array, "M 3"], max_iter: int, tol: float
) -> tuple[Float[Array, "M 3"], Float[Array, "M 3"]]:
    """SciPy's `_solve_for_angular_rates`: rates at keys 0…N−2 and θ̇ at each segment's end,
    starting from each segment's mean rate `θ/Δt` (which the end keys keep)."""
    rates = rotvecs / dt[:, None]
    first, last = rates[0], rates[-1]
    A = _rate_to_rotvec_dot(rotvecs)
    A_inv = _rotvec_dot_to_rate(rotvecs)
    m = rotvecs.shape[0] - 1  # inner keys 1…N−2
    eye = jnp.eye(3, dtype=rotvecs.dtype)
    D = (4 * (1 / dt[:-1] + 1 / dt[1:]))[:, None, None] * eye
    zero = jnp.zeros((1, 3, 3), rotvecs.dtype)
    L = jnp.concatenate([zero, 2 * A_inv[1:-1] / dt[1:-1, None, None]])
    U = jnp.concatenate([2 * A[1:-1] / dt[1:-1, None, None], zero])
    b0 = 6 * (rotvecs[:-1] / dt[:-1, None] ** 2 + rotvecs[1:] / dt[1:, None] ** 2)
    b0 = b0.at[0].add(-2 / dt[0] * (A_inv[0] @ first))
    b0 = b0.at[-1].add(-2 / dt[-1] * (A[-1] @ last))

    def sweep(carry, _):
        inner, done = carry  # inner: rates at keys 1…N−2
        rotvecs_dot = _mv(A, jnp.concatenate([inner, last[None]]))
        new = _block_thomas(L, D, U, b0 - _nonlinear(rotvecs[:-1], rotvecs_dot[:-1]))
        converged = jnp.all(jnp.abs(new - inner) < tol * (1 + jnp.abs(new)))
        return (jnp.where(done, inner, new), done | converged), None

    start = (rates[:m], jnp.zeros((), bool))
    (inner, _), _ = jax.lax.scan(sweep, start, None, length=max_iter)
    ends = jnp.concatenate([inner, last[None]])
    return jnp.concatenate([first[None], inner]), _mv(A, ends)


class RotationSpline(eqx.Module):
    """Interpolation through key attitudes with continuous angular rate and acceleration, the
    same as SciPy's `RotationSpline` (module docstring for the formulas).

    `RotationSpline(ts, q)`: key times `ts (N,)`, strictly increasing (a repeated time is a
    ValueError naming it, a run-time error under `jit`), key attitudes `q (N, 4)` (scalar-first,
    treated as unit), N ≥ 2. `spline(t, order=0)` at times `t` of any shape: the attitude as a
    unit quaternion `t.shape + (4,)` (key k's sign on `[t_k, t_k+1)`, the last key's from its
    time on); `order=1` the angular rate and `order=2` the angular acceleration, both in the body
    frame (SciPy's), `t.shape + (3,)`.
    Times outside `[ts[0], ts[-1]]` extrapolate the end segments' cubics (as SciPy). An equinox
    Module: `jit`, `vmap` and `grad` with respect to `ts`, `q` and `t` (the fixed-point sweeps
    are differentiated as computed).

    `max_iter`, `tol`: the fixed-point sweeps for the inner rates, SciPy's 10 and 1e-9 by
    default. With large turns between keys 10 sweeps may stop short (SciPy's spline then has
    jumps in the angular acceleration at the keys, e.g. 1e-4 relative); `max_iter=50, tol=0`
    iterates to the fixed point, continuous to rounding.
    """

    times: Float[Array, " N"]
    keys: Float[Array, "N 4"]
    coeffs: Float[Array, "3 M 3"]  # (a, b, ω_k) of each segment's cubic θ(τ)
    max_iter: int = eqx.field(static=True, default=10)
    tol: float = eqx.field(static=True, default=1e-9)

    def __init__(self, ts: RealLike, q: QuatLike, max_iter: int = 10, tol: float = 1e-9):
        max_iter = integer(max_iter, "max_iter")
        real = isinstance(tol, numbers.Real) and not isinstance(tol, bool)
        if not (real and math.isfinite(tol) and tol >= 0):
            raise ValueError(
                f"tol must be a finite number >= 0 (the sweeps' relative change; 0: all "
                f"max_iter sweeps), got {tol!r}"
            )
        times, keys = key_frames(ts, q)
        dt = jnp.diff(times)
        rotvecs = _to_rotvec(mul(conj(keys[:-1]), keys[1:]))
        if keys.shape[0] == 2:
            rates = rotvecs_dot = rotvecs / dt[:, None]
        else:
            rates, rotvecs_dot = _solve_rates(dt, rotvecs, max_iter, tol)
        d = dt[:, None]
        a = (-2 * rotvecs + d * rates + d * rotvecs_dot) / d**3
        b = (3 * rotvecs - 2 * d * rates - d * rotvecs_dot) / d**2
        self.times, self.keys, self.coeffs = times, keys, jnp.stack([a, b, rates])
        self.max_iter, self.tol = max_iter, tol

    def _segment(self, t: Array) -> tuple[Array, Array]:
        n = self.times.shape[0]
        idx = jnp.clip(jnp.searchsorted(self.times, t, side="right") - 1, 0, n - 2)
        return idx, (t - self.times[idx])[..., None]

    def __call__(self, t: RealLike, order: int = 0) -> Float[Array, "..."]:
        if order not in (0, 1, 2):
            raise ValueError(f"`order` must be 0, 1 or 2, got order={order!r}")
        t = _v.check_finite(as_float(t, "t"), "t", 0).astype(self.times.dtype)
        idx, tau = self._segment(t)
        a, b, w = self.coeffs[0][idx], self.coeffs[1][idx], self.coeffs[2][idx]
        theta = ((a * tau + b) * tau + w) * tau
        if order == 0:  # the sign of key k on [t_k, t_k+1), of the last key from t_N−1 on
            q = mul(self.keys[idx], _from_rotvec(theta))
            d = self.times[-1] - self.times[-2]
            a1, b1, w1 = self.coeffs[:, -1]
            end = mul(self.keys[-2], _from_rotvec(((a1 * d + b1) * d + w1) * d))
            return _with_last_sign(q, t, self.times, self.keys, end)
        theta_dot = (3 * a * tau + 2 * b) * tau + w
        rate_part = _rotvec_dot_to_rate(theta)
        if order == 1:
            return _mv(rate_part, theta_dot)
        theta_ddot = 6 * a * tau + 2 * b
        return _mv(rate_part, theta_ddot) + _nonlinear(theta, theta_dot)
