"""Sampled-data control with a zero-order hold: the command `controller(t_k, Ω_k, q_k, params)`
is computed at the samples `t_k = t0 + k T_c` and held until the next one, as flight software
runs (Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed., §4.3). The
solve steps from grid point to grid point of `ts ∪ {t_k}`, so every step of a fixed-step method
lies within one hold interval: the right-hand side is smooth in each step, and the method keeps
its order. The command is part of the state (zero derivative), set by a jump map at the
samples, so that the whole loop is one model: one CPU kernel call for all steps and samples.

A controller with memory (`rigidjax.control.StatefulController`: a filter, simulated sensors
and their PRNG key) carries it the same way: the held part of the state is then
`(command ‖ log, memory)`, both set by the jump map, and the `log` recorded with the command.
A jump map the CPU kernel cannot take (random draws, for one) runs on the Diffrax path, with
the same steps."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import concrete_value
from .._custom_types import RealScalarLike
from .._integrate import SolveOptions, raise_failure
from ..events import Event
from ..models.solve import solve_tree

Controller = Callable[[Array, Array, Array, Any], Array]


def sample_grid(
    ts: np.ndarray, period: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`(grid, sample, out, src)`: the sorted union of the output times `ts` and the samples
    `ts[0] + k period < ts[-1]` (a sample within `1e-9` of the span from an output time is that
    output time), whether each grid point is a sample, the grid index of each output time, and
    where each grid point comes from: `src ≥ 0` the output time `ts[src]`, else the sample
    `k = −1 − src`."""
    if not period > 0:
        raise ValueError(f"control_period must be positive, got {period}")
    span = ts[-1] - ts[0]
    tol = 1e-9 * span
    count = int(np.ceil(span / period * (1 - 1e-12)))
    samples = ts[0] + period * np.arange(count)
    near = np.searchsorted(ts, samples)
    new, new_k = [], []
    sample_at = np.zeros(ts.shape[0], bool)
    for i, (s, k) in enumerate(zip(samples, near, strict=True)):
        hits = [j for j in (k - 1, k) if 0 <= j < ts.shape[0] and abs(ts[j] - s) <= tol]
        if hits:
            sample_at[hits[0]] = True
        else:
            new.append(s)
            new_k.append(i)
    grid = np.concatenate([ts, np.asarray(new, ts.dtype)])
    sample = np.concatenate([sample_at, np.ones(len(new), bool)])
    src = np.concatenate([np.arange(ts.shape[0]), -1 - np.asarray(new_k, int)])
    order = np.argsort(grid, kind="stable")
    out = np.argsort(order)[: ts.shape[0]]
    return grid[order], sample[order], out, src[order]


class _Held(eqx.Module):
    """The field on the state `(y, command)`: `vf(t, y, (*args, command))`, the command held
    (zero derivative); with memory (`m` given), on `(y, (command ‖ log, memory))`, the first
    `m` entries the command, all of it held."""

    vf: Callable
    m: int | None = eqx.field(static=True, default=None)

    def __call__(self, t, y, args):
        state, held = y
        cmd = held if self.m is None else held[0][: self.m]
        zero = jax.tree_util.tree_map(jnp.zeros_like, held)
        return self.vf(t, state, (*args, cmd)), zero


class _Sample(eqx.Module):
    """The jump map at a sample: `(y, command) ← (y, command(t, y))`; with memory,
    `(y, (_, memory)) ← (y, (command ‖ log, memory'))`, `(command, memory', log) =
    command(t, y, memory)`."""

    command: Callable
    memory: bool = eqx.field(static=True, default=False)

    def __call__(self, t, y, args):
        state, held = y
        if not self.memory:
            return state, self.command(t, state)
        cmd, memory, log = self.command(t, state, held[1])
        return state, (jnp.concatenate([cmd, log.astype(cmd.dtype)]), memory)


def held_solve(
    vf: Callable,
    command: Callable[..., Any],
    y0: Any,
    args: tuple,
    ts: Array,
    times: np.ndarray | None,
    period: RealScalarLike,
    cmd0: Array,
    options: SolveOptions,
    *,
    unit: tuple[int, ...],
    name: str,
    memory0: Any = None,
    log_size: int = 0,
    event: Event | None = None,
) -> tuple[Any, dict[str, Array], diffrax.RESULTS, Array, Array, Array | None]:
    """Integrate `vf(t, y, (*args, cmd))` with the command `cmd = command(t_k, y_k)` sampled at
    `ts[0] + k period` and held (`cmd0` before the first sample; `times`: the values of `ts`,
    None where they are not known at trace time): one solve over the grid of
    `sample_grid`, the command a state with zero derivative that a jump map sets at the samples
    (`solve_tree` with `jump`: inside the CPU kernel, or a solve per grid interval on the
    Diffrax path). Returns `(ys (T, ...), stats, result, control_ts (K,), commands (K, m),
    event_t)`, raising a failure (`options.throw`) at the output interval where it happened;
    `event`: a `rigidjax.Event` on `(t, Ω, q)` of the state `(Ω, q, ...)`, its time `event_t`
    (None without one).

    With `memory0` (a controller's memory, a PyTree), `command(t_k, y_k, memory) -> (cmd,
    memory, log (log_size,))` and the commands returned are `(K, m + log_size)`: each command
    followed by its log."""
    value = concrete_value(period)
    if times is None or value is None:
        raise ValueError(
            "with a controller, ts and control_period must be concrete (not traced under "
            "jit): the sample grid is built from them; close over them instead of passing "
            "them as traced arguments"
        )
    if value.ndim != 0 or value.dtype == bool:
        raise ValueError(f"control_period must be a number, got {period!r}")
    period = float(value)
    grid_np, sample_np, out, src = sample_grid(times, period)
    # the grid's values, with the derivatives of the times it is made of: a sample's, ts[0] +
    # k period (also where it is an output time), else the output time's; differentiating ts
    # moves the outputs and the samples with it
    last = np.arange(grid_np.shape[0]) == grid_np.shape[0] - 1  # (no jump there)
    at_sample = sample_np & ~last
    steps = jnp.asarray(period * np.rint((grid_np - times[0]) / period), ts.dtype)
    made_of = jnp.where(at_sample, ts[0] + steps, ts[np.maximum(src, 0)])
    grid = jnp.asarray(grid_np, ts.dtype) + (made_of - jax.lax.stop_gradient(made_of))
    inner = dataclasses.replace(options, throw=False)
    keep = np.zeros(grid_np.shape[0], bool)
    keep[out] = True
    stateful = memory0 is not None
    m = cmd0.shape[-1]
    if stateful:
        log0 = jnp.zeros(log_size, cmd0.dtype)
        held0: Any = (jnp.concatenate([cmd0, log0]), memory0)
    else:
        held0 = cmd0
    (ys, _), stats, result = solve_tree(
        _Held(vf, m if stateful else None), grid, (y0, held0), args, inner, unit=unit,
        name=name, jump=_Sample(command, stateful), jumps=sample_np[:-1], keep=keep,
        record=len(jax.tree_util.tree_leaves(y0)),
        event=None if event is None else event.on_state(_held_omega_quat),
    )  # fmt: skip
    commands = stats.pop("recorded")
    control_ts = grid[np.flatnonzero(sample_np[:-1])]
    # an output time that is also a sample: its grid point moves with the sample, so the
    # output's own derivative is added, the field's just after the sample (with its command)
    merged = np.flatnonzero(at_sample[out] & (np.arange(len(out)) > 0))
    if merged.size:
        g = out[merged]
        k = np.cumsum(sample_np)[g] - 1  # (the samples' commands, in grid order)
        moved = ts[merged] - grid[g]
        moved = moved - jax.lax.stop_gradient(moved)  # (zero: a derivative only)
        cmd = commands[k, :m]
        state = jax.tree_util.tree_map(lambda y: y[merged], ys)
        rate = jax.vmap(lambda t, y, u: vf(t, y, (*args, u)))(grid[g], state, cmd)
        ys = jax.tree_util.tree_map(
            lambda y, r: y.at[merged].add(r * moved.reshape(-1, *[1] * (r.ndim - 1))), ys, rate
        )
    if options.throw:

        def probe(k: int) -> str | None:
            """The controller, if it returned a non-finite command in `[ts[k-1], ts[k])`."""
            inside = (control_ts >= ts[k - 1]) & (control_ts < ts[k])
            bad = inside & ~jnp.all(jnp.isfinite(commands[..., :m]), axis=-1)
            if not bool(jnp.any(bad)):
                return None
            t = float(control_ts[int(jnp.argmax(bad))])
            return (
                f"the controller returned a non-finite command (NaN or inf) at the sample "
                f"t = {t:.6g}: make controller(t_k, omega_k, q_k, params) finite there"
            )

        ys = raise_failure(result, stats["num_valid"], ts, ys, options.max_steps, probe)
    event_t = stats.pop("event_t", None)
    return ys, stats, result, control_ts, commands, event_t


def _held_omega_quat(y: tuple) -> tuple[Array, Array]:
    """`(Ω, q)` of a held solve's state `((Ω, q, ...), held)`."""
    return y[0][0], y[0][1]
