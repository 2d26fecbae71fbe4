"""Attitude sensors with explicit PRNG keys: the rate gyro of Farrenkopf's model and a star
tracker. Batched over leading dimensions, jit-able and differentiable in the true motion and
the noise levels (the draws are reparametrised: `noise = level × N(0, 1)`).

**Rate gyro** (Farrenkopf, AIAA J. 16(4), 1978; Crassidis & Junkins, *Optimal Estimation of
Dynamic Systems*, 2nd ed., §7.2; Markley & Crassidis, *Fundamentals of Spacecraft Attitude
Determination and Control*, 2014, ch. 6). Per body axis the gyro reads

    ω̃(t) = ω(t) + β(t) + η_v(t),   β̇ = η_u(t),

`η_v`, `η_u` white with spectral densities `σ_v²` (angle random walk `arw`, rad/√s) and `σ_u²`
(rate random walk `rrw`, rad/s^1.5). A sampled gyro reports the mean over each interval
`[t_k, t_k + Δ]`: `r_k = ω̄_k + β̄_k + v̄_k`. Its exact discrete statistics, with
`W(s) = β(t_k + s) − β_k` a Brownian motion of intensity `σ_u²`:

- `v̄_k = (1/Δ) ∫ η_v ~ N(0, σ_v²/Δ)`;
- the bias increment `β_{k+1} − β_k = W(Δ)` and the mean bias `β̄_k − β_k = (1/Δ) ∫₀^Δ W(s) ds`
  are jointly Gaussian with `Var W(Δ) = σ_u² Δ`, `Var(β̄_k − β_k) = σ_u² Δ/3` and
  `Cov = (1/Δ) ∫₀^Δ min(s, Δ) σ_u² ds = σ_u² Δ/2` (correlation √3/2), drawn here as
  `W(Δ) = σ_u √Δ z₁`, `β̄_k − β_k = σ_u √Δ (z₁/2 + z₂/(2√3))` with `z₁, z₂ ~ N(0, 1)`.

So `r_k = ω̄_k + (β_k + β_{k+1})/2 + (σ_v²/Δ + σ_u² Δ/12)^{1/2} N(0, 1)`, Crassidis & Junkins'
simulation formula, and the error of a filter that propagates with `r_k − b̂` obeys Farrenkopf's
discrete process noise `Q = [[σ_v² Δ + σ_u² Δ³/3, −σ_u² Δ²/2], [−σ_u² Δ²/2, σ_u² Δ]]` exactly
(`rigidjax.estimation.mekf`). At rest the Allan variance of the readings is
`σ_A²(τ) = σ_v²/τ + σ_u² τ/3` for every cluster time `τ = nΔ` (IEEE Std 952-1997, annex C).

The true mean rate `ω̄_k` is the trapezoid `(ω_k + ω_{k+1})/2` of the sampled true rate (error
`Δ² |ω̈|/12`), or the exact mean given as `omega_mean` (e.g. the rotation vector of
`q_k⁻¹ ∘ q_{k+1}` over `Δ`, the constant rate that carries one sample to the next).

**Star tracker**: the measured attitude `q ∘ δq(n)`, `δq(n) = (cos(|n|/2), sin(|n|/2) n/|n|)`,
with `n ~ N(0, σ²)` per body axis (rad): small-angle noise in body axes, as the
multiplicative filter models it (Markley & Crassidis ch. 6)."""

from __future__ import annotations

import math
from typing import Annotated

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ._checks import (
    as_float,
    broadcast_batch,
    broadcast_level,
    check_finite,
    check_nonnegative,
    validate,
    vector,
)
from ._custom_types import RealLike
from .rotations import quat

__all__ = ["gyro", "star_tracker"]

KeyLike = PRNGKeyArray | Array


def keys_for(key: KeyLike, batch: tuple[int, ...], name: str = "key") -> tuple[Array, bool]:
    """`(typed key array, per_run)`: one key per run of shape `batch` (typed `batch`, or raw
    `(*batch, 2)`; for a single run, `batch = ()`, its one key), or one key (`()` typed, or raw
    `(2,)` uint32 from `jax.random.PRNGKey`) for the whole batch."""
    if not isinstance(key, jax.Array):
        key = jnp.asarray(key)
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        typed = key
    elif key.dtype == jnp.uint32 and key.ndim >= 1 and key.shape[-1] == 2:
        typed = jax.random.wrap_key_data(key)
    else:
        raise TypeError(
            f"{name} must be a JAX PRNG key (jax.random.key(seed) or jax.random.PRNGKey(seed)) "
            f"or one per run, got dtype {key.dtype} and shape {tuple(key.shape)}"
        )
    if typed.shape == tuple(batch):  # (first: a single run's one key is its own key)
        return typed, True
    if typed.shape == ():
        return typed, False
    raise ValueError(
        f"{name} must be one key or one key per run (batch shape {tuple(batch)}), got "
        f"{typed.shape} keys; e.g. jax.random.split(key, {tuple(batch) or 1})"
    )


def normals(key: KeyLike, batch: tuple[int, ...], shape: tuple[int, ...], dtype) -> Array:
    """Standard normals of shape `(*batch, *shape)`: drawn at once from one key, or per run
    from a key per run (so that each run's draws depend on its own key only)."""
    typed, per_run = keys_for(key, batch)
    if not per_run:
        return jax.random.normal(typed, (*batch, *shape), dtype)
    flat = typed.reshape(-1)
    out = jax.vmap(lambda k: jax.random.normal(k, shape, dtype))(flat)
    return out.reshape(*batch, *shape)


def _level(x: RealLike, name: str, unit: str) -> Array:
    return check_nonnegative(
        as_float(x, name), name, unit, hint=f"; give the noise level {name} ≥ 0"
    )


def gyro(
    key: KeyLike,
    ts: Annotated[RealLike, "*#batch T"],
    omega: Annotated[RealLike, "*#batch T 3"] | None,
    *,
    arw: RealLike,
    rrw: RealLike,
    bias0: Annotated[RealLike, "*#batch 3"] | None = None,
    scale_factor: Annotated[RealLike, "*#batch 3"] | None = None,
    misalignment: Annotated[RealLike, "*#batch 3 3"] | None = None,
    omega_mean: Annotated[RealLike, "*#batch T-1 3"] | None = None,
) -> tuple[Float[Array, "*batch n 3"], Float[Array, "*batch T 3"]]:
    """Farrenkopf's rate gyro (module docstring): returns `(rate (..., T−1, 3), bias (..., T, 3))`,
    `rate[k]` the measured mean rate over `[ts[k], ts[k+1]]`

        rate[k] = M ω̄_k + β̄_k + (arw/√Δ_k) N(0, I),   M = I + diag(scale_factor) + misalignment,

    `ω̄_k = (omega[k] + omega[k+1])/2` (or `omega_mean[k]`), `β̄_k` the mean bias over the
    interval, drawn jointly with the increment `bias[k+1] − bias[k] ~ N(0, rrw² Δ_k I)`
    (covariance `rrw² Δ [[1, 1/2], [1/2, 1/3]]`); `bias[0] = bias0` (zero by default).

    `key`: one PRNG key, or one per run (shape of the batch). `ts (..., T)` strictly increasing;
    `omega (..., T, 3)` the true body rate at `ts` (rad/s); `arw` (rad/√s) and `rrw`
    (rad/s^1.5) scalars, or arrays broadcasting against `rate` (e.g. `(3,)` per axis);
    `scale_factor (..., 3)` and `misalignment (..., 3, 3)` (dimensionless, small) optional."""
    ts = as_float(ts, "ts")
    if ts.ndim < 1 or ts.shape[-1] < 2:
        raise ValueError(f"ts must have shape (..., T) with T ≥ 2 times, got {tuple(ts.shape)}")
    if omega_mean is not None:
        mean = check_finite(vector(omega_mean, 3, "omega_mean"), "omega_mean")
        if mean.ndim < 2 or mean.shape[-2] != ts.shape[-1] - 1:
            raise ValueError(
                f"omega_mean must have shape (..., T−1, 3) = (..., {ts.shape[-1] - 1}, 3), "
                f"got {tuple(mean.shape)}"
            )
    elif omega is None:
        raise ValueError("give omega (..., T, 3), the true rate at ts, or omega_mean")
    else:
        om = check_finite(vector(omega, 3, "omega"), "omega")
        if om.ndim < 2 or om.shape[-2] != ts.shape[-1]:
            raise ValueError(
                f"omega must have shape (..., T, 3) with T = len(ts) = {ts.shape[-1]}, got "
                f"{tuple(om.shape)}"
            )
        mean = 0.5 * (om[..., 1:, :] + om[..., :-1, :])
    dt = ts[..., 1:] - ts[..., :-1]
    dt = validate(
        dt,
        lambda xp, d: ~((d > 0) & xp.isfinite(d)),
        "ts must be strictly increasing and finite",
        lambda d: f": the first bad interval is ts[{int(np.flatnonzero(~(d.ravel() > 0))[0])}:]",
    )
    arw, rrw = _level(arw, "arw", "rad/√s"), _level(rrw, "rrw", "rad/s^1.5")
    b0 = jnp.zeros(3) if bias0 is None else check_finite(vector(bias0, 3, "bias0"), "bias0")
    gain = None
    if scale_factor is not None:
        s = check_finite(vector(scale_factor, 3, "scale_factor"), "scale_factor")
        gain = jnp.eye(3, dtype=s.dtype) + s[..., :, None] * jnp.eye(3, dtype=s.dtype)
    if misalignment is not None:
        m = as_float(misalignment, "misalignment")
        if m.shape[-2:] != (3, 3):
            raise ValueError(f"misalignment must have shape (..., 3, 3), got {tuple(m.shape)}")
        m = check_finite(m, "misalignment")
        gain = (jnp.eye(3, dtype=m.dtype) if gain is None else gain) + m
    batch = broadcast_batch(
        ts=ts.shape[:-1],
        omega=mean.shape[:-2],
        bias0=b0.shape[:-1],
        **({} if gain is None else {"scale_factor/misalignment": gain.shape[:-2]}),
    )
    # the data's dtype (the rates and times): the noise levels, bias and gains are cast to it,
    # so float32 data give float32 under x64 whatever the levels' type (np.deg2rad(x) / 60 is a
    # NumPy float64)
    dtype = jnp.result_type(mean, dt)
    arw, rrw = arw.astype(dtype), rrw.astype(dtype)
    gain = None if gain is None else gain.astype(dtype)
    T1 = mean.shape[-2]
    for name, level in (("arw", arw), ("rrw", rrw)):
        shape = (*batch, T1, 3)
        broadcast_level(level.shape, shape, name, f"to the rate's shape (..., T−1, 3) = {shape}")
    z = normals(key, batch, (T1, 3, 3), dtype)
    sdt = jnp.sqrt(dt)[..., None]
    step = rrw * sdt * z[..., 1]  # β_{k+1} − β_k
    mean_dev = rrw * sdt * (0.5 * z[..., 1] + z[..., 2] / (2 * math.sqrt(3.0)))  # β̄_k − β_k
    b0 = jnp.broadcast_to(b0, (*batch, 3)).astype(dtype)
    bias = jnp.concatenate([b0[..., None, :], b0[..., None, :] + jnp.cumsum(step, axis=-2)], -2)
    true = mean if gain is None else jnp.einsum("...ij,...tj->...ti", gain, mean)
    rate = true + bias[..., :-1, :] + mean_dev + arw / sdt * z[..., 0]
    return rate, bias


def star_tracker(
    key: KeyLike, q: Annotated[RealLike, "*#batch 4"], sigma: RealLike
) -> Float[Array, "*batch 4"]:
    """A star tracker's attitude `q ∘ δq(n)`, `n ~ N(0, sigma²)` per body axis (rad): `q (..., 4)`
    the true attitude (body → space), `sigma` a scalar or `(3,)` per body axis (e.g. a larger
    roll error about the boresight). `key`: one PRNG key, or one per quaternion (shape
    `q.shape[:-1]`)."""
    q = quat.normalize(check_finite(vector(q, 4, "q"), "q"))
    sigma = _level(sigma, "sigma", "rad")
    noise = (*q.shape[:-1], 3)
    broadcast_level(sigma.shape, noise, "sigma", f"to the noise's shape (..., 3) = {noise}")
    n = normals(key, q.shape[:-1], (3,), q.dtype) * sigma.astype(q.dtype)  # (q's dtype)
    return quat.mul(q, quat.from_rotvec(n))
