"""The kernels as backends of `models.solve`: the CPU kernel at fixed steps (`cpu_backend`), the
adaptive CPU kernel (`adaptive_backend`), the Pallas kernel (`gpu_backend`) and the adaptive
Pallas kernel (`adaptive_gpu_backend`); each a `Backend` with the steps and failures of
`solve_saved`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array

from .._checks import is_concrete
from .._integrate import (
    SolveOptions,
    fixed_step_count,
)
from ..events import Event
from ..kernels import (
    adaptive,
    model_pallas,
    model_pallas_adaptive,
    model_pallas_adaptive_back,
    model_pallas_back,
)
from ..kernels import model as model_kernel
from ..solvers.explicit_rk import ExplicitRK
from . import _adaptive
from ._diffrax_path import Backend, diffrax_backend, joined, method_of
from .model import Model


def kernel_options(options: SolveOptions) -> bool:
    """Whether `options` ask for what the kernels integrate: fixed steps `dt0`
    (`diffrax.ConstantStepSize`), reverse-mode (default) adjoint, no Diffrax progress meter;
    the method is checked by the kernel (`free_body.METHODS`)."""
    return (
        isinstance(options.stepsize_controller, diffrax.ConstantStepSize)
        and options.dt0 is not None
        and isinstance(options.adjoint, None | diffrax.RecursiveCheckpointAdjoint)
        and isinstance(options.progress_meter, None | diffrax.NoProgressMeter)
    )


Run = Callable[[Array, Array, Array, Array], Array]
"""`(n (K,), taken (K,), h (K,), t0 (K,)) -> states (B, T, N)`: a kernel's fixed steps."""


def kernel_solve(
    run: Run, ts: Array, options: SolveOptions, keep: np.ndarray | None = None
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """A kernel's solve with the steps of `solve_saved` (`n` equal steps of at most `dt0` per
    output interval) and its failures: more steps than `max_steps` (where Diffrax stops), or a
    non-finite state; returns `(states (B, T, N), stats, result)` (the caller raises a
    failure: `raise_failure`; forward mode: `_solve`'s `both_modes`). `keep`
    (booleans `(T,)`, the first and last true): the times whose states `run` returns; failures
    are then placed in the intervals between kept times."""
    width = ts[1:] - ts[:-1]
    n = fixed_step_count(width, jnp.asarray(options.dt0, ts.dtype))
    taken = jnp.minimum(n, options.max_steps).astype(jnp.int32)
    h = width / n
    # the kernel takes n, h and t0 mapped alike under `jax.vmap` (a mapped dt0 maps n and h)
    ys = run(n, taken, h, ts[:-1] + 0 * h)
    finite = jnp.all(jnp.isfinite(ys), axis=(0, 2))
    kept = np.arange(ts.shape[0]) if keep is None else np.flatnonzero(keep)
    over = jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(n > options.max_steps)])
    too_many = over[kept[1:]] > over[kept[:-1]]  # per kept interval
    fails = too_many | ~finite[1:]
    first = jnp.argmax(fails)
    result = diffrax.RESULTS.where(
        jnp.any(fails),
        diffrax.RESULTS.where(
            too_many[first],
            cast(diffrax.RESULTS, diffrax.RESULTS.max_steps_reached),
            cast(diffrax.RESULTS, diffrax.RESULTS.nonfinite),
        ),
        diffrax.RESULTS.successful,
    )
    num_steps = jnp.sum(taken)
    stats = dict(
        num_steps=num_steps,
        num_accepted_steps=num_steps,
        num_rejected_steps=0 * num_steps,
        num_valid=1 + jnp.where(jnp.any(fails), first, kept.size - 1),
    )
    return ys, stats, result


def cpu_backend(kernel, model: Model, options: SolveOptions, jumps, keep) -> Backend:
    """The CPU kernel's solve (`kernels.model.run`)."""

    def backend(y0, blocks, c, ts):
        dtype = ts.dtype
        pk = [b.astype(dtype) for b in blocks] + ([c[None]] if c.shape[0] else [])
        recorded = []

        def run(n, taken, h, t0):
            ys, rec = model_kernel.run(kernel, y0, pk, taken, h, t0, jumps, keep)
            recorded.append(rec)
            return ys

        ys, stats, result = kernel_solve(run, ts, options, keep)
        return (jnp.moveaxis(ys, 1, 0), jnp.moveaxis(recorded[0], 1, 0)), (stats, result)

    return backend


def adaptive_backend(
    kernel: adaptive.AdaptiveKernel, ctl, problem: tuple, options, event: Event | None = None
) -> Backend:
    """The adaptive CPU kernel's solve (`kernels.adaptive.run`; each body its own steps, its
    `event` located on the kernel: its time after the records), the output times and the
    events differentiated through the Diffrax path."""
    model, _, single, jumps, keep = problem
    checkpointed = diffrax.RecursiveCheckpointAdjoint()
    arrays, rest = eqx.partition(event, eqx.is_array)

    def backend(y0, blocks, c, ts):
        dtype, n = ts.dtype, len(blocks)
        pk = [b.astype(dtype) for b in blocks] + ([c[None]] if c.shape[0] else [])

        def through(y0, pk, ts, arrays):  # (the event's arrays: an operand of the kernel's rule)
            cc = pk[n][0] if len(pk) > n else jnp.zeros((0,), dtype)
            ev = eqx.combine(arrays, rest)
            solve = diffrax_backend(problem, options, checkpointed, values=True, event=ev)
            ys, rec, *event_t = solve(y0, tuple(pk[:n]), cc, ts)
            when = (
                jnp.reshape(event_t[0], y0.shape[:1])
                if event_t
                else jnp.full(y0.shape[:1], jnp.inf, dtype)
            )
            return jnp.moveaxis(ys, 0, 1), jnp.moveaxis(rec, 0, 1), when

        ys, rec, st, ev = adaptive.run(kernel, y0, pk, ts, ctl, through, jumps, keep, arrays)
        stats, result = _adaptive.per_body(st, single, np.flatnonzero(keep))
        out = (jnp.moveaxis(ys, 1, 0), jnp.moveaxis(rec, 1, 0))
        if event is not None:
            out = (*out, ev[0] if single else ev)
        return out, (stats, result)

    return backend


def adaptive_gpu_backend(
    solver: diffrax.AbstractSolver,
    ctl,
    problem: tuple,
    options,
    event: Event | None = None,
    fixed: bool = False,
) -> Backend:
    """The adaptive Pallas kernel's solve (`kernels.model_pallas_adaptive`, each body its own
    steps, adaptive or, `fixed`, fixed; in Pallas' interpreter where the backend is not a GPU:
    the tests), with a jump map's
    schedule and records as the CPU kernel's and an `event` located in the kernel (its time
    after the records). Reverse mode runs the kernel's own adjoint of the accepted steps
    (`model_pallas_adaptive_back.run_back`); where the output times are differentiated, or
    the model has a jump map or an event, the same per-body steps through the Diffrax path."""
    model, hoisted, single, jumps, keep = problem
    method = cast(type[diffrax.AbstractERK], type(solver))  # `serves` checked it
    spec = model_pallas.Spec(hoisted, model.unit, method, model.record, fixed)
    checkpointed = diffrax.RecursiveCheckpointAdjoint()
    arrays, rest = eqx.partition(event, eqx.is_array)
    interpret = jax.default_backend() != "gpu"
    own = jumps is None and event is None and keep.all() and not fixed  # the kernel's adjoint

    def forward(y0, p, c, ts, arrays):
        K = ts.shape[0] - 1
        sc = None if jumps is None else model_kernel.Schedule.of(K, jumps, keep, model.record[1])
        args = (spec, y0, _packed(p, c), ts, ctl)
        ys, rec, st, *ev = model_pallas_adaptive.run(*args, interpret=interpret, schedule=sc)
        return (ys, rec, *ev), st

    def values(y0, p, c, ts, arrays):  # (B, S, N), (B, R, NR), the event times: the kernel's
        event = eqx.combine(arrays, rest)  # (its arrays: an operand of this rule)
        solve = diffrax_backend(problem, options, checkpointed, values=True, event=event)
        ys, rec, *ev = solve(y0, (p,), c, ts)
        ev = [jnp.reshape(e, y0.shape[:1]) for e in ev]  # (one body: a scalar there)
        return (jnp.moveaxis(ys, 0, 1), jnp.moveaxis(rec, 0, 1), *ev)

    def fwd(y0, p, c, ts, arrays):
        args = (y0.value, p.value, c.value, ts.value, jax.tree.map(lambda x: x.value, arrays))
        if (
            ts.perturbed
            or not own
            or not (interpret or model_pallas_adaptive_back.serves_back(spec))
        ):
            # (the pullback made here, of every operand: a closure would leak this trace)
            out = forward(*args)
            return out, (jax.vjp(values, *args)[1], out[0])
        y0, p, c, ts, _ = args
        run_args = (spec, y0, _packed(p, c), ts, ctl)
        ys, rec, st, hk, nk = model_pallas_adaptive.run(
            *run_args, interpret=interpret, adjoint=True
        )
        return ((ys, rec), st), ((ys, hk, nk, p, c, ts), None)

    def bwd(residuals, g):
        first, out = residuals
        if out is not None:  # through the Diffrax path
            dense = tuple(
                jnp.zeros_like(x) if isinstance(d, SymbolicZero) else d
                for d, x in zip(g[0], out, strict=True)
            )
            return first(dense)
        ys, hk, nk, p, c, ts = first
        gy = jnp.zeros_like(ys) if isinstance(g[0][0], SymbolicZero) else g[0][0]
        args = (spec, ys, hk, nk, gy, _packed(p, c), ts, ctl)
        y0b, pb = model_pallas_adaptive_back.run_back(*args, interpret=interpret)
        P = p.shape[1]
        pbar = pb[:P].T if p.shape[0] > 1 else jnp.sum(pb[:P], axis=1)[None]
        return y0b, pbar, jnp.sum(pb[P:], axis=1), None, None

    run = jax.custom_vjp(forward)
    run.defvjp(fwd, bwd, symbolic_zeros=True)

    def backend(y0, blocks, c, ts):
        (ys, rec, *ev), st = run(y0, joined(list(blocks), ts.dtype), c, ts, arrays)
        if jumps is None and not keep.all():
            ys = ys[:, np.flatnonzero(keep)]
        stats, result = _adaptive.per_body(st, single, np.flatnonzero(keep))
        out = (jnp.moveaxis(ys, 1, 0), jnp.moveaxis(rec, 1, 0))
        if event is not None:
            out = (*out, ev[0][0] if single else ev[0])
        return out, (stats, result)

    return backend


def gpu_backend(problem: tuple, options: SolveOptions) -> Backend:
    """The Pallas kernel's solve (`_gpu`)."""

    def backend(y0, blocks, c, ts):
        p = joined(list(blocks), ts.dtype)
        (ys, rec), stats, result = _gpu(problem, ts, y0, p, c, options)
        return (ys, rec), (stats, result)

    return backend


def _packed(p: Array, c: Array) -> Array:
    """The kernels' parameter rows `(P + Pc, Bp)`: the parameters, then the lifted constants."""
    return jnp.concatenate([p, jnp.broadcast_to(c, (p.shape[0], c.shape[0]))], axis=1).T


def _gpu(
    problem: tuple,
    ts: Array,
    y0: Array,
    p: Array,
    c: Array,
    options: SolveOptions,
) -> tuple[tuple[Array, Array], dict[str, Array], diffrax.RESULTS]:
    """The Pallas kernel's solve (`model_pallas`, in Pallas' interpreter where the backend is
    not a GPU: the tests): the kept states `(S, B, N)` and the records `(J, B, NR)` (a model
    with a jump map: its held commands). Reverse mode runs the kernel's own adjoint
    (`model_pallas_back.run_back`, the same steps reversed); where the output times are
    differentiated, or the model has a jump map, the same steps through Diffrax
    (`ExplicitRK(method)`), whose reverse mode differentiates them."""
    model, hoisted, _, jumps, keep = problem
    method = cast(diffrax.AbstractERK, method_of(options))  # one of METHODS: `serves` checked
    through = dataclasses.replace(options, solver=ExplicitRK(method), throw=False)
    interpret = jax.default_backend() != "gpu"
    K, NR = ts.shape[0] - 1, model.record[1]
    sc = None if jumps is None else model_kernel.Schedule.of(K, jumps, keep, NR)

    def steps(ts):
        width = ts[1:] - ts[:-1]
        n = fixed_step_count(width, jnp.asarray(options.dt0, ts.dtype))
        h = width / n
        return jnp.minimum(n, options.max_steps).astype(jnp.int32), h, ts[:-1] + 0 * h

    spec = model_pallas.Spec(hoisted, model.unit, type(method), model.record)

    def forward(y0, p, c, ts):
        args = (spec, y0, _packed(p, c), steps(ts))
        if sc is None:
            ys = cast(Array, model_pallas.run(*args, interpret=interpret))
            return ys, jnp.zeros((y0.shape[0], 0, 0), ys.dtype)
        return model_pallas.run(*args, interpret=interpret, schedule=sc)

    through_values = diffrax_backend(problem, through, values=True)

    def through_diffrax(y0, p, c, ts):
        return tuple(jnp.moveaxis(a, 0, 1) for a in through_values(y0, (p,), c, ts))

    def schedule(ts) -> tuple[tuple[Array, Array, Array], int]:
        """The steps, and a bound on an interval's (static: the checkpoints' shape)."""
        with jax.ensure_compile_time_eval():  # concrete steps where the times are known now
            n, h, t0 = steps(ts)
        longest = int(np.max(np.asarray(n), initial=1)) if is_concrete(n) else options.max_steps
        return (n, h, t0), longest

    def fwd(y0, p, c, ts):
        args = (y0.value, p.value, c.value, ts.value)
        if ts.perturbed or sc is not None or not (interpret or model_pallas_back.serves_back(spec)):
            out, pullback = jax.vjp(through_diffrax, *args)
            return out, (pullback, out)
        y0, p, c, ts = args
        (n, h, t0), longest = schedule(ts)
        if is_concrete(n) and model_pallas_back.stores_checkpoints(np.asarray(n), longest):
            # the states, and the reverse mode's checkpoints (the same steps)
            ys, src = model_pallas.run(
                spec, y0, _packed(p, c), (n, h, t0), interpret=interpret, longest=longest
            )
            out = (ys, jnp.zeros((y0.shape[0], 0, 0), ys.dtype))
        else:  # the reverse mode recomputes them from the states
            out = forward(y0, p, c, ts)
            src = out[0]
        return out, ((src, p, c, ts), out)

    def bwd(residuals, g):
        g = tuple(
            jnp.zeros_like(x) if isinstance(d, SymbolicZero) else d
            for d, x in zip(g, residuals[1], strict=True)
        )
        if callable(residuals[0]):
            return residuals[0](g)
        (src, p, c, ts), _ = residuals
        stepped, longest = schedule(ts)
        args = (spec, src, g[0], _packed(p, c), stepped)
        y0b, pb = model_pallas_back.run_back(*args, longest=longest, interpret=interpret)
        P = p.shape[1]
        pbar = pb[:P].T if p.shape[0] > 1 else jnp.sum(pb[:P], axis=1)[None]
        return y0b, pbar, jnp.sum(pb[P:], axis=1), None

    run = jax.custom_vjp(forward)
    run.defvjp(fwd, bwd, symbolic_zeros=True)
    recorded = []

    def kernel_run(n, taken, h, t0):
        ys, rec = run(y0, p, c, ts)
        recorded.append(rec)
        return ys if sc is not None or keep.all() else ys[:, np.flatnonzero(keep)]

    ys, stats, result = kernel_solve(kernel_run, ts, options, keep)
    return (jnp.moveaxis(ys, 1, 0), jnp.moveaxis(recorded[0], 1, 0)), stats, result
