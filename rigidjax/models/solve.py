"""One model, every backend: `solve` integrates a `Model` for a batch of bodies on the CPU kernel
written from its field (`rigidjax.kernels.model`) or on a GPU's Pallas kernel evaluating it
(`rigidjax.kernels.model_pallas`) where one serves, and through Diffrax otherwise, with the same
steps and the same scalar operations."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jaxtyping import Array, Float

from .._checks import is_concrete
from .._integrate import (
    SolveOptions,
    fixed_step_count,
    nonfinite_field,
    raise_failure,
    solve_saved,
)
from .._modes import both_modes
from ..kernels import adaptive, model_pallas
from ..kernels import model as model_kernel
from ..kernels._scalar import Unsupported
from ..solvers.explicit_rk import ExplicitRK
from . import _adaptive
from .model import Model, TreeModel, flat, leaves, ravel

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
    ys = run(n, taken, width / n, ts[:-1])
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


class _Components(eqx.Module):
    """The model's field on the Diffrax path: the state is N component arrays `(B,)` (one body:
    scalars), the parameters P components (scalars where shared); `field` is the scalar program
    (`kernels.model.field_components`) or, for a field without one, the model's own field
    mapped over the bodies."""

    field: Callable
    scalar: bool = eqx.field(static=True)

    def __call__(self, t, y, args):
        p, c = args
        if self.scalar:
            return self.field(t, y, p, c)
        ys = jnp.stack(y, axis=-1)
        # no parameters: an empty `(P = 0,)` row, as `_joined` makes for the kernels
        ps = jnp.stack(jnp.broadcast_arrays(*p), axis=-1) if p else jnp.zeros((0,), ys.dtype)
        if ys.ndim == 1:
            return tuple(self.field(t, ys, ps))
        ps = jnp.broadcast_to(ps, (*ys.shape[:-1], ps.shape[-1]))
        return tuple(jnp.moveaxis(jax.vmap(self.field, in_axes=(None, 0, 0))(t, ys, ps), -1, 0))


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


def _compile(model: Model, dtype):
    """The model's field hoisted (its float constants lifted), or the primitive it cannot take."""
    try:
        fns = (model.jump, model.end)
        return model_kernel.hoist(model.field, model.size, model.params, dtype, *fns), None
    except Unsupported as e:
        return None, e.primitive


def _unrolled(hoisted: model_kernel.Hoisted) -> tuple[model_kernel.Hoisted | None, str | None]:
    """`(hoisted, None)` where the Diffrax path can evaluate its scalar program (every map it
    has unrolls), else `(None, primitive)`: the model's own field then (an adaptive solve never
    builds the kernel, which would have found the primitive first)."""
    dt = hoisted.dtype
    scalar = jax.ShapeDtypeStruct((), dt)
    c = jax.ShapeDtypeStruct(hoisted.c.shape, dt)
    args = (scalar, (scalar,) * hoisted.n, (scalar,) * hoisted.p, c)
    maps = [hoisted.components, hoisted.end_components]
    maps += [hoisted.jump_components] if hoisted.jumps else []
    try:
        for fn in maps:
            if fn is not None:
                jax.eval_shape(fn, *args)
    except Unsupported as e:
        return None, e.primitive
    return hoisted, None


def solve_model(
    model: Model,
    ts: Float[Array, " T"],
    y0: Float[Array, "B N"],
    p: Float[Array, "Bp P"] | Sequence[Float[Array, "#Bp _"]],
    options: SolveOptions,
    *,
    single: bool = False,
    jumps: np.ndarray | None = None,
    keep: np.ndarray | None = None,
    event: Event | None = None,
) -> tuple[Float[Array, "S B N"], dict[str, Array], diffrax.RESULTS]:
    """Integrate `model` for B bodies from `y0` with parameters `p` (per body, `Bp = B`, or
    shared, `Bp = 1`; or in blocks of columns, each per body or shared), saving at `ts`;
    returns `(ys (T, B, N), stats, result)` as `solve_saved`.
    A model with a jump map applies it at the start of each interval `k` with `jumps[k]`
    (`(T − 1,)` booleans, concrete: the samples of a held command); with `model.record`, the
    components it sets after each jump are `stats["recorded"] (J, B, NR)`. `keep` (booleans
    `(T,)`, concrete, the first and last true; all by default): the times whose states are
    returned, and between which failures are placed.

    Fixed steps of an explicit Runge–Kutta method with a kernel (`kernel_options`) run on the
    CPU kernel of the model (built on first use); a field the kernel cannot take runs on the
    Diffrax path with one warning naming the primitive. The Diffrax path integrates the N
    state components as separate `(B,)` arrays (`single`: one body, as scalars, which
    `jax.vmap` turns into `(N,)` batches that XLA vectorises), evaluating the same scalar
    program as the kernel. Adaptive steps on the Diffrax path are each body's own (the
    one-body solve mapped over the bodies): the step counts in `stats` are then per body
    `(B,)`, `num_valid` and `result` the batch's (the first failure).

    `event`: a `rigidjax.Event` whose condition takes `(t, y (N,))` of one body
    (`Event.on_state`), shared by the bodies; it runs on the Diffrax path (no kernel), its time
    `stats["event_t"]` (`(B,)`, or a scalar with `single`); not with a jump map."""
    if (model.jump is None) != (jumps is None):
        raise ValueError("a model with a jump map takes jumps (T − 1,), and only such a model")
    if event is not None and jumps is not None:
        raise ValueError("events are not supported for a model with a jump map")
    quiet = dataclasses.replace(options, throw=False)
    keep = np.ones(ts.shape[0], bool) if keep is None else np.asarray(keep, bool)
    blocks = [p] if isinstance(p, jax.Array | np.ndarray) else list(p)
    p = _joined(blocks, ts.dtype)
    ys, stats, result = _solve(model, ts, y0, blocks, p, quiet, single, jumps, keep, event)
    ts = ts[np.flatnonzero(keep)]
    if options.throw:

        def probe(k: int) -> str | None:
            def vf(t, y):
                return jax.vmap(model.field, in_axes=(None, 0, 0))(
                    t, y, jnp.broadcast_to(p, (y.shape[0], p.shape[1]))
                )

            return nonfinite_field(vf, ts, ys, k, model.name == "torque")

        ys = raise_failure(result, stats["num_valid"], ts, ys, options.max_steps, probe)
    return ys, stats, result


def _solve(
    model: Model,
    ts: Array,
    y0: Array,
    blocks: list[Array],
    p: Array,
    options: SolveOptions,
    single: bool,
    jumps: np.ndarray | None,
    keep: np.ndarray,
    event: Event | None = None,
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """`solve_model` without raising failures (with an `event`: the Diffrax path, whose
    `solve_saved` differentiates it in every mode): the CPU kernel (each block of parameters its
    own operand: a shared block is never copied per body), the GPU kernel, or Diffrax (`p`:
    the blocks joined). With the default adjoint, every backend of a model with a scalar
    program is differentiable in every mode and order (`_modes.both_modes`): its own reverse
    mode, forward mode and higher orders through the Diffrax path on the same steps."""
    dtype = ts.dtype
    hoisted, missing = _compile(model, dtype)
    backend: Backend | None = None
    if hoisted is not None and kernel_options(options) and event is None:
        method = method_of(options)
        try:
            kernel = model_kernel.build(hoisted, model.unit, method, model.record)
            gpu = (
                kernel is None
                and jumps is None
                and model_pallas.serves(hoisted, model.unit, method)
            )
        except Unsupported as e:
            kernel, gpu, hoisted, missing = None, False, None, e.primitive
        if kernel is not None:
            backend = _cpu(kernel, model, options, jumps, keep)
        elif gpu and hoisted is not None and keep.all():
            backend = _gpu_backend(model, hoisted, options)
    adaptive_kernel, ctl = None, None
    if hoisted is not None and not kernel_options(options) and event is None:
        ctl = _adaptive.controls(options, BatchMaxRMS(-1), dtype)
    if ctl is not None and hoisted is not None:
        try:
            method = method_of(options)
            adaptive_kernel = adaptive.build(hoisted, model.unit, method, model.record)
        except Unsupported as e:
            hoisted, missing = None, e.primitive
    if backend is None and hoisted is not None:
        hoisted, missing = _unrolled(hoisted)
    if missing is not None and (kernel_options(options) or ctl is not None):
        warnings.warn(
            f"the {model.name} uses `{missing}`, which the fast path (the CPU kernel written "
            "from the field) cannot take: it runs on the Diffrax path instead, with the same "
            "steps (slower)",
            RuntimeWarning,
            stacklevel=4,
        )
    c = jnp.zeros((0,), dtype) if hoisted is None else hoisted.c.astype(dtype)
    problem = (model, hoisted, single, jumps, keep)
    if event is not None:
        backend = _diffrax_backend(problem, options, event=event)
    if adaptive_kernel is not None and hoisted is not None:
        assert ctl is not None
        backend = _cpu_adaptive(adaptive_kernel, ctl, problem, options)
    if (
        event is None
        and hoisted is not None
        and isinstance(options.adjoint, None | diffrax.RecursiveCheckpointAdjoint)
    ):
        # the scalar program: every input explicit (`c`), so one rule differentiates it all
        # (the model's own field: `solve_saved`'s rule, its closure converted)
        if backend is None:
            checkpointed = diffrax.RecursiveCheckpointAdjoint()
            backend = _diffrax_backend(problem, options, checkpointed)
        forward = _diffrax_backend(problem, options, diffrax.ForwardMode(), values=True)
        second = _diffrax_backend(problem, options, diffrax.DirectAdjoint(), values=True)
        backend = both_modes(backend, forward, second)
    if backend is None:
        backend = _diffrax_backend(problem, options)
    (ys, recorded), (stats, result) = backend(y0, tuple(blocks), c, ts)
    if model.record[1]:
        stats["recorded"] = recorded
    return ys, stats, result


Backend = Callable[..., Any]
"""`(y0 (B, N), blocks, c (Pc,), ts (T,)) -> ((ys (S, B, N), recorded (J, B, NR)),
(stats, result))`: one backend's solve (`S` the kept times, `J` the recorded jumps)."""


def _cpu(kernel, model: Model, options: SolveOptions, jumps, keep) -> Backend:
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


def _cpu_adaptive(kernel: adaptive.AdaptiveKernel, ctl, problem: tuple, options) -> Backend:
    """The adaptive CPU kernel's solve (`kernels.adaptive.run`; each body its own steps), the
    output times differentiated through the Diffrax path."""
    model, _, single, jumps, keep = problem
    checkpointed = diffrax.RecursiveCheckpointAdjoint()
    through_diffrax = _diffrax_backend(problem, options, checkpointed, values=True)

    def backend(y0, blocks, c, ts):
        dtype, n = ts.dtype, len(blocks)
        pk = [b.astype(dtype) for b in blocks] + ([c[None]] if c.shape[0] else [])

        def through(y0, pk, ts):
            cc = pk[n][0] if len(pk) > n else jnp.zeros((0,), dtype)
            ys, rec = through_diffrax(y0, tuple(pk[:n]), cc, ts)
            none = jnp.full(y0.shape[:1], jnp.inf, dtype)
            return jnp.moveaxis(ys, 0, 1), jnp.moveaxis(rec, 0, 1), none

        ys, rec, st, _ = adaptive.run(kernel, y0, pk, ts, ctl, through, jumps, keep)
        stats, result = _adaptive.per_body(st, single, np.flatnonzero(keep))
        return (jnp.moveaxis(ys, 1, 0), jnp.moveaxis(rec, 1, 0)), (stats, result)

    return backend


def _gpu_backend(model: Model, hoisted: model_kernel.Hoisted, options: SolveOptions) -> Backend:
    """The Pallas kernel's solve (`_gpu`)."""

    def backend(y0, blocks, c, ts):
        p = _joined(list(blocks), ts.dtype)
        ys, stats, result = _gpu(model, hoisted, ts, y0, p, c, options)
        return (ys, jnp.zeros((0, *ys.shape[1:-1], 0), ys.dtype)), (stats, result)

    return backend


def _diffrax_backend(
    problem: tuple,
    options: SolveOptions,
    adjoint: diffrax.AbstractAdjoint | None = None,
    *,
    values: bool = False,
    event: Event | None = None,
) -> Backend:
    """The Diffrax path's solve of `problem` (`(model, hoisted, single, jumps, keep)`) with
    `options` (and `adjoint`, if given); `values`: the states and records only; `event`: as
    `solve_model`'s (its time in the stats)."""
    model, hoisted, single, jumps, keep = problem
    if adjoint is not None:
        options = dataclasses.replace(options, adjoint=adjoint)
    kept = np.flatnonzero(keep)

    def backend(y0, blocks, c, ts):
        p = _joined(list(blocks), ts.dtype)
        if jumps is not None:
            args = (model, hoisted, ts, y0, p, c, options, single)
            ys, stats, result = _diffrax_jumps(args, jumps)
        else:
            ys, stats, result = _diffrax(model, hoisted, ts, y0, p, c, options, single, event)
        R0, NR = model.record
        at = np.flatnonzero(jumps) + 1 if NR and jumps is not None else np.zeros(0, int)
        out = (ys[kept], ys[at, :, R0 : R0 + NR])
        if values:
            return out
        stats["num_valid"] = jnp.sum(jnp.asarray(kept) < stats["num_valid"])
        return out, (stats, result)

    return backend


def _diffrax_jumps(
    problem: tuple, jumps: np.ndarray
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """The Diffrax path of a model with a jump map (`problem`: `_diffrax`'s arguments): one
    solve per interval of `ts` inside a `lax.scan`, each started by the jump map where `jumps`
    flags it (the scalar program of `hoisted`, or the model's own map)."""
    model, hoisted, ts, y0, p, c, options, single = problem
    jump = cast(Callable, model.jump)
    pb = jnp.broadcast_to(p, (y0.shape[0], p.shape[1]))

    def apply(t, y):
        if hoisted is None:
            return jax.vmap(jump, in_axes=(None, 0, 0))(t, y, pb)
        out = hoisted.jump_components(t, tuple(y.T), tuple(pb.T), c)
        return jnp.stack(out, axis=-1)

    keys = ("num_steps", "num_accepted_steps", "num_rejected_steps")

    def interval(carry, x):
        y, result = carry
        ta, tb, flag = x
        y = jnp.where(flag, apply(ta, y), y)
        ys, stats, res = _diffrax(model, hoisted, jnp.stack([ta, tb]), y, p, c, options, single)
        y1 = ys[-1]
        result = diffrax.RESULTS.where(result == diffrax.RESULTS.successful, res, result)
        counts = jnp.stack([stats[k] for k in keys])
        return (y1, result), (y1, counts, res == diffrax.RESULTS.successful)

    init = (y0, diffrax.RESULTS.successful)
    xs = (ts[:-1], ts[1:], jnp.asarray(jumps))
    (_, result), (ys, counts, valid) = jax.lax.scan(interval, init, xs)
    stats: dict[str, Array] = dict(zip(keys, jnp.sum(counts, axis=0), strict=True))
    stats["num_valid"] = 1 + jnp.sum(jnp.cumprod(valid))
    return jnp.concatenate([y0[None], ys]), stats, result


def _joined(blocks: list[Array], dtype) -> Array:
    """The parameters `(Bp, P)` from their blocks of columns `(Bp or 1, Pj)`."""
    rows = max((b.shape[0] for b in blocks), default=1)
    parts = [jnp.broadcast_to(b, (rows, b.shape[1])).astype(dtype) for b in blocks]
    return jnp.concatenate([*parts, jnp.zeros((rows, 0), dtype)], axis=1)


def _packed(p: Array, c: Array) -> Array:
    """The kernels' parameter rows `(P + Pc, Bp)`: the parameters, then the lifted constants."""
    return jnp.concatenate([p, jnp.broadcast_to(c, (p.shape[0], c.shape[0]))], axis=1).T


def _diffrax(
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
        p_axis = 0 if p.shape[0] > 1 else None

        def one(y, pb):
            pb = pb[None] if p_axis == 0 else pb
            ys, stats, result = _diffrax(model, hoisted, ts, y[None], pb, c, options, True, event)
            return ys[:, 0], stats, result

        ys, stats, results = jax.vmap(one, in_axes=(0, p_axis))(y0, p)
        valid = stats["num_valid"]
        failed = results != diffrax.RESULTS.successful
        first = jnp.argmin(jnp.where(failed, valid, jnp.iinfo(valid.dtype).max))
        stats = {**stats, "num_valid": jnp.min(valid)}
        return jnp.moveaxis(ys, 0, 1), stats, jtu.tree_map(lambda r: r[first], results)
    field = model.field if hoisted is None else hoisted.components
    shared = p.shape[0] == 1
    comps = (lambda a: tuple(a[0])) if (single or shared) else (lambda a: tuple(a.T))
    y_init = tuple(y0[0]) if single else tuple(y0.T)
    ys, stats, result = solve_saved(
        diffrax.ODETerm(_Components(field, hoisted is not None)),
        ts,
        y_init,
        options,
        args=(comps(p), c),
        step_end=_StepEnd(model.unit, model.end) if model.unit or model.end else None,
        norm=BatchMaxRMS(-1),
        event=None if event is None else event.on_state(_stacked if single else _columns),
    )
    ys = jnp.stack(ys, axis=-1)  # (T, B, N) or (T, N)
    return (ys[:, None] if single else ys), stats, result


def _stacked(y: tuple[Array, ...]) -> tuple[Array]:
    """`(y (N,),)` from one body's components."""
    return (jnp.stack(y),)


def _columns(y: tuple[Array, ...]) -> tuple[Array]:
    """`(y (N,),)` from the components `(1,)` of a batch of one body."""
    return (jnp.stack(y, axis=-1)[0],)


def _gpu(
    model: Model,
    hoisted: model_kernel.Hoisted,
    ts: Array,
    y0: Array,
    p: Array,
    c: Array,
    options: SolveOptions,
) -> tuple[Array, dict[str, Array], diffrax.RESULTS]:
    """The Pallas kernel's solve (`model_pallas`, in Pallas' interpreter where the backend is
    not a GPU: the tests). Reverse mode runs the kernel's own adjoint (`model_pallas.run_back`,
    the same steps reversed); where the output times are differentiated, the same steps
    through Diffrax (`ExplicitRK(method)`), whose reverse mode differentiates them."""
    method = cast(diffrax.AbstractERK, method_of(options))  # one of METHODS: `serves` checked
    through = dataclasses.replace(options, solver=ExplicitRK(method), throw=False)
    interpret = jax.default_backend() != "gpu"

    def steps(ts):
        width = ts[1:] - ts[:-1]
        n = fixed_step_count(width, jnp.asarray(options.dt0, ts.dtype))
        return jnp.minimum(n, options.max_steps).astype(jnp.int32), width / n, ts[:-1]

    spec = model_pallas.Spec(hoisted, model.unit, type(method))

    def forward(y0, p, c, ts):
        return model_pallas.run(spec, y0, _packed(p, c), steps(ts), interpret=interpret)

    def through_diffrax(y0, p, c, ts):
        ys = _diffrax(model, hoisted, ts, y0, p, c, through, False)[0]
        return jnp.moveaxis(ys, 0, 1)

    def schedule(ts) -> tuple[tuple[Array, Array, Array], int]:
        """The steps, and a bound on an interval's (static: the checkpoints' shape)."""
        with jax.ensure_compile_time_eval():  # concrete steps where the times are known now
            n, h, t0 = steps(ts)
        longest = int(np.max(np.asarray(n), initial=1)) if is_concrete(n) else options.max_steps
        return (n, h, t0), longest

    def fwd(y0, p, c, ts):
        args = (y0.value, p.value, c.value, ts.value)
        if ts.perturbed or not (interpret or model_pallas.serves_back(spec)):
            ys, pullback = jax.vjp(through_diffrax, *args)
            return ys, (pullback, None)
        y0, p, c, ts = args
        (n, h, t0), longest = schedule(ts)
        if is_concrete(n) and model_pallas.stores_checkpoints(np.asarray(n), longest):
            # the states, and the reverse mode's checkpoints (the same steps)
            ys, src = model_pallas.run(
                spec, y0, _packed(p, c), (n, h, t0), interpret=interpret, longest=longest
            )
        else:  # the reverse mode recomputes them from the states
            ys = src = forward(y0, p, c, ts)
        return ys, ((src, p, c, ts), ys)

    def bwd(residuals, g):
        if residuals[1] is None:
            return residuals[0](g)
        (src, p, c, ts), ys = residuals
        if isinstance(g, jax.custom_derivatives.SymbolicZero):
            g = jnp.zeros_like(ys)
        stepped, longest = schedule(ts)
        args = (spec, src, g, _packed(p, c), stepped)
        y0b, pb = model_pallas.run_back(*args, longest=longest, interpret=interpret)
        P = p.shape[1]
        pbar = pb[:P].T if p.shape[0] > 1 else jnp.sum(pb[:P], axis=1)[None]
        return y0b, pbar, jnp.sum(pb[P:], axis=1), None

    run = jax.custom_vjp(forward)
    run.defvjp(fwd, bwd, symbolic_zeros=True)
    ys, stats, result = kernel_solve(lambda n, taken, h, t0: run(y0, p, c, ts), ts, options)
    return jnp.moveaxis(ys, 1, 0), stats, result


def solve_tree(
    vf: Callable,
    ts: Float[Array, " T"],
    y0: Any,
    args: Any,
    options: SolveOptions,
    *,
    unit: tuple[int, ...] = (),
    name: str = "model",
    jump: Callable | None = None,
    jumps: np.ndarray | None = None,
    keep: np.ndarray | None = None,
    record: int | None = None,
    end: Callable | None = None,
    event: Event | None = None,
) -> tuple[Any, dict[str, Array], diffrax.RESULTS]:
    """`solve_model` for one body whose state `y0` and parameters `args` are PyTrees and whose
    field is `vf(t, y, args)` (`unit`: the indices of the state's leaves that are unit
    quaternions; `jump(t, y, args) -> y` applied where `jumps` flags an interval, recording
    the state's leaf `record` after each jump in `stats["recorded"] (J, ...)`; `keep`: the
    times whose states are returned; `end(y) -> (y', changed)`: a step-end map; `event`: a
    `rigidjax.Event` whose condition takes `(t, y)`, `y` the state's tree, its time
    `stats["event_t"]`); returns `(ys, stats, result)`, `ys` the state's tree with a leading
    time axis. Under `jax.vmap` the mapped bodies join one kernel call."""
    dtype = ts.dtype
    (y_leaves, y_def), (p_leaves, p_def) = (jtu.tree_flatten(x) for x in (y0, args))
    y_shapes, p_shapes = (tuple(jnp.shape(a) for a in xs) for xs in (y_leaves, p_leaves))
    tm = TreeModel(vf, y_def, y_shapes, p_def, p_shapes, unit, name, jump, record, end)
    model = flat(tm)
    p = [leaf[None] for leaf in leaves(args, dtype)]  # a block each
    y = ravel(y0, dtype)[None]
    on_flat = None if event is None else event.on_state(_Unravel(tm))
    ys, stats, result = solve_model(
        model, ts, y, p, options, single=True, jumps=jumps, keep=keep, event=on_flat
    )
    if "recorded" in stats:
        stats["recorded"] = stats["recorded"][:, 0]
    return tm.unravel(ys[:, 0], "y"), stats, result


class _Unravel(eqx.Module):
    """`(the state's tree,)` of one body's flat state `(N,)`."""

    tm: TreeModel

    def __call__(self, y: Array) -> tuple[Any]:
        return (self.tm.unravel(y, "y"),)
