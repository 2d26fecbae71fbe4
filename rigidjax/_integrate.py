"""The one integration driver: from solver options (`SolveOptions`) to `diffrax.diffeqsolve` to
the states at the output times. Every integrating entry point (`darboux`, `simulate`, the heavy
top, 6-DOF bodies, Kepler, the satellite, identification) goes through `solve_saved`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NoReturn, TypedDict, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, PyTree

from ._checks import attach_check, is_concrete
from ._custom_types import Frame, RealScalarLike
from ._modes import both_modes, closure_free
from ._tolerances import (
    check_discretisation,
    default_controller,
    default_tolerances,
    discretisation,
    python_int,
    warn_unattainable,
)
from .solvers.exact_free_body import AbstractFlowSolver, RigidBodyField
from .solvers.explicit_rk import unrolled
from .solvers.rkmk import RKMK, LieTerm
from .solvers.step_end_map import StepEndMap

if TYPE_CHECKING:
    from .events import Event, RootedEvent


class IntegrationError(RuntimeError):
    """A solve that failed (its state became non-finite, or an output interval needed more than
    `max_steps` steps). The message names the output interval, the cause and the remedy; run
    with `throw=False` to get the trajectory up to the failure instead."""


_CAUSES: tuple[tuple[Any, str], ...] = (
    (
        diffrax.RESULTS.nonfinite,
        "the state became non-finite (NaN or inf): the step is too large for this angular "
        "velocity (lower dt0, or use an adaptive controller: stepsize_controller="
        "diffrax.PIDController(rtol, atol)), or the motion itself blows up there",
    ),
    (
        diffrax.RESULTS.max_steps_reached,
        "the maximum number of solver steps (max_steps = {max_steps} per output interval) was "
        "reached: raise max_steps, loosen rtol/atol, or give output times closer together",
    ),
)


def _cause(result: diffrax.RESULTS, max_steps: int) -> str:
    for known, text in _CAUSES:
        if result == known:
            return text.format(max_steps=max_steps)
    return diffrax.RESULTS[result]


def _has_torque(obj: Any) -> bool:
    """Whether the vector field `obj` (a tree of dataclasses) carries a `torque`."""
    if getattr(obj, "torque", None) is not None:
        return True
    fields = dataclasses.fields(obj) if dataclasses.is_dataclass(obj) else ()
    return any(_has_torque(getattr(obj, f.name)) for f in fields)


def nonfinite_field(
    vf: Callable[[Array, PyTree], PyTree], ts: Array, ys: PyTree, k: int, torque: bool
) -> str | None:
    """The cause of a failure in `[ts[k-1], ts[k]]` when it is the vector field's `vf(t, y)`
    (the torque's, with `torque`), not the step's: the first of 33 equally spaced times of the
    interval at which the field, at the last saved (finite) state, is non-finite; None if it is
    finite at all of them."""
    y = jax.tree.map(lambda a: a[k - 1], ys)
    grid = jnp.linspace(ts[k - 1], ts[k], 33)
    ok = jax.vmap(lambda t: _all_finite(vf(t, y)))(grid)
    if not _all_finite(y) or bool(jnp.all(ok)):
        return None
    t = float(grid[int(jnp.argmin(ok))])
    if torque:
        return (
            f"the torque returned a non-finite value (NaN or inf) at t = {t:.6g} for the finite "
            f"state reached at ts[{k - 1}]: make torque(t, omega, q) finite over the whole span"
        )
    return (
        f"the vector field returned a non-finite value (NaN or inf) at t = {t:.6g} for the "
        f"finite state reached at ts[{k - 1}]: a function of time or state that you passed "
        "(a torque, h_rate, omega(t), a potential, ...) is not finite there"
    )


def _all_finite(y: PyTree) -> Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(y)]))


def raise_failure(
    result: diffrax.RESULTS,
    num_valid: Array,
    ts: Array,
    ys: PyTree,
    max_steps: int,
    probe: Callable[[int], str | None] | None = None,
    body: Callable[[int], str | None] | None = None,
) -> PyTree:
    """Raise `IntegrationError` for a failed solve, naming the output interval (concrete
    results), or attach the same check with `equinox.error_if` (traced results); returns `ys`.
    `probe(k)` may name a cause found in the failed interval `k` (`nonfinite_field`), `body(k)`
    the body of a batch that failed (`_batch.failed_body`)."""
    if is_concrete(num_valid):
        if result == diffrax.RESULTS.successful:
            return ys
        k = int(num_valid)
        cause = (probe(k) if probe else None) or _cause(result, max_steps)
        where = body(k) if body else None
        which = "" if where is None else f" for {where}"
        raise IntegrationError(
            f"integration failed{which} between t = {float(ts[k - 1]):.6g} and "
            f"t = {float(ts[k]):.6g}"
            f" (output times {k - 1} and {k}): {cause}. With throw=False the"
            f" trajectory comes back with its result; its states are valid up to ts[{k - 1}]."
        )
    causes = [r for r, _ in _CAUSES]
    messages = [
        f"integration failed: {_cause(r, max_steps)} (call it outside jit to see where, or run "
        "with throw=False and read the trajectory's result)"
        for r in causes
    ] + ["integration failed (call it outside jit for the details, or run with throw=False)"]
    index = jnp.asarray(len(causes))
    for i, r in enumerate(causes):
        index = jnp.where(result == r, i, index)
    return attach_check(ys, result != diffrax.RESULTS.successful, index, messages)


class SolveKwargs(TypedDict, total=False):
    """The keyword shorthand for the fields of `SolveOptions` (`simulate(..., rtol=1e-8)`)."""

    solver: diffrax.AbstractSolver
    stepsize_controller: diffrax.AbstractStepSizeController
    rtol: RealScalarLike
    atol: RealScalarLike
    dt0: RealScalarLike
    max_steps: int
    adjoint: diffrax.AbstractAdjoint
    progress_meter: diffrax.AbstractProgressMeter
    throw: bool


class SolveOptions(eqx.Module):
    """How to integrate: accepted by every integrating entry point as `options=`, with each field
    also accepted as a keyword argument (which overrides the field).

    - `solver`: any Diffrax solver; default Tsit5 with unrolled stages (`ExplicitRK`); explicit
      Runge–Kutta solvers are run as `ExplicitRK` (same numbers, fused stages).
    - `stepsize_controller`: default `diffrax.PIDController(rtol, atol)`; or
      `diffrax.ConstantStepSize()` with `dt0`.
    - `rtol`, `atol`: default `default_tolerances(dtype)` (1e-10 in float64, 1e-6 in float32).
    - `dt0`: the (initial) step; default Diffrax's initial-step heuristic for adaptive steps.
    - `rtol`, `atol` (finite) and `dt0` (`inf`: one step per output interval) are positive
      numbers, checked when the program runs if traced; they set the discretisation, so
      derivatives with respect to them are zero.
    - `max_steps`: bound on the steps of each output interval.
    - `adjoint`: default every mode (`jax.grad`, `jax.jacrev` by Diffrax's checkpointed
      adjoint; `jax.jacfwd`, `jax.jvp`, `jax.hessian` by forward mode); one given is used as is.
    - `progress_meter`: default none; e.g. `diffrax.TqdmProgressMeter()`.
    - `throw`: raise `IntegrationError` when the solve fails (default); with `False` the
      trajectory comes back with its `result` set to the first failure
      (`diffrax.RESULTS.max_steps_reached`, `diffrax.RESULTS.nonfinite`) and
      `stats["num_valid"]`, the number of leading output times whose states are valid (later
      intervals start from the state reached, unless it is non-finite).
    """

    solver: diffrax.AbstractSolver | None = None
    stepsize_controller: diffrax.AbstractStepSizeController | None = None
    rtol: RealScalarLike | None = None
    atol: RealScalarLike | None = None
    dt0: RealScalarLike | None = None
    max_steps: int = eqx.field(static=True, default=100_000, converter=python_int)
    adjoint: diffrax.AbstractAdjoint | None = None
    progress_meter: diffrax.AbstractProgressMeter | None = None
    throw: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        for name in ("rtol", "atol", "dt0"):
            check_discretisation(getattr(self, name), name)
        steps = self.max_steps
        if not (isinstance(steps, int) and not isinstance(steps, bool) and steps > 0):
            raise ValueError(f"max_steps must be a positive integer, got {self.max_steps!r}")

    def rkmk(self, frame: Frame) -> RKMK:
        """The geometric solver: RKMK on SO(3) in `frame` with `solver`'s tableau (default
        Dormand–Prince 5(4)); a solver that is not explicit Runge–Kutta is a clear error."""
        if self.solver is None:
            return RKMK(frame=frame)
        return RKMK(cast(diffrax.AbstractRungeKutta, self.solver), frame)

    @classmethod
    def of(cls, options: SolveOptions | None, kwargs: SolveKwargs) -> SolveOptions:
        """`options` (default `SolveOptions()`) with the keyword shorthand `kwargs` applied; an
        unknown keyword is a TypeError that lists the valid ones."""
        options = cls() if options is None else options
        if not isinstance(options, SolveOptions):
            raise TypeError(f"options must be a rigidjax.SolveOptions, got {options!r}")
        unknown = sorted(set(kwargs) - set(SolveKwargs.__annotations__))
        if unknown:
            raise TypeError(
                f"unexpected keyword argument(s) {unknown}; the solver options are "
                f"{sorted(SolveKwargs.__annotations__)} (or options=rigidjax.SolveOptions(...))"
            )
        options = dataclasses.replace(options, **kwargs) if kwargs else options
        given = {
            name: discretisation(value, name)
            for name in ("rtol", "atol", "dt0")
            if (value := getattr(options, name)) is not None and type(value) is not float
        }
        return dataclasses.replace(options, **given) if given else options


def solve_saved(
    term: diffrax.AbstractTerm,
    ts: Array,
    y0: PyTree,
    options: SolveOptions,
    *,
    solver: diffrax.AbstractSolver | None = None,
    args: PyTree = None,
    step_end: Callable | None = None,
    norm: Callable | None = None,
    tight: bool = False,
    event: Event | None = None,
) -> tuple[PyTree, dict[str, Array], diffrax.RESULTS]:
    """Integrate `term` from `ts[0]` through every output time `ts[k]` with `options`; returns
    `(ys (T, ...), stats, result)`: step counts summed over the intervals, `num_valid` (the
    leading output times reached) and the first failure (`diffrax.RESULTS.successful` if none;
    a state that becomes non-finite is `diffrax.RESULTS.nonfinite`). A failure raises
    `IntegrationError` naming the interval, unless `options.throw` is False; the intervals after
    a failure start from the state reached, and are not integrated once it is non-finite.

    One `diffrax.diffeqsolve` per output interval `[ts[k], ts[k+1]]`, all in one `lax.scan`:
    steps end exactly at the output times, so the saved values are step-end states (after
    `step_end`: normalised quaternions, shadowed rotation vectors), never interpolants, and no
    dense output is formed inside the step loop — on CPU that machinery cost more than half the
    time of a batched fixed-step solve (benchmarks/bench_dynamics.py). Fixed steps
    (`diffrax.ConstantStepSize`) divide each interval into the fewest equal steps of at most
    `dt0` (to a relative 1e-6, so that rounding in the output times never adds a step): the same
    steps as one solve when the output times lie on the `dt0` grid. Adaptive controllers start at
    `dt0` (default: Diffrax's initial-step heuristic) and each later interval at the previous
    interval's mean accepted step; output times closer together than the natural step cost one
    step each (an identification fit to 1001 gyro samples: 0.71 s vs 0.11 s with Diffrax's
    interpolated output; benchmarks/results/identify.json). `max_steps` bounds each interval.

    `solver` (default `options.solver`) runs as `ExplicitRK` when it is an explicit Runge–Kutta
    method, wrapped in `StepEndMap` with `step_end` when given. Without a step-size controller,
    a `PIDController` at `options.rtol`, `options.atol` (defaults `default_tolerances`), with
    error norm `norm` when given.

    `event`: a `rigidjax.Event` whose condition takes `(t, y)`, `y` this solve's state (one
    body: `Event.on_state`). Each interval's solve carries it as a `diffrax.Event` (the zero
    crossing located by `optimistix.Newton` at the tolerances above) until it first occurs;
    its time is `stats["event_t"]` (`inf` where none; differentiable). With `terminate` the
    state at the event (after `step_end`) is the output of that interval and of all later ones
    (empty solves); otherwise the interval is integrated again without the event, so the
    states are those of the solve without it."""
    method = unrolled(options.solver if solver is None else solver)
    adjoint = diffrax.RecursiveCheckpointAdjoint() if options.adjoint is None else options.adjoint
    meter = diffrax.NoProgressMeter() if options.progress_meter is None else options.progress_meter

    def solver_for(adjoint: diffrax.AbstractAdjoint) -> diffrax.AbstractSolver:
        return method if step_end is None else StepEndMap.wrap(method, step_end, adjoint)

    solver = solver_for(adjoint)
    controller = options.stepsize_controller
    if controller is None:
        controller = default_controller(
            ts.dtype, options.rtol, options.atol, norm=norm, tight=tight
        )
    adaptive = isinstance(controller, diffrax.AbstractAdaptiveStepSizeController)
    if not adaptive and not isinstance(controller, diffrax.ConstantStepSize):
        raise ValueError(
            "stepsize_controller must be diffrax.ConstantStepSize (with dt0) or an adaptive "
            f"controller such as diffrax.PIDController, got {type(controller).__name__}"
            " (steps always end at the output times ts)"
        )
    dt0 = options.dt0
    if not adaptive and dt0 is None:
        raise ValueError("dt0 (the step size) is required with diffrax.ConstantStepSize")
    dt0 = None if dt0 is None else jnp.asarray(dt0, ts.dtype)  # traced: no recompiling per value
    warn_unattainable(ts.dtype, options.rtol, options.atol)
    rooted = None  # located at the adaptive controller's tolerances, else `options`'
    if event is not None:
        given = (options.rtol, options.atol)
        rooted = event.rooted(controller, given, default_tolerances(ts.dtype, tight=tight))
    steps = (controller, options.max_steps, meter)
    try:
        flows = isinstance(method, AbstractFlowSolver)  # (they read a `RigidBodyField`)
        if options.adjoint is None and type(term) in (diffrax.ODETerm, LieTerm):
            one_field = cast(diffrax.ODETerm | LieTerm, term)  # (not a subclass: rebuilt)
            (ys, event_t), stats, result = _in_every_mode(
                one_field, solver_for, steps, ts, y0, args, dt0, rooted, flows
            )
        else:
            (ys, event_t), stats, result = _solve_intervals(
                term, solver, controller, ts, y0, args, dt0, options.max_steps, adjoint, meter,
                rooted,
            )  # fmt: skip
    except TypeError as e:
        raise_forward_mode(e)
    if rooted is not None:
        stats["event_t"] = cast(Array, event_t)
    if options.throw:

        def probe(k: int) -> str | None:
            return nonfinite_field(lambda t, y: term.vf(t, y, args), ts, ys, k, _has_torque(term))

        ys = raise_failure(result, stats["num_valid"], ts, ys, options.max_steps, probe)
    return ys, stats, result


def _in_every_mode(
    term: diffrax.ODETerm | LieTerm,
    solver_for: Callable,
    steps: tuple,
    ts,
    y0,
    args,
    dt0,
    event: RootedEvent | None,
    flows: bool,
):
    """`_solve_intervals` with the default adjoint, differentiable in every mode and order
    (`_modes.both_modes`): Diffrax's checkpointed reverse mode, forward mode by `ForwardMode`,
    higher orders by `DirectAdjoint`. The field's (and the event condition's) closed-over
    tracers (a torque's gain under `jax.grad`) become explicit inputs
    (`_modes.closure_free`), as a custom rule needs; for a flow solver (`flows`)
    the field stays a `RigidBodyField`, its torque converted."""
    controller, max_steps, meter = steps
    kind = type(term)  # a term of one vector field: an `ODETerm`, or a `LieTerm` (RKMK)
    if flows:
        field = cast(RigidBodyField, term.vector_field)
        if field.torque is not None:  # (one body's torque(t, Ω, q))
            one = (jnp.zeros(3, ts.dtype), jnp.zeros(4, ts.dtype))
            torque = closure_free(field.torque, ts[0], *one)
            field = eqx.tree_at(lambda f: f.torque, field, torque)
    else:
        field = closure_free(term.vf, ts[0], y0, args)
    if event is not None:
        condition = closure_free(event.condition, ts[0], y0)
        event = dataclasses.replace(event, condition=condition)
    dynamic, static = eqx.partition((field, event), eqx.is_array)

    def run(adjoint: diffrax.AbstractAdjoint, values: bool) -> Callable:
        def solve(y0, args, ts, dt0, dynamic):
            field, event = eqx.combine(dynamic, static)
            solver = solver_for(adjoint)
            out = _solve_intervals(
                kind(field), solver, controller, ts, y0, args, dt0, max_steps, adjoint, meter,
                event,
            )  # fmt: skip
            return out[0] if values else (out[0], out[1:])

        return solve

    solve = both_modes(
        run(diffrax.RecursiveCheckpointAdjoint(), False),
        run(diffrax.ForwardMode(), True),
        run(diffrax.DirectAdjoint(), True),
    )
    out, (stats, result) = solve(y0, args, ts, dt0, dynamic)
    return out, stats, result


def raise_forward_mode(e: TypeError) -> NoReturn:
    """Re-raise JAX's error for forward-mode autodiff through a reverse-mode-only integration
    with the remedy; any other TypeError unchanged."""
    if "forward-mode autodiff" not in str(e):
        raise e
    raise TypeError(
        "jax.jacfwd / jax.jvp through an integration needs adjoint=diffrax.ForwardMode() "
        "(e.g. simulate(..., adjoint=diffrax.ForwardMode())): the default "
        "RecursiveCheckpointAdjoint differentiates in reverse mode only (jax.grad, jax.jacrev)"
    ) from e


def fixed_step_count(width: Array, dt0: Array) -> Array:
    """The fewest equal steps of at most `dt0` over an output interval of `width` (to a relative
    1e-6, so that rounding in the output times never adds a step), as a float: the steps of
    every fixed-step solve (`solve_saved`, and `simulate`'s CPU kernel)."""
    return jnp.maximum(jnp.ceil(width / dt0 * (1 - 1e-6)), 1)


@eqx.filter_jit  # one compilation per problem structure, as `diffrax.diffeqsolve` itself
def _solve_intervals(
    term, solver, stepsize_controller, ts, y0, args, dt0, max_steps, adjoint, meter, event=None
):
    """The `lax.scan` over output intervals of `solve_saved`; returns `((ys, event_t), stats,
    result)` (`event_t` None without `event`). Each interval starts from the state the previous
    one reached (also after it hit `max_steps`); once the state is non-finite the remaining
    intervals are empty (`t1 = t0`: no steps) and repeat it, as they do after a terminating
    event."""
    adaptive = isinstance(stepsize_controller, diffrax.AbstractAdaptiveStepSizeController)
    if adaptive and dt0 is None:
        t_next, _ = stepsize_controller.init(
            term, ts[0], ts[-1], y0, None, args, solver.func, solver.error_order(term)
        )
        dt0 = t_next - ts[0]
    span = ts[-1] - ts[0]
    keys = ("num_steps", "num_accepted_steps", "num_rejected_steps")

    def finite(y):
        return jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(y)]))

    def solve(y, t0, t1, h, active):
        """One `diffeqsolve` over `[t0, t1]`: `(y1, its result, counts, the event's time or
        inf)`; `active`: whether the event is looked for."""
        sol = diffrax.diffeqsolve(
            term,
            solver,
            t0,
            t1,
            h,
            y,
            args=args,
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=stepsize_controller,
            max_steps=max_steps,
            adjoint=adjoint,
            event=None if event is None else event.diffrax_event(active),
            throw=False,  # `solve_saved` raises, naming the interval
        )
        y1 = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
        counts = jnp.stack([sol.stats[k] for k in keys])
        if event is None:
            return y1, sol.result, counts, None
        hit = sol.result == diffrax.RESULTS.event_occurred
        if isinstance(solver, StepEndMap):  # the interpolated state at the event, mapped
            y1 = jax.tree.map(lambda a, b: jnp.where(hit, a, b), solver.fn(y1)[0], y1)
        result = diffrax.RESULTS.where(hit, diffrax.RESULTS.successful, sol.result)
        return y1, result, counts, jnp.where(hit, cast(Array, sol.ts)[-1], jnp.inf)

    def interval(carry, t01):
        y, h, meter_state, result, t_event = carry
        ok = result == diffrax.RESULTS.successful
        alive = finite(y)
        if event is not None and event.terminate:  # stopped at the event: empty intervals
            t01 = jnp.stack([t01[0], jnp.where(jnp.isinf(t_event), t01[1], t01[0])])
        if adaptive:  # a non-finite state is not integrated further (its steps would all be
            # rejected until max_steps): the interval is empty, t1 = t0
            t01 = jnp.stack([t01[0], jnp.where(alive, t01[1], t01[0])])
        else:  # the fewest equal steps of at most dt0 (to 1e-6, against rounding), a hair
            # above width/n so that Diffrax's ceil(width/h) is exactly n. A non-finite state
            # just takes its n steps: the step count then depends on the times only, so under
            # `jax.vmap` (a sweep) the loop stays unbatched instead of masking every step
            width = t01[1] - t01[0]  # (an empty interval, after a terminating event: dt0)
            h = jnp.where(width > 0, width / fixed_step_count(width, dt0), dt0)
            h = h * (1 + 4 * jnp.finfo(width.dtype).eps)
        active = jnp.isinf(t_event)
        y1, step_result, counts, t_hit = solve(y, t01[0], t01[1], h, active)
        accepted = counts[1]
        if event is not None:
            if not event.terminate:  # the interval again without the event: the same states
                # as the solve without it (an empty solve where there was none)
                found = jnp.isfinite(cast(Array, t_hit))
                again = solve(y, t01[0], jnp.where(found, t01[1], t01[0]), h, jnp.array(False))
                y1 = jax.tree.map(lambda a, b: jnp.where(found, a, b), again[0], y1)
                step_result = diffrax.RESULTS.where(found, again[1], step_result)
                counts = counts + again[2]
                accepted = jnp.where(found, again[2][1], accepted)
            t_event = jnp.where(active, cast(Array, t_hit), t_event)
        step_result = diffrax.RESULTS.where(
            finite(y1) | (step_result != diffrax.RESULTS.successful),
            step_result,
            cast(diffrax.RESULTS, diffrax.RESULTS.nonfinite),
        )
        if adaptive:  # the next interval starts at this one's mean accepted step
            h_next = (t01[1] - t01[0]) / jnp.maximum(accepted, 1)
            h = jnp.where(alive & (t01[1] > t01[0]), h_next, h)
        meter_state = meter.step(meter_state, (t01[1] - ts[0]) / span)
        result = diffrax.RESULTS.where(ok, step_result, result)  # keep the first failure
        valid = result == diffrax.RESULTS.successful
        return (y1, h, meter_state, result, t_event), (y1, counts, valid)

    t_none = jnp.asarray(jnp.inf, ts.dtype)
    init = (y0, dt0, meter.init(), diffrax.RESULTS.successful, t_none)
    (_, _, meter_state, result, t_event), (ys, counts, valid) = jax.lax.scan(
        interval, init, jnp.stack([ts[:-1], ts[1:]], axis=1)
    )
    meter.close(meter_state)
    ys = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), y0, ys)
    stats: dict[str, Array] = dict(zip(keys, jnp.sum(counts, axis=0), strict=True))
    stats["num_valid"] = 1 + jnp.sum(valid)
    return (ys, None if event is None else t_event), stats, result
