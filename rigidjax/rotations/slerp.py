"""Piecewise spherical linear interpolation through key attitudes, as SciPy's `Slerp`.

Between key times `t_k ≤ t ≤ t_{k+1}`: `q(t) = q_k ∘ exp(α θ_k)`, `α = (t − t_k)/(t_{k+1} − t_k)`,
`θ_k = log(q_k⁻¹ ∘ q_{k+1})` with `|θ_k| ≤ π` (the shorter arc; SciPy's `as_rotvec`).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import Check, as_float, floats, validate_all, vector
from .._custom_types import Quat, QuatLike, RealLike
from . import _validation as _v
from ._quat_core import _from_rotvec, _to_rotvec, _unit, conj, mul

__all__ = ["Slerp", "key_frames"]


def key_frames(ts: RealLike, q: QuatLike) -> tuple[Float[Array, " N"], Float[Array, "N 4"]]:
    """Key times `(N,)` (finite, strictly increasing, N ≥ 2) and unit key quaternions `(N, 4)`,
    checked with SciPy's messages (and the fix)."""
    ts, q = floats((ts, "ts"), (q, "q"))
    q = vector(q, 4, "q")
    if q.ndim != 2:
        raise ValueError(
            f"q must have shape (N, 4), got {tuple(q.shape)}: Rotations with more than 1 leading "
            "dimension are not supported (use jax.vmap for a batch of interpolations)"
        )
    if q.shape[0] < 2:
        raise ValueError(
            f"`rotations` must be a sequence of at least 2 rotations: q has shape {q.shape}"
        )
    if ts.ndim != 1:
        raise ValueError(
            f"Expected times to be specified in a 1 dimensional array, got {ts.ndim} dimensions "
            f"(ts has shape {tuple(ts.shape)})"
        )
    if ts.shape[0] != q.shape[0]:
        raise ValueError(
            "Expected number of rotations to be equal to number of timestamps given, got "
            f"{q.shape[0]} rotations and {ts.shape[0]} timestamps (q has shape {q.shape}, ts "
            f"{ts.shape})"
        )

    def bad(xp: Any, t: Any) -> Any:
        return ~xp.all(xp.isfinite(t)) | xp.any(~(t[1:] > t[:-1]))

    def detail(t: np.ndarray) -> str:
        if not np.all(np.isfinite(t)):
            k = int(np.flatnonzero(~np.isfinite(t))[0])
            return f": ts[{k}] = {t[k]}"
        k = int(np.flatnonzero(~(t[1:] > t[:-1]))[0])
        return f": ts[{k + 1}] = {t[k + 1]} follows ts[{k}] = {t[k]}"

    check = Check(
        bad,
        "Values in `ts` must be finite and in a strictly increasing order",
        detail,
        "; drop or merge repeated key times (one attitude per time)",
    )
    return validate_all(ts, [check]), _unit(q, "q")


def _with_last_sign(q: Array, t: Array, times: Array, keys: Array, end: Array) -> Array:
    """`q (..., 4)` at times `t` with the last key's sign from its time on: the last segment,
    from `keys[-2]`, ends at `end`, which is ±`keys[-1]` (the shorter arc)."""
    flip = (t >= times[-1]) & (jnp.sum(end * keys[-1], -1) < 0)
    return jnp.where(flip[..., None], -q, q)


class Slerp(eqx.Module):
    """Spherical linear interpolation between consecutive key attitudes (SciPy's `Slerp`).

    `Slerp(ts, q)`: key times `ts (N,)`, strictly increasing, and key attitudes `q (N, 4)`
    (scalar-first, treated as unit), N ≥ 2. `slerp(t)` for times `t` of any shape returns unit
    quaternions `t.shape + (4,)`; `t` must lie in `[ts[0], ts[-1]]` (SciPy's ValueError, a
    run-time error under `jit`). Each key keeps its sign; between keys the shorter arc is taken.
    An equinox Module: `jit`, `vmap` and `grad` with respect to `ts`, `q` and `t`.
    """

    times: Float[Array, " N"]
    keys: Float[Array, "N 4"]
    rotvecs: Float[Array, "M 3"]

    def __init__(self, ts: RealLike, q: QuatLike):
        self.times, self.keys = key_frames(ts, q)
        self.rotvecs = _to_rotvec(mul(conj(self.keys[:-1]), self.keys[1:]))

    def __call__(self, t: RealLike) -> Quat:
        t = _v.check_finite(as_float(t, "t"), "t", 0).astype(self.times.dtype)
        t0, t1 = self.times[0], self.times[-1]

        def outside(xp: Any, x: Any) -> Any:
            return (x[0] < x[1]) | (x[0] > x[2])

        def detail(x: np.ndarray) -> str:
            k = _v.first(outside(np, x))
            return f": [{x[1][k]}, {x[2][k]}], got {_v.at('t', k)} = {x[0][k]}"

        # (t, t0, t1) together: checked in NumPy when all three are concrete
        x = jnp.stack([t, *jnp.broadcast_arrays(t0, t1, t)[:2]])
        t = validate_all(
            x,
            [
                Check(
                    outside,
                    "Interpolation times must be within the range [ts[0], ts[-1]], both inclusive",
                    detail,
                    "; Slerp does not extrapolate",
                )
            ],
            on=t,
        )
        n = self.times.shape[0]
        idx = jnp.clip(jnp.searchsorted(self.times, t, side="right") - 1, 0, n - 2)
        alpha = (t - self.times[idx]) / (self.times[idx + 1] - self.times[idx])
        q = mul(self.keys[idx], _from_rotvec(alpha[..., None] * self.rotvecs[idx]))
        end = mul(self.keys[-2], _from_rotvec(self.rotvecs[-1]))
        return _with_last_sign(q, t, self.times, self.keys, end)
