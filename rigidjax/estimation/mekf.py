"""The multiplicative extended Kalman filter (MEKF) of attitude and gyro bias (Lefferts, Markley &
Shuster, J. Guid. Control Dyn. 5(5), 1982; Markley & Crassidis, *Fundamentals of Spacecraft
Attitude Determination and Control*, 2014, ch. 6; Crassidis & Junkins, *Optimal Estimation of
Dynamic Systems*, 2nd ed., §7.2). Equations and sources: docs/estimation.md.

State: the attitude `q̂` (body → space) and the gyro bias `b̂`. Error state `x = (δθ, δb)` in body
axes: `q = q̂ ∘ δq(δθ)`, `b = b̂ + δb`, covariance `P (6, 6)`.

- Propagation over `[t_k, t_{k+1}]` with the gyro's mean rate `r_k`: `ω̂ = r_k − b̂` held,
  `q̂ ← q̂ ∘ exp(ω̂ Δ)`, `P ← Φ P Φᵀ + Q`, with the exact transition of
  `δθ̇ = −[ω̂×] δθ − δb` for a constant rate, `Φ = [[Φ₁₁, Φ₁₂], [0, I]]`,
  `Φ₁₁ = exp(−[ω̂×]Δ) = I − A [θ×] + B [θ×]²`, `Φ₁₂ = −Δ (I − B [θ×] + C [θ×]²)`, `θ = ω̂Δ`,
  `A = sin θ/θ`, `B = (1 − cos θ)/θ²`, `C = (θ − sin θ)/θ³`, and Farrenkopf's process noise
  per axis `Q = [[σ_v²Δ + σ_u²Δ³/3, −σ_u²Δ²/2], [−σ_u²Δ²/2, σ_u²Δ]]` (exact at zero rate for
  the gyro of `rigidjax.sensors.gyro`; for a turning body it neglects the rotation of the
  noise within one step, a term of order `σ_u² Δ³ |ω̂Δ|²`).
- Update with a star tracker `q_m = q ∘ δq(n)`, `n ~ N(0, R)`: the innovation
  `y = log(q̂⁻¹ ∘ q_m) ≈ δθ + n` (`H = [I 0]`), `S = H P Hᵀ + R`, `K = P Hᵀ S⁻¹`,
  Joseph's form `P ← (I − KH) P (I − KH)ᵀ + K R Kᵀ` (Bucy & Joseph 1968), and the reset
  `q̂ ← q̂ ∘ δq(δθ⁺)`, `b̂ ← b̂ + δb⁺` (the covariance is kept through the reset, to first order
  as in Lefferts et al.).
- The log-likelihood of the innovations, `ℓ = −½ Σ_k (y_kᵀ S_k⁻¹ y_k + ln det S_k + 3 ln 2π)`
  (Schweppe 1965), the objective for tuning the noise levels by gradient."""

from __future__ import annotations

import math
from typing import Annotated, Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import (
    Check,
    as_float,
    broadcast_batch,
    broadcast_level,
    check_finite,
    check_nonnegative,
    is_concrete,
    validate,
    validate_all,
    vector,
)
from .._custom_types import RealLike
from .._numerics import cofactors
from ..rotations import _series, quat
from ..rotations._quat_core import _from_rotvec, _to_rotvec, _unit

__all__ = ["MEKF", "FilterState", "mekf", "propagate", "update"]

_LOG_2PI = math.log(2 * math.pi)
DEFAULT_ATTITUDE_SIGMA = 0.1  # rad: the prior of P0 when none is given
DEFAULT_BIAS_SIGMA = 1e-3  # rad/s


class FilterState(NamedTuple):
    """One run's filter state: attitude `q (4,)`, bias `b (3,)`, covariance `P (6, 6)` of
    `(δθ, δb)`."""

    q: Float[Array, "4"]
    b: Float[Array, "3"]
    P: Float[Array, "6 6"]


class MEKF(eqx.Module):
    """The result of `mekf`: after the update at each `ts[k]`, the attitude `quat (..., T, 4)`,
    bias `bias (..., T, 3)` and covariance `cov (..., T, 6, 6)` of `(δθ, δb)`; the innovations
    `innovation (..., T, 3)` and their normalised squares `nis (..., T)` = `yᵀ S⁻¹ y` (NaN
    where no measurement), and the log-likelihood of the innovations `log_likelihood (...)`."""

    quat: Float[Array, "*batch T 4"]
    bias: Float[Array, "*batch T 3"]
    cov: Float[Array, "*batch T 6 6"]
    innovation: Float[Array, "*batch T 3"]
    nis: Float[Array, "*batch T"]
    log_likelihood: Float[Array, "*batch"]


def _skew(v: Float[Array, "3"]) -> Float[Array, "3 3"]:
    z = jnp.zeros_like(v[0])
    return jnp.stack(
        [
            jnp.stack([z, -v[2], v[1]]),
            jnp.stack([v[2], z, -v[0]]),
            jnp.stack([-v[1], v[0], z]),
        ]
    )


def transition(
    w: Float[Array, "3"], dt: Float[Array, ""]
) -> tuple[Float[Array, "3 3"], Float[Array, "3 3"]]:
    """`(Φ₁₁, Φ₁₂)` of the error dynamics `δθ̇ = −[w×] δθ − δb` over `dt` at constant `w`
    (module docstring; Markley & Crassidis ch. 6, Crassidis & Junkins §7.2)."""
    th = w * dt
    x2 = jnp.sum(th * th)
    W = _skew(th)
    W2 = W @ W
    eye = jnp.eye(3, dtype=w.dtype)
    A, B, C = _series.sin_over(x2), _series.one_minus_cos_over(x2), _series.theta_minus_sin_over(x2)
    return eye - A * W + B * W2, -dt * (eye - B * W + C * W2)


def propagate(
    s: FilterState,
    rate: Float[Array, "3"],
    dt: Float[Array, ""],
    arw: Float[Array, "3"],
    rrw: Float[Array, "3"],
) -> FilterState:
    """One propagation over `dt` with the gyro's mean rate `rate` (module docstring); `arw`,
    `rrw` per axis. `dt = 0` leaves the state as it is."""
    w = rate - s.b
    F11, F12 = transition(w, dt)
    dtype = w.dtype
    top = jnp.concatenate([F11, F12], axis=1)
    bottom = jnp.concatenate([jnp.zeros((3, 3), dtype), jnp.eye(3, dtype=dtype)], axis=1)
    Phi = jnp.concatenate([top, bottom], axis=0)
    v2, u2 = arw * arw, rrw * rrw
    Qtt = jnp.diag(v2 * dt + u2 * dt**3 / 3)
    Qtb = jnp.diag(-u2 * dt**2 / 2)
    Qbb = jnp.diag(u2 * dt)
    Q = jnp.concatenate(
        [jnp.concatenate([Qtt, Qtb], axis=1), jnp.concatenate([Qtb, Qbb], axis=1)], axis=0
    )
    P = Phi @ s.P @ Phi.T + Q
    q = quat.mul(s.q, _from_rotvec(w * dt))
    q = q / jnp.sqrt(jnp.sum(q * q))
    return FilterState(q, s.b, 0.5 * (P + P.T))


def update(
    s: FilterState, q_meas: Float[Array, "4"], sigma: Float[Array, "3"]
) -> tuple[FilterState, Float[Array, ""], Float[Array, "3"], Float[Array, ""]]:
    """The star tracker's update with `q_meas = q ∘ δq(n)`, `n ~ N(0, diag(sigma²))` (module
    docstring): returns `(state, log-likelihood term, innovation, nis)`; a measurement with a
    non-finite entry (a NaN row) leaves the state as it is, with a zero log-likelihood term
    and NaN innovation and nis."""
    valid = jnp.all(jnp.isfinite(q_meas))
    qm = jnp.where(valid, q_meas, s.q)  # a finite stand-in: finite values and gradients
    y = _to_rotvec(quat.mul(quat.conj(s.q), qm))
    R = jnp.diag(sigma * sigma)
    S = s.P[:3, :3] + R
    cof, det = cofactors(S)
    S_inv = cof.T / det
    K = s.P[:, :3] @ S_inv  # (6, 3)
    dtype = y.dtype
    IKH = jnp.eye(6, dtype=dtype) - jnp.concatenate([K, jnp.zeros((6, 3), dtype)], axis=1)
    P = IKH @ s.P @ IKH.T + K @ R @ K.T
    dx = K @ y
    q = quat.mul(s.q, _from_rotvec(dx[:3]))
    q = q / jnp.sqrt(jnp.sum(q * q))
    nis = y @ S_inv @ y
    ll = -0.5 * (nis + jnp.log(det) + 3 * _LOG_2PI)
    new = FilterState(q, s.b + dx[3:], 0.5 * (P + P.T))
    out = jax.tree_util.tree_map(lambda a, b: jnp.where(valid, a, b), new, s)
    nan = jnp.asarray(jnp.nan, dtype)
    return (
        FilterState(*out),
        jnp.where(valid, ll, 0.0),
        jnp.where(valid, y, nan),
        jnp.where(valid, nis, nan),
    )


def _level(x: RealLike, name: str, unit: str, positive: bool = False) -> Array:
    x = as_float(x, name)
    if positive:
        return validate(
            x,
            lambda xp, v: ~((v > 0) & xp.isfinite(v)),
            f"{name} must be positive and finite",
            lambda v: f", got {v}" if v.ndim == 0 else f", got min {np.min(v)}",
            hint=f"; give the star tracker's noise {name} > 0 ({unit})",
        )
    return check_nonnegative(x, name, unit, hint=f"; give the gyro's noise level {name} ≥ 0")


def default_P0(dtype) -> Float[Array, "6 6"]:
    """The prior covariance when none is given: `diag(0.1² I, (1e-3)² I)` (0.1 rad, 1e-3 rad/s)."""
    d = jnp.array([DEFAULT_ATTITUDE_SIGMA**2] * 3 + [DEFAULT_BIAS_SIGMA**2] * 3, dtype)
    return jnp.diag(d)


def check_P0(P0: RealLike, name: str = "P0") -> Array:
    """`P0 (..., 6, 6)`, checked finite and symmetric (and positive definite, where concrete)."""
    P = as_float(P0, name)
    if P.shape[-2:] != (6, 6):
        raise ValueError(f"{name} must have shape (..., 6, 6) over (δθ, δb), got {tuple(P.shape)}")
    P = check_finite(P, name)

    def bad(xp, v):
        sym = xp.abs(v - xp.swapaxes(v, -1, -2)) > 1e-9 * (1 + xp.abs(v))
        return xp.any(sym, axis=(-1, -2))

    P = validate(P, bad, f"{name} must be symmetric", hint=f"; give {name} = (M + Mᵀ)/2")
    if is_concrete(P) and np.any(np.linalg.eigvalsh(np.asarray(P)) <= 0):
        raise ValueError(
            f"{name} must be positive definite (a covariance of (δθ, δb)), its smallest "
            f"eigenvalue is {np.min(np.linalg.eigvalsh(np.asarray(P))):.3g}"
        )
    return P


def _run(ts, gyro, q_meas, arw, rrw, sigma, q0, b0, P0):
    """One run (no batch): one scan over the samples, each a propagation (none before the
    first: `dt = 0` is the identity) and an update."""

    def step(carry, x):
        s, ll = carry
        dt, r, qm = x
        s = propagate(s, r, dt, arw, rrw)
        s, dll, y, nis = update(s, qm, sigma)
        return (s, ll + dll), (s, y, nis)

    dts = jnp.concatenate([jnp.zeros_like(ts[:1]), ts[1:] - ts[:-1]])
    rates = jnp.concatenate([jnp.zeros_like(gyro[:1]), gyro])
    init = (FilterState(q0, b0, P0), jnp.zeros((), ts.dtype))
    (_, ll), (ss, ys, ns) = jax.lax.scan(jax.checkpoint(step), init, (dts, rates, q_meas))
    return ss.q, ss.b, ss.P, ys, ns, ll


_batched = jax.jit(jax.vmap(_run))  # compiled once per shape, also when called eagerly


def mekf(
    ts: Annotated[RealLike, "*#batch T"],
    gyro: Annotated[RealLike, "*#batch T-1 3"],
    q_meas: Annotated[RealLike, "*#batch T 4"],
    *,
    arw: RealLike,
    rrw: RealLike,
    sigma: RealLike,
    q0: Annotated[RealLike, "*#batch 4"],
    bias0: Annotated[RealLike, "*#batch 3"] | None = None,
    P0: Annotated[RealLike, "*#batch 6 6"] | None = None,
) -> MEKF:
    """The MEKF of attitude and gyro bias (module docstring) over the times `ts (..., T)`:
    starts from `q0 (..., 4)`, `bias0 (..., 3)` (zero) and `P0 (..., 6, 6)` over `(δθ, δb)`
    (default `diag(0.1² I, (1e-3)² I)`) at `ts[0]`, updates with `q_meas[0]`, then for each
    `k ≥ 1` propagates from `ts[k−1]` to `ts[k]` with the gyro's mean rate `gyro[k−1]`
    (`(..., T−1, 3)`, rad/s) and updates with the star tracker's `q_meas[k]` (`(..., T, 4)`; a
    row with a NaN: no update; an infinite entry is an error). Noise levels (scalars, or
    broadcasting against `(..., 3)`: `(3,)` per body axis): the gyro's angle random walk
    `arw` (rad/√s) and rate random walk `rrw` (rad/s^1.5), as in `rigidjax.sensors.gyro`,
    and the star tracker's `sigma` (rad).

    A `jax.lax.scan` over the steps, vmapped over the runs: `jit`, `vmap` and `grad` (with
    respect to `arw`, `rrw`, `sigma`, `q0`, `P0` and the data) go through; returns an `MEKF`."""
    ts = as_float(ts, "ts")
    gyro_ = check_finite(vector(gyro, 3, "gyro"), "gyro")
    qm = vector(q_meas, 4, "q_meas")
    if ts.ndim < 1 or ts.shape[-1] < 2:
        raise ValueError(f"ts must have shape (..., T) with T ≥ 2, got {tuple(ts.shape)}")
    T = ts.shape[-1]
    if gyro_.ndim < 2 or gyro_.shape[-2] != T - 1:
        raise ValueError(
            f"gyro must have shape (..., T−1, 3) = (..., {T - 1}, 3) (one mean rate per "
            f"interval of ts), got {tuple(gyro_.shape)}"
        )
    if qm.ndim < 2 or qm.shape[-2] != T:
        raise ValueError(
            f"q_meas must have shape (..., T, 4) = (..., {T}, 4) (a NaN row where there is no "
            f"measurement), got {tuple(qm.shape)}"
        )
    ts = validate(
        ts,
        lambda xp, t: ~xp.isfinite(t) | ~(xp.diff(t, axis=-1, prepend=-xp.inf) > 0),
        "ts must be strictly increasing and finite",
    )

    def zero_row(xp: Any, q: Any) -> Any:  # (|q|² may underflow to 0 for a tiny row)
        return xp.all(xp.isfinite(q), axis=-1) & (xp.sum(q * q, axis=-1) == 0)

    def infinite(xp: Any, q: Any) -> Any:  # (an overflow, not a missing measurement)
        return xp.any(xp.isinf(q), axis=-1)

    no_meas = "; give a row of NaN where there is no measurement"
    qm = validate_all(
        qm,
        [
            Check(
                zero_row,
                "q_meas has a row of zeros, which is no attitude",
                lambda q: f": row {np.argwhere(zero_row(np, q))[0].tolist()}",
                no_meas,
            ),
            Check(
                infinite,
                "q_meas has an infinite entry",
                lambda q: f": row {np.argwhere(infinite(np, q))[0].tolist()}",
                no_meas,
            ),
        ],
    )
    q0_ = _unit(check_finite(vector(q0, 4, "q0"), "q0"), "q0")
    b0 = jnp.zeros(3) if bias0 is None else check_finite(vector(bias0, 3, "bias0"), "bias0")
    arw_, rrw_ = _level(arw, "arw", "rad/√s"), _level(rrw, "rrw", "rad/s^1.5")
    sigma_ = _level(sigma, "sigma", "rad", positive=True)
    # the data's dtype (times, gyro, measurements, start): the noise levels, bias0 and P0 are
    # cast to it, so float32 data give float32 under x64 (a NumPy float64 level did promote)
    dtype = jnp.result_type(ts, gyro_, qm, q0_)
    P = default_P0(dtype) if P0 is None else check_P0(P0)
    lead = {
        "ts": ts.shape[:-1],
        "gyro": gyro_.shape[:-2],
        "q_meas": qm.shape[:-2],
        "q0": q0_.shape[:-1],
        "bias0": b0.shape[:-1],
        "P0": P.shape[:-2],
    }
    for name, x in (("arw", arw_), ("rrw", rrw_), ("sigma", sigma_)):
        lead[name] = broadcast_level(
            x.shape, (3,), name, "against (..., 3) (runs: (N, 1))", extend=True
        )[:-1]
    batch = broadcast_batch(**lead)
    B = int(np.prod(batch))

    def flat(x, tail):
        return jnp.broadcast_to(x.astype(dtype), (*batch, *tail)).reshape(B, *tail)

    args = (
        flat(ts, (T,)),
        flat(gyro_, (T - 1, 3)),
        flat(qm, (T, 4)),
        flat(jnp.broadcast_to(arw_, (*arw_.shape[:-1], 3)) if arw_.ndim else arw_, (3,)),
        flat(jnp.broadcast_to(rrw_, (*rrw_.shape[:-1], 3)) if rrw_.ndim else rrw_, (3,)),
        flat(jnp.broadcast_to(sigma_, (*sigma_.shape[:-1], 3)) if sigma_.ndim else sigma_, (3,)),
        flat(q0_, (4,)),
        flat(b0, (3,)),
        flat(P, (6, 6)),
    )
    qs, bs, Ps, ys, ns, ll = _batched(*args)

    def shape(a):
        return a.reshape(*batch, *a.shape[1:])

    return MEKF(shape(qs), shape(bs), shape(Ps), shape(ys), shape(ns), shape(ll))
