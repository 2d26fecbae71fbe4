"""Sampled-data control with a zero-order hold: the command `controller(t_k, Ω_k, q_k, params)`
is computed at the samples `t_k = t0 + k T_c` and held until the next one, as flight software
runs (Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed., §4.3). The
solve steps from grid point to grid point of `ts ∪ {t_k}` inside one `lax.scan`, so every step
of a fixed-step method lies within one hold interval: the right-hand side is smooth in each
step, and the method keeps its order."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import is_concrete
from .._integrate import SolveOptions, raise_failure

Controller = Callable[[Array, Array, Array, Any], Array]
Step = Callable[[Array, Any, Array, SolveOptions], tuple[Any, dict[str, Array], Any]]


def sample_grid(ts: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(grid, sample, out)`: the sorted union of the output times `ts` and the samples
    `ts[0] + k period < ts[-1]` (a sample within `1e-9` of the span from an output time is that
    output time), whether each grid point is a sample, and the grid index of each output time."""
    if not period > 0:
        raise ValueError(f"control_period must be positive, got {period}")
    span = ts[-1] - ts[0]
    tol = 1e-9 * span
    count = int(np.ceil(span / period * (1 - 1e-12)))
    samples = ts[0] + period * np.arange(count)
    near = np.searchsorted(ts, samples)
    new = []
    sample_at = np.zeros(ts.shape[0], bool)
    for s, k in zip(samples, near, strict=True):
        hits = [j for j in (k - 1, k) if 0 <= j < ts.shape[0] and abs(ts[j] - s) <= tol]
        if hits:
            sample_at[hits[0]] = True
        else:
            new.append(s)
    grid = np.concatenate([ts, np.asarray(new, ts.dtype)])
    sample = np.concatenate([sample_at, np.ones(len(new), bool)])
    order = np.argsort(grid, kind="stable")
    out = np.argsort(order)[: ts.shape[0]]
    return grid[order], sample[order], out


def held_solve(
    step: Step,
    command: Callable[[Array, Any], Array],
    y0: Any,
    ts: Array,
    period: float,
    cmd0: Array,
    options: SolveOptions,
) -> tuple[Any, dict[str, Array], diffrax.RESULTS, Array, Array]:
    """Integrate with a held command: `step(t01 (2,), y, cmd, options) -> (ys, stats, result)`
    one grid interval with the command `cmd` fixed; `command(t_k, y_k)` the new command at a
    sample. Returns `(ys (T, ...), stats, result, control_ts (K,), commands (K, m))`, raising a
    failure (`options.throw`) at the output interval where it happened."""
    if not (is_concrete(ts) and isinstance(period, int | float | np.floating)):
        raise ValueError(
            "with a controller, ts and control_period must be concrete (not traced under "
            "jit): the sample grid is built from them; close over them instead of passing "
            "them as traced arguments"
        )
    grid_np, sample_np, out = sample_grid(np.asarray(ts), float(period))
    grid = jnp.asarray(grid_np, ts.dtype)
    inner = dataclasses.replace(options, throw=False)
    keys = ("num_steps", "num_accepted_steps", "num_rejected_steps")

    def interval(carry, x):
        y, cmd, result = carry
        ta, tb, sample = x
        cmd = jnp.where(sample, command(ta, y), cmd)
        ys, stats, res = step(jnp.stack([ta, tb]), y, cmd, inner)
        y1 = jax.tree_util.tree_map(lambda a: a[-1], ys)
        result = diffrax.RESULTS.where(result == diffrax.RESULTS.successful, res, result)
        counts = jnp.stack([stats[k] for k in keys])
        return (y1, cmd, result), (y1, cmd, counts, result == diffrax.RESULTS.successful)

    init = (y0, cmd0, diffrax.RESULTS.successful)
    xs = (grid[:-1], grid[1:], jnp.asarray(sample_np[:-1]))
    (_, _, result), (ys, cmds, counts, valid) = jax.lax.scan(interval, init, xs)
    ys = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b])[out], y0, ys)
    stats: dict[str, Array] = dict(zip(keys, jnp.sum(counts, axis=0), strict=True))
    stats["num_valid"] = 1 + jnp.sum(valid[out[1:] - 1])
    if options.throw:
        ys = raise_failure(result, stats["num_valid"], ts, ys, options.max_steps)
    at = np.flatnonzero(sample_np[:-1])
    return ys, stats, result, grid[at], cmds[at]
