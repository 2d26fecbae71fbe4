"""The estimator in the loop: a sampled-data control law acting on the MEKF's estimate from a
simulated rate gyro and star tracker, instead of the true state.

`estimated(law, arw=..., rrw=..., sigma=...)` wraps a law `law(t_k, ω, q, params) -> command`
(e.g. `rigidjax.control.quaternion_pd`) into a `rigidjax.control.StatefulController` for
`simulate(gyrostat, ..., controller=c.with_key(keys), control_period=T)`. Each body
carries, in the solve's state, the true gyro bias, the filter's state `(q̂, b̂, P)` and its PRNG
key; at each sample `t_k` (flight software's cycle):

1. the gyro reads its mean rate over `[t_{k−1}, t_k]`, `r_k = ω̄ + β̄ + (σ_v/√T) N(0, I)`, with
   the true mean rate `ω̄` the trapezoid of the true rates at the two samples and the bias drawn
   as in `rigidjax.sensors.gyro` (the first sample reads the period before `t0` at `Ω0`);
2. the MEKF propagates with `r_k` (from the second sample on) and updates with the star
   tracker's `q ∘ δq(n)`, `n ~ N(0, σ² I)` (`rigidjax.estimation.mekf`'s `propagate`,
   `update`);
3. the law acts on the estimate: `command = law(t_k, r_k − b̂, q̂, params)`.

The initial estimate is drawn from the filter's prior: `q̂_0 = q_0 ∘ δq(−δθ_0)`, the true bias
`δb_0`, `(δθ_0, δb_0) ~ N(0, P0)`. The sensors' draws come from L'Ecuyer's MRG32k3a (Oper.
Res. 47(1), 1999; period 2^191), seeded from the body's key and carried in its memory, in exact
float64 arithmetic, with Box–Muller normals: float operations only, so that the whole loop,
filter and sensors included, runs inside the model's CPU kernel; a Monte Carlo is reproducible
body by body, whatever the batch. The log at each sample (`log_size` =
19, unpacked by `loop_log`): `q̂ (4)`, `b̂ (3)`, the true knowledge error
`δθ = log(q̂⁻¹ ∘ q) (3)` and bias error `b − b̂ (3)` (body axes), and the filter's standard
deviations of `(δθ, δb)` (6).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._checks import as_float
from .._custom_types import RealLike
from ..control.stateful import StatefulController
from ..rotations import quat
from ..rotations._quat_core import _from_rotvec, _to_rotvec
from .mekf import FilterState, _level, check_P0, default_P0, propagate, update

__all__ = ["Estimated", "LoopLog", "control_error", "estimated", "knowledge_error", "loop_log"]

_SQRT3 = math.sqrt(3.0)


# L'Ecuyer's MRG32k3a (Oper. Res. 47(1), 1999), in float64 arithmetic as in its reference
# implementation: every product is below 2^53, so each step is exact.
_M1, _M2 = 4294967087.0, 4294944443.0
_A12, _A13N, _A21, _A23N = 1403580.0, 810728.0, 527612.0, 1370589.0
_NORM = 1.0 / (_M1 + 1.0)


def _mod(p: Array, m: float) -> Array:
    """`p mod m` in [0, m) for an integer-valued float `p` (exact: `k m` and `p − k m` are)."""
    r = p - jnp.floor(p / m) * m
    r = jnp.where(r < 0, r + m, r)
    return jnp.where(r >= m, r - m, r)


def _seed(key: PRNGKeyArray, dtype) -> Float[Array, "6"]:
    """The generator's state `(s₁₀, s₁₁, s₁₂, s₂₀, s₂₁, s₂₂)` drawn from `key` (each component
    below its modulus and not all zero)."""
    bits = jax.random.bits(key, (6,), jnp.uint32)
    m = jnp.array([_M1] * 3 + [_M2] * 3, jnp.float64)
    s = jnp.remainder(bits.astype(jnp.float64), m)
    s = s.at[0].set(jnp.where(jnp.all(s[:3] == 0), 1.0, s[0]))
    s = s.at[3].set(jnp.where(jnp.all(s[3:] == 0), 1.0, s[3]))
    return s.astype(dtype)


def _uniform(s: Float[Array, "6"]) -> tuple[Float[Array, ""], Float[Array, "6"]]:
    """One MRG32k3a draw in (0, 1) and the next state (float operations only: the sampling jump
    map stays one the CPU kernel can take)."""
    p1 = _mod(_A12 * s[1] - _A13N * s[0], _M1)
    p2 = _mod(_A21 * s[5] - _A23N * s[3], _M2)
    u = jnp.where(p1 <= p2, p1 - p2 + _M1, p1 - p2) * _NORM
    return u, jnp.stack([s[1], s[2], p1, s[4], s[5], p2])


def normals(s: Float[Array, "6"], n: int) -> tuple[Float[Array, " n"], Float[Array, "6"]]:
    """`n` (even) standard normals by Box–Muller from MRG32k3a uniforms, and the next state."""
    out = []
    for _ in range(n // 2):
        u1, s = _uniform(s)
        u2, s = _uniform(s)
        r = jnp.sqrt(-2 * jnp.log(u1))
        out += [r * jnp.cos(2 * math.pi * u2), r * jnp.sin(2 * math.pi * u2)]
    return jnp.stack(out), s


class LoopLog(NamedTuple):
    """The estimator's log at the control samples (`loop_log`), each `(..., K, ·)`: estimate
    `quat`, `bias`; true errors `attitude_error` `δθ = log(q̂⁻¹ ∘ q)` and `bias_error` `b − b̂`
    (body axes); the filter's standard deviations `sigma_attitude`, `sigma_bias`."""

    quat: Float[Array, "*batch K 4"]
    bias: Float[Array, "*batch K 3"]
    attitude_error: Float[Array, "*batch K 3"]
    bias_error: Float[Array, "*batch K 3"]
    sigma_attitude: Float[Array, "*batch K 3"]
    sigma_bias: Float[Array, "*batch K 3"]


def loop_log(traj: Any) -> LoopLog:
    """The `LoopLog` of a trajectory simulated with an `estimated` controller (its
    `controller_log (..., K, 19)`)."""
    log = getattr(traj, "controller_log", None)
    if log is None or log.shape[-1] != Estimated.log_size:
        raise ValueError(
            "loop_log reads the controller_log of simulate(gyrostat, ..., controller="
            "estimated(...)); this trajectory has "
            + ("none" if log is None else f"a log of {log.shape[-1]} entries")
        )
    cuts = (0, 4, 7, 10, 13, 16, 19)
    return LoopLog(*(log[..., a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True)))


def _angle(v: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
    """`|v|` with a finite gradient at 0 (double `where`)."""
    n2 = jnp.sum(v * v, axis=-1)
    pos = n2 > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, 1.0)), 0.0)


def knowledge_error(traj: Any) -> Float[Array, "*batch K"]:
    """The pointing knowledge error at each control sample (rad): the angle `|δθ|` between the
    estimate and the true attitude, `δθ = log(q̂⁻¹ ∘ q)` (ECSS-E-ST-60-10's knowledge error,
    after the sample's update)."""
    return _angle(loop_log(traj).attitude_error)


def control_error(traj: Any, q_target: RealLike) -> Float[Array, "*batch K"]:
    """The control error at each control sample (rad): the angle between the target
    `q_target (4,)` and the estimate `q̂` that the law acts on (with `knowledge_error`, the
    two terms of the pointing error `rigidjax.observables.pointing_error`, true vs target)."""
    q_hat = loop_log(traj).quat
    qt = jnp.asarray(q_target, q_hat.dtype)
    qe = quat.mul(quat.conj(qt / jnp.linalg.norm(qt)), q_hat)
    return 2 * jnp.arctan2(_angle(qe[..., 1:]), jnp.abs(qe[..., 0]))


class Estimated(StatefulController):
    """A law acting on the MEKF's estimate from a simulated gyro and star tracker (module
    docstring). The sensors' true noise: `arw`, `rrw`, `sigma` `(3,)`; the filter's model:
    `filter_arw`, `filter_rrw`, `filter_sigma`; `P0 (6, 6)`: the filter's prior and the spread of
    the true initial errors."""

    law: Callable
    arw: Float[Array, "3"]
    rrw: Float[Array, "3"]
    sigma: Float[Array, "3"]
    filter_arw: Float[Array, "3"]
    filter_rrw: Float[Array, "3"]
    filter_sigma: Float[Array, "3"]
    P0: Float[Array, "6 6"]
    log_size: ClassVar[int] = 19

    def init(self, key, t0, omega0, q0, params, period):
        if key is None:
            raise ValueError(
                "the estimator in the loop draws sensor noise: give it a key, "
                "controller=estimated(...).with_key(jax.random.key(seed)) or simulate(..., "
                "controller_key=...) (one key, split over the bodies, or one per body)"
            )
        dtype = jnp.asarray(omega0).dtype
        if dtype != jnp.float64:
            raise ValueError(
                "the estimator in the loop runs in float64 (its generator's arithmetic is exact "
                "there): jax.config.update('jax_enable_x64', True) and float64 states"
            )
        k_err, k_run = jax.random.split(key)
        L = jnp.linalg.cholesky(self.P0.astype(dtype))
        err = L @ jax.random.normal(k_err, (6,), dtype)
        q_hat = quat.mul(q0, _from_rotvec(-err[:3]))
        return dict(
            rng=_seed(k_run, dtype),
            count=jnp.zeros((), dtype),
            t_prev=jnp.asarray(t0, dtype) - period,
            omega_prev=jnp.asarray(omega0, dtype),
            bias_true=err[3:],
            q=q_hat / jnp.linalg.norm(q_hat),
            b=jnp.zeros(3, dtype),
            P=self.P0.astype(dtype),
        )

    def step(self, t, omega, q, params, memory):
        mem = memory
        dtype = omega.dtype
        z, rng = normals(mem["rng"], 12)
        z = z.reshape(4, 3)
        dt = t - mem["t_prev"]
        sdt = jnp.sqrt(dt)
        rrw, arw = self.rrw.astype(dtype), self.arw.astype(dtype)
        mean_bias = mem["bias_true"] + rrw * sdt * (0.5 * z[0] + z[1] / (2 * _SQRT3))
        bias_true = mem["bias_true"] + rrw * sdt * z[0]
        rate = 0.5 * (mem["omega_prev"] + omega) + mean_bias + arw / sdt * z[2]
        s = FilterState(mem["q"], mem["b"], mem["P"])
        started = mem["count"] > 0
        s = propagate(
            s, rate, jnp.where(started, dt, 0.0), self.filter_arw.astype(dtype),
            self.filter_rrw.astype(dtype),
        )  # fmt: skip
        q_meas = quat.mul(q, _from_rotvec(self.sigma.astype(dtype) * z[3]))
        s, _, _, _ = update(s, q_meas, self.filter_sigma.astype(dtype))
        u = self.law(t, rate - s.b, s.q, params)
        log = jnp.concatenate(
            [
                s.q,
                s.b,
                _to_rotvec(quat.mul(quat.conj(s.q), q)),
                bias_true - s.b,
                jnp.sqrt(jnp.stack([s.P[i, i] for i in range(6)])),
            ]
        )
        new = dict(
            rng=rng,
            count=mem["count"] + 1,
            t_prev=jnp.asarray(t, dtype),
            omega_prev=omega,
            bias_true=bias_true,
            q=s.q,
            b=s.b,
            P=s.P,
        )
        return u, new, log


def _axes(x: RealLike, name: str, unit: str, positive: bool = False) -> Array:
    v = _level(x, name, unit, positive)
    if v.shape not in ((), (3,)):
        raise ValueError(f"{name} must be a scalar or (3,) per body axis, got {v.shape}")
    return jnp.broadcast_to(v, (3,))


def estimated(
    law: Callable,
    *,
    arw: RealLike,
    rrw: RealLike,
    sigma: RealLike,
    P0: RealLike | None = None,
    filter_arw: RealLike | None = None,
    filter_rrw: RealLike | None = None,
    filter_sigma: RealLike | None = None,
) -> Estimated:
    """The `law` (`law(t_k, ω, q, params) -> command`) acting on the MEKF's estimate (module
    docstring) from a gyro of angle random walk `arw` (rad/√s) and rate random walk `rrw`
    (rad/s^1.5) and a star tracker of noise `sigma` (rad), each a scalar or `(3,)` per body
    axis. The filter assumes `filter_arw`, `filter_rrw`, `filter_sigma` (default: the true
    values) and starts from `P0 (6, 6)` over `(δθ, δb)` (default `diag(0.1² I, (1e-3)² I)`),
    from which the initial knowledge and bias errors are drawn. For
    `simulate(gyrostat, ..., controller=estimated(...).with_key(key), control_period=T)`
    (`key`: one PRNG key, split over the bodies, or one per body)."""
    if not callable(law):
        raise TypeError(f"law must be a callable law(t, omega, q, params) -> command, got {law!r}")
    a, r = _axes(arw, "arw", "rad/√s"), _axes(rrw, "rrw", "rad/s^1.5")
    s = _axes(sigma, "sigma", "rad", positive=True)
    fa = a if filter_arw is None else _axes(filter_arw, "filter_arw", "rad/√s")
    fr = r if filter_rrw is None else _axes(filter_rrw, "filter_rrw", "rad/s^1.5")
    fs = s if filter_sigma is None else _axes(filter_sigma, "filter_sigma", "rad", positive=True)
    dtype = jnp.result_type(a, r, s, fa, fr, fs)
    P = default_P0(dtype) if P0 is None else check_P0(P0)
    if P.shape != (6, 6):
        raise ValueError(f"P0 must be one (6, 6) covariance, got {P.shape}")
    return Estimated(law, a, r, s, fa, fr, fs, as_float(P, "P0"))
