"""One model, every backend: `solve` integrates a `Model` for a batch of bodies on the CPU kernel
written from its field (`rigidjax.kernels.model`) or on a GPU's Pallas kernel evaluating it
(`rigidjax.kernels.model_pallas`) where one serves, and through Diffrax otherwise, with the same
steps and the same scalar operations."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jaxtyping import Array, Float

from .._batch import failed_body
from .._integrate import (
    SolveOptions,
    nonfinite_field,
    raise_failure,
)
from .._modes import both_modes, closure_free
from ..kernels import adaptive, model_pallas, model_pallas_adaptive
from ..kernels import model as model_kernel
from ..kernels._scalar import Unsupported
from . import _adaptive
from ._diffrax_path import (
    Backend,
    BatchMaxRMS,
    diffrax_backend,
    joined,
    method_of,
)
from ._kernels import (
    adaptive_backend,
    adaptive_gpu_backend,
    cpu_backend,
    gpu_backend,
    kernel_options,
)
from .model import Model, TreeModel, flat, leaves, ravel

__all__ = ["BatchMaxRMS", "kernel_options", "method_of", "solve_model", "solve_tree"]


if TYPE_CHECKING:
    from ..events import Event


def _compile(model: Model, dtype, event: Event | None = None):
    """The model's field hoisted (its float constants lifted; with an `event`, its condition
    too), or the primitive it cannot take."""
    try:
        fns = (model.jump, model.end, None if event is None else _Condition(event.condition))
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
    maps += [hoisted.event_components] if hoisted.events else []
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
    (`Event.on_state`), shared by the bodies; its time `stats["event_t"]` (`(B,)`, or a scalar
    with `single`). It runs on the per-body CPU kernel (`kernels.adaptive`: adaptive steps, or
    each body's fixed steps), located by the Illinois method on the step, else on the Diffrax
    path (Diffrax's events); its derivatives through the Diffrax path. With a jump map, a
    terminating event holds the state: the later jumps are not applied (their records repeat
    the held components)."""
    if (model.jump is None) != (jumps is None):
        raise ValueError("a model with a jump map takes jumps (T − 1,), and only such a model")
    quiet = dataclasses.replace(options, throw=False)
    keep = np.ones(ts.shape[0], bool) if keep is None else np.asarray(keep, bool)
    blocks = [p] if isinstance(p, jax.Array | np.ndarray) else list(p)
    params: Array = joined(blocks, ts.dtype)
    ys, stats, result = _solve(model, ts, y0, blocks, params, quiet, single, jumps, keep, event)
    first = stats.pop("failed_body", None)  # (per-body solves: the body that failed first)
    if not keep.all():  # (a gather: some ten small programs to compile on a first call)
        ts = ts[np.flatnonzero(keep)]
    if options.throw:

        def probe(k: int) -> str | None:
            def vf(t, y):
                return jax.vmap(model.field, in_axes=(None, 0, 0))(
                    t, y, jnp.broadcast_to(params, (y.shape[0], params.shape[1]))
                )

            return nonfinite_field(vf, ts, ys, k, model.name == "torque")

        def body(k: int) -> str | None:
            return None if single else failed_body((y0.shape[0],), first, ys[k])

        ys = raise_failure(result, stats["num_valid"], ts, ys, options.max_steps, probe, body)
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
    """`solve_model` without raising failures (with an `event`: the per-body kernel, the
    adaptive GPU kernel, or the Diffrax path, whose `solve_saved` differentiates it in every
    mode): the CPU kernel (each block of parameters its own operand: a shared block is never
    copied per body), the GPU kernels, or Diffrax (`p`: the blocks joined). With the default
    adjoint, every backend of a model with a scalar program is differentiable in every mode
    and order
    (`_modes.both_modes`): its own reverse mode, forward mode and higher orders through the
    Diffrax path on the same steps."""
    dtype = ts.dtype
    fixed = isinstance(options.stepsize_controller, diffrax.ConstantStepSize)
    per_body = event is not None or not kernel_options(options)  # each body its own steps
    ctl = _adaptive.controls(options, BatchMaxRMS(-1), dtype, event) if per_body else None
    hoisted, missing = _compile(model, dtype, event if ctl is not None else None)
    kernel_backend: Backend | None = None  # (fixed steps, no event: the lockstep kernels)
    if hoisted is not None and kernel_options(options) and event is None:
        method = method_of(options)
        try:
            kernel = model_kernel.build(hoisted, model.unit, method, model.record)
            gpu = kernel is None and model_pallas.serves(hoisted, model.unit, method, model.record)
        except Unsupported as e:
            kernel, gpu, hoisted, missing = None, False, None, e.primitive
        if kernel is not None:
            kernel_backend = cpu_backend(kernel, model, options, jumps, keep)
        elif gpu and hoisted is not None:
            kernel_backend = gpu_backend((model, hoisted, single, jumps, keep), options)
    adaptive_kernel = None
    if ctl is not None and hoisted is not None:
        try:
            method = method_of(options)
            args = (hoisted, model.unit, method, model.record)
            adaptive_kernel = adaptive.build(*args, fixed=fixed)
        except Unsupported as e:
            hoisted, missing = None, e.primitive
    # on a GPU: the adaptive Pallas kernel (an event's condition in it)
    on_gpu = (
        ctl is not None  # (at fixed steps: with an event)
        and adaptive_kernel is None
        and hoisted is not None
        and _unrolled(hoisted)[0] is not None
        and model_pallas_adaptive.serves(
            hoisted, model.unit, method_of(options), model.record, fixed
        )
    )
    if (
        adaptive_kernel is None
        and not on_gpu
        and event is not None
        and hoisted is not None
        and hoisted.events
    ):
        hoisted, missing = _compile(model, dtype)  # (the Diffrax path's: without the event)
    if kernel_backend is None and hoisted is not None:
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
    # the event's arrays an argument of the backends, not a closure: `both_modes`' rules trace
    # them again, outside the trace those arrays may belong to (a per-body event under the
    # bodies' `jax.vmap`, a condition closing over a traced value)
    if event is not None:
        y_one = jnp.zeros(y0.shape[1:], dtype)
        condition = closure_free(event.condition, ts[0], y_one)
        event = eqx.tree_at(lambda e: e.condition, event, condition)
    arrays, rest = eqx.partition(event, eqx.is_array)

    def on_event(make: Callable[[Event | None], Callable]) -> Callable:
        def backend(y0, blocks, c, ts, arrays):
            return make(eqx.combine(arrays, rest))(y0, blocks, c, ts)

        return backend

    backend = None if kernel_backend is None else on_event(lambda ev: kernel_backend)
    if adaptive_kernel is not None and hoisted is not None:
        assert ctl is not None
        backend = on_event(lambda ev: adaptive_backend(adaptive_kernel, ctl, problem, options, ev))
    elif on_gpu:
        method = method_of(options)
        backend = on_event(
            lambda ev: adaptive_gpu_backend(method, ctl, problem, options, ev, fixed)
        )
    elif event is not None:
        backend = on_event(lambda ev: diffrax_backend(problem, options, event=ev))
    if (
        (event is None or adaptive_kernel is not None or on_gpu)
        and hoisted is not None
        and isinstance(options.adjoint, None | diffrax.RecursiveCheckpointAdjoint)
    ):
        # the scalar program: every input explicit (`c`, the event's arrays), so one rule
        # differentiates it all (the model's own field: `solve_saved`'s rule, its closure
        # converted); an event's time is one of the values (the Diffrax path with an event
        # differentiates itself)
        if backend is None:
            checkpointed = diffrax.RecursiveCheckpointAdjoint()
            backend = on_event(lambda ev: diffrax_backend(problem, options, checkpointed))
        forward, second = (
            on_event(lambda ev, a=a: diffrax_backend(problem, options, a, values=True, event=ev))
            for a in (diffrax.ForwardMode(), diffrax.DirectAdjoint())
        )
        backend = both_modes(backend, forward, second)
    if backend is None:
        backend = on_event(lambda ev: diffrax_backend(problem, options))
    (ys, recorded, *event_t), (stats, result) = backend(y0, tuple(blocks), c, ts, arrays)
    if model.record[1]:
        stats["recorded"] = recorded
    if event_t:
        stats["event_t"] = event_t[0]
    return ys, stats, result


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


class _Condition(eqx.Module):
    """An event's condition `(t, y) -> ()` of one body's flat state as the kernels take it:
    `(t, y, p) -> ()`."""

    condition: Callable

    def __call__(self, t, y, p):
        del p
        return self.condition(t, y)


class _Unravel(eqx.Module):
    """`(the state's tree,)` of one body's flat state `(N,)`."""

    tm: TreeModel

    def __call__(self, y: Array) -> tuple[Any]:
        return (self.tm.unravel(y, "y"),)
