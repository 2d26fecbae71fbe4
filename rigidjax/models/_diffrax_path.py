"""The Diffrax path of a `Model` (`models.solve`'s fallback and reference): the component state
(N arrays of the bodies), the scalar program of the kernels or the model's own field, each
body its own adaptive steps, jump maps interval by interval, events."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jaxtyping import Array

from .._batch import first_failure
from .._integrate import (
    SolveOptions,
    solve_saved,
)
from ..kernels import model as model_kernel
from ..solvers.explicit_rk import ExplicitRK
from .model import Model

if TYPE_CHECKING:
    from ..events import Event


class BatchMaxRMS(eqx.Module):
    """Error norm of a batch integrated as one state: the largest per-member RMS, so every
    member meets the tolerance (the default RMS over the whole batch would average it away).
    Squares are summed leaf by leaf: concatenating the leaves of the component state made
    adaptive solves collapse (Dopri8 on 600 bodies did not finish in 100 s; 8 ms now)."""

    axis: int = eqx.field(static=True)

    def __call__(self, y) -> Array:
        leaves = [jnp.moveaxis(jnp.atleast_1d(x), self.axis, 0) for x in jtu.tree_leaves(y)]
        squares = sum(jnp.sum((x * x).reshape(x.shape[0], -1), axis=1) for x in leaves)
        count = sum(math.prod(x.shape[1:]) for x in leaves)
        return jnp.sqrt(jnp.max(squares) / count)


def method_of(options: SolveOptions) -> diffrax.AbstractSolver:
    """The solver of `options`; without one, the method `solve_saved` runs by default
    (`ExplicitRK`'s)."""
    return ExplicitRK().method if options.solver is None else options.solver


class _Components(eqx.Module):
    """The model's field on the Diffrax path: the state is N component arrays `(B,)` (one body:
    scalars), the parameters P components (scalars where shared), the constants Pc scalars;
    `field` is the scalar program
    (`kernels.model.Hoisted.components`) or, for a field without one, the model's own field
    mapped over the bodies. The scalar program is one jitted call: traced once per solve, not
    once per stage and again per derivative of each (`jax.jacfwd` of the satellite, 16 bodies,
    50 steps: first call 6.9 s instead of 7.8 s, the closed loop 10.3 s instead of 12.7 s)."""

    field: Callable
    scalar: bool = eqx.field(static=True)
    apart: bool = eqx.field(static=True, default=False)  # `_materialized` (`APART_ABOVE`)

    def __call__(self, t, y, args):
        p, c = args
        if self.scalar:
            k = jax.jit(self.field)(t, y, p, c)
            return _materialized(k) if self.apart else k
        ys = jnp.stack(y, axis=-1)
        # no parameters: an empty `(P = 0,)` row, as `joined` makes for the kernels
        ps = jnp.stack(jnp.broadcast_arrays(*p), axis=-1) if p else jnp.zeros((0,), ys.dtype)
        if ys.ndim == 1:
            return tuple(self.field(t, ys, ps))
        ps = jnp.broadcast_to(ps, (*ys.shape[:-1], ps.shape[-1]))
        return tuple(jnp.moveaxis(jax.vmap(self.field, in_axes=(None, 0, 0))(t, ys, ps), -1, 0))


APART_ABOVE = 64
"""One body's solve passes its stages through `_materialized` where the scalar program has more
statements than this. `jax.jacfwd` of 100 bodies at rtol = atol = 1e-8 (`bench_modes.py`): the
damping torque (47 statements) 1.4 ms as it is, 6.4 ms through it; the gravity-gradient torque
with an event (110 statements, 16 bodies) 677 ms as it is, 2.2 ms through it."""


@jax.custom_jvp
def _materialized(k: tuple[Array, ...]) -> tuple[Array, ...]:
    """The field's components `k` themselves; their tangents (and, transposed, cotangents)
    go through one product with the identity, which XLA computes apart. Otherwise it fused
    each stage's tangents into every consumer, the Runge–Kutta stages into each other, and
    evaluated the whole chain again for each state component (`jax.jvp` of a gravity-gradient
    torque, 4 bodies, Tsit5 on the Diffrax path: 239 ms, now 1.5 ms). A tangent that is not
    finite makes every component's NaN."""
    return _apart(k)


def _apart(k: tuple[Array, ...]) -> tuple[Array, ...]:
    """`k` itself, through a sort by the components' index (already in order): XLA fuses no
    sort, so each component is computed once."""
    st = jnp.stack(k)
    key = jax.lax.broadcasted_iota(jnp.int32, st.shape, 0)
    return tuple(jax.lax.sort((key, st), dimension=0, num_keys=1)[1])


@_materialized.defjvp
def _materialized_jvp(primals, tangents):
    (k,), (dk,) = primals, tangents
    k = _apart(k)
    dk = jnp.stack(dk)
    eye = jnp.eye(dk.shape[0], dtype=dk.dtype)
    dk = jnp.tensordot(eye, dk, 1, precision=jax.lax.Precision.HIGHEST)
    return k, tuple(dk)


class _StepEnd(eqx.Module):
    """Step-end map of the component state: each unit group divided by its norm, then the
    model's map `end(y) -> (y', changed)` on each body, if any (`changed` anywhere: the next
    step re-evaluates a first-same-as-last stage)."""

    unit: tuple[tuple[int, int], ...] = eqx.field(static=True)
    end: Callable | None

    def __call__(self, y):
        y = list(y)
        for a, m in self.unit:
            r = jax.lax.rsqrt(sum(y[j] * y[j] for j in range(a, a + m)))
            for j in range(a, a + m):
                y[j] = y[j] * r
        if self.end is None:
            return tuple(y), jnp.array(False)
        stacked, end = jnp.stack(y, axis=-1), self.end
        for _ in range(stacked.ndim - 1):  # the bodies' axes
            end = jax.vmap(end)
        out, changed = end(stacked)
        return tuple(jnp.moveaxis(out, -1, 0)), jnp.any(changed)


Backend = Callable[..., Any]
"""`(y0 (B, N), blocks, c (Pc,), ts (T,)) -> ((ys (S, B, N), recorded (J, B, NR)[, event_t]),
(stats, result))`: one backend's solve (`S` the kept times, `J` the recorded jumps; with an
event, its time `(B,)`, a scalar for one body)."""


def diffrax_backend(
    problem: tuple,
    options: SolveOptions,
    adjoint: diffrax.AbstractAdjoint | None = None,
    *,
    values: bool = False,
    event: Event | None = None,
) -> Backend:
    """The Diffrax path's solve of `problem` (`(model, hoisted, single, jumps, keep)`) with
    `options` (and `adjoint`, if given); `values`: the states and records only (and the event's
    time); `event`: as `solve_model`'s (its time after the records)."""
    model, hoisted, single, jumps, keep = problem
    if adjoint is not None:
        options = dataclasses.replace(options, adjoint=adjoint)
    kept = np.flatnonzero(keep)

    def backend(y0, blocks, c, ts):
        p = joined(list(blocks), ts.dtype)
        if jumps is not None:
            args = (model, hoisted, ts, y0, p, c, options, single)
            ys, stats, result = diffrax_jumps(args, jumps, event)
        else:
            ys, stats, result = solve_components(
                model, hoisted, ts, y0, p, c, options, single, event
            )
        R0, NR = model.record
        at = np.flatnonzero(jumps) + 1 if NR and jumps is not None else np.zeros(0, int)
        out = (ys[kept], ys[at, :, R0 : R0 + NR])
        if event is not None:  # the event's time: a value, differentiated with the states
            out = (*out, stats.pop("event_t"))
        if values:
            return out
        stats["num_valid"] = jnp.sum(jnp.asarray(kept) < stats["num_valid"])
        return out, (stats, result)

    return backend


def diffrax_jumps(
    problem: tuple, jumps: np.ndarray, event: Event | None = None
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """The Diffrax path of a model with a jump map (`problem`: `solve_components`'s arguments): one
    solve per interval of `ts` inside a `lax.scan`, each started by the jump map where `jumps`
    flags it (the scalar program of `hoisted`, or the model's own map). With an `event` (each
    body its own solves), its first time `stats["event_t"]`; after a terminating one the state
    is held (no jump, empty solves)."""
    model, hoisted, ts, y0, p, c, options, single = problem
    if event is not None and y0.shape[0] > 1:

        def one(y, pb):
            return diffrax_jumps((model, hoisted, ts, y, pb, c, options, True), jumps, event)

        return each_body(one, y0, p)
    jump = cast(Callable, model.jump)
    pb = jnp.broadcast_to(p, (y0.shape[0], p.shape[1]))

    def apply(t, y):
        if hoisted is None:
            return jax.vmap(jump, in_axes=(None, 0, 0))(t, y, pb)
        out = hoisted.jump_components(t, tuple(y.T), tuple(pb.T), c)
        return jnp.stack(out, axis=-1)

    keys = ("num_steps", "num_accepted_steps", "num_rejected_steps")
    holds = event is not None and event.terminate

    def interval(carry, x):
        y, result, t_event = carry
        ta, tb, flag = x
        stopped = jnp.isfinite(t_event) & holds  # (by a terminating event: held)
        y = jnp.where(flag & ~stopped, apply(ta, y), y)
        t01 = jnp.stack([ta, jnp.where(stopped, ta, tb)])
        ys, stats, res = solve_components(model, hoisted, t01, y, p, c, options, single, event)
        if event is not None:
            t_event = jnp.where(jnp.isinf(t_event), jnp.reshape(stats["event_t"], ()), t_event)
        y1 = ys[-1]
        result = diffrax.RESULTS.where(result == diffrax.RESULTS.successful, res, result)
        counts = jnp.stack([stats[k] for k in keys])
        return (y1, result, t_event), (y1, counts, res == diffrax.RESULTS.successful)

    init = (y0, diffrax.RESULTS.successful, jnp.asarray(jnp.inf, ts.dtype))
    xs = (ts[:-1], ts[1:], jnp.asarray(jumps))
    (_, result, t_event), (ys, counts, valid) = jax.lax.scan(interval, init, xs)
    stats: dict[str, Array] = dict(zip(keys, jnp.sum(counts, axis=0), strict=True))
    stats["num_valid"] = 1 + jnp.sum(jnp.cumprod(valid))
    if event is not None:
        stats["event_t"] = t_event
    return jnp.concatenate([y0[None], ys]), stats, result


def each_body(
    solve_one: Callable, y0: Array, p: Array
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """`solve_one(y (1, N), p (1, P)) -> (ys (T, 1, N), stats, result)` mapped over the bodies
    of `y0 (B, N)` and `p (B or 1, P)` (`jax.vmap`: each body its own steps and events), joined
    into `(ys (T, B, N), stats (B,) each, the batch's first failure)`."""
    p_axis = 0 if p.shape[0] > 1 else None

    def one(y, pb):
        ys, stats, result = solve_one(y[None], pb[None] if p_axis == 0 else pb)
        return ys[:, 0], stats, result

    ys, stats, results = jax.vmap(one, in_axes=(0, p_axis))(y0, p)
    stats, result = first_failure(stats, results)
    return jnp.moveaxis(ys, 0, 1), stats, result


@functools.partial(jax.jit, static_argnums=1)
def joined(blocks: list[Array], dtype) -> Array:
    """The parameters `(Bp, P)` from their blocks of columns `(Bp or 1, Pj)` (one compiled
    program)."""
    rows = max((b.shape[0] for b in blocks), default=1)
    parts = [jnp.broadcast_to(b, (rows, b.shape[1])).astype(dtype) for b in blocks]
    return jnp.concatenate([*parts, jnp.zeros((rows, 0), dtype)], axis=1)


def solve_components(
    model: Model,
    hoisted: model_kernel.Hoisted | None,
    ts: Array,
    y0: Array,
    p: Array,
    c: Array,
    options: SolveOptions,
    single: bool,
    event: Event | None = None,
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """The Diffrax path on the component state: the scalar program of `hoisted` (constants
    `c`), or the model's own field where it has none. Adaptive steps (or an `event`) for
    several bodies: the one-body solve (`single`) mapped over them (`jax.vmap`), each body
    with its own steps (the same numbers as alone, or as `jax.vmap` of the one-body solve);
    the step counts `(B,)`, `num_valid` and `result` the batch's first failure. Fixed steps
    keep one state for the batch (the same steps for every body)."""
    adaptive = not isinstance(options.stepsize_controller, diffrax.ConstantStepSize)
    if not single and y0.shape[0] > 1 and (adaptive or event is not None):

        def one(y, pb):
            return solve_components(model, hoisted, ts, y, pb, c, options, True, event)

        return each_body(one, y0, p)
    field = model.field if hoisted is None else hoisted.components
    shared = p.shape[0] == 1
    comps = (lambda a: tuple(a[0])) if (single or shared) else (lambda a: tuple(a.T))
    y_init = tuple(y0[0]) if single else tuple(y0.T)
    apart = single and hoisted is not None and hoisted.operations > APART_ABOVE
    ys, stats, result = solve_saved(
        diffrax.ODETerm(_Components(field, hoisted is not None, apart)),
        ts,
        y_init,
        options,
        # the constants as components too, split once here: indexed in the field, each
        # stage's cotangent of `c` was a chain of pads that XLA fused with the whole transposed
        # field, evaluated again for each pad (`jax.grad` of a gravity-gradient torque with a
        # traced gain, 4 bodies, Tsit5: 188 ms, now 5 ms)
        args=(comps(p), tuple(c)),
        step_end=_StepEnd(model.unit, model.end) if model.unit or model.end else None,
        norm=BatchMaxRMS(-1),
        event=None if event is None else event.on_state(stacked if single else columns),
    )
    ys = jnp.stack(ys, axis=-1)  # (T, B, N) or (T, N)
    return (ys[:, None] if single else ys), stats, result


def stacked(y: tuple[Array, ...]) -> tuple[Array]:
    """`(y (N,),)` from one body's components."""
    return (jnp.stack(y),)


def columns(y: tuple[Array, ...]) -> tuple[Array]:
    """`(y (N,),)` from the components `(1,)` of a batch of one body."""
    return (jnp.stack(y, axis=-1)[0],)
