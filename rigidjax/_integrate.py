"""The one integration driver: from solver options (`SolveOptions`) to `diffrax.diffeqsolve` to
the states at the output times. Every integrating entry point (`darboux`, `simulate`, the heavy
top, 6-DOF bodies, Kepler, the satellite, identification) goes through `solve_saved`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TypedDict, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, PyTree

from ._custom_types import Frame
from .solvers.explicit_rk import unrolled
from .solvers.rkmk import RKMK
from .solvers.step_end_map import StepEndMap


def default_tolerances(dtype, *, tight: bool = False) -> tuple[float, float]:
    """The defaults of every integrator, per dtype, decided here only: `(rtol, atol)` = 1e-10 in
    float64 (1e-12 with `tight`, for orbits followed over many periods) and 1e-6 in float32."""
    if jnp.finfo(dtype).eps < 1e-10:
        return (1e-12, 1e-12) if tight else (1e-10, 1e-10)
    return (1e-6, 1e-6)


class SolveKwargs(TypedDict, total=False):
    """The keyword shorthand for the fields of `SolveOptions` (`simulate(..., rtol=1e-8)`)."""

    solver: diffrax.AbstractSolver
    stepsize_controller: diffrax.AbstractStepSizeController
    rtol: float
    atol: float
    dt0: float
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
    - `max_steps`: bound on the steps of each output interval.
    - `adjoint`: default `diffrax.RecursiveCheckpointAdjoint()`; `diffrax.ForwardMode()` for
      `jax.jacfwd`.
    - `progress_meter`: default none; e.g. `diffrax.TqdmProgressMeter()`.
    - `throw`: raise when the solve fails (default); with `False` the trajectory comes back
      with its `result` set to the failure (e.g. `diffrax.RESULTS.max_steps_reached`).
    """

    solver: diffrax.AbstractSolver | None = None
    stepsize_controller: diffrax.AbstractStepSizeController | None = None
    rtol: float | None = None
    atol: float | None = None
    dt0: float | None = None
    max_steps: int = eqx.field(static=True, default=100_000)
    adjoint: diffrax.AbstractAdjoint | None = None
    progress_meter: diffrax.AbstractProgressMeter | None = None
    throw: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        for name in ("rtol", "atol", "dt0"):
            value = getattr(self, name)
            if isinstance(value, int | float) and not value > 0:
                raise ValueError(f"{name} must be positive, got {value}")
        if not (isinstance(self.max_steps, int) and self.max_steps > 0):
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
        return dataclasses.replace(options, **kwargs) if kwargs else options


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
) -> tuple[PyTree, dict[str, Array], diffrax.RESULTS]:
    """Integrate `term` from `ts[0]` through every output time `ts[k]` with `options`; returns
    `(ys (T, ...), stats, result)`: step counts summed over the intervals and the first failure
    (`diffrax.RESULTS.successful` if none; failures raise unless `options.throw` is False).

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
    error norm `norm` when given."""
    solver = unrolled(options.solver if solver is None else solver)
    adjoint = diffrax.RecursiveCheckpointAdjoint() if options.adjoint is None else options.adjoint
    meter = diffrax.NoProgressMeter() if options.progress_meter is None else options.progress_meter
    if step_end is not None:
        solver = StepEndMap.wrap(solver, step_end, adjoint)
    controller = options.stepsize_controller
    if controller is None:
        d_rtol, d_atol = default_tolerances(ts.dtype, tight=tight)
        controller = diffrax.PIDController(
            rtol=d_rtol if options.rtol is None else options.rtol,
            atol=d_atol if options.atol is None else options.atol,
            norm=optx.rms_norm if norm is None else norm,  # Diffrax's default norm
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
    return _solve_intervals(
        term,
        solver,
        controller,
        ts,
        y0,
        args,
        dt0,
        options.max_steps,
        adjoint,
        meter,
        options.throw,
    )


@eqx.filter_jit  # one compilation per problem structure, as `diffrax.diffeqsolve` itself
def _solve_intervals(
    term, solver, stepsize_controller, ts, y0, args, dt0, max_steps, adjoint, meter, throw
):
    """The `lax.scan` over output intervals of `solve_saved`."""
    adaptive = isinstance(stepsize_controller, diffrax.AbstractAdaptiveStepSizeController)
    if adaptive and dt0 is None:
        t_next, _ = stepsize_controller.init(
            term, ts[0], ts[-1], y0, None, args, solver.func, solver.error_order(term)
        )
        dt0 = t_next - ts[0]
    span = ts[-1] - ts[0]
    keys = ("num_steps", "num_accepted_steps", "num_rejected_steps")

    def interval(carry, t01):
        y, h, meter_state, result = carry
        if not adaptive:  # the fewest equal steps of at most dt0 (to 1e-6, against rounding)
            width = t01[1] - t01[0]
            n = jnp.maximum(jnp.ceil(width / dt0 * (1 - 1e-6)), 1)
            # a hair above width/n, so that Diffrax's ceil(width/h) is exactly n
            h = width / n * (1 + 4 * jnp.finfo(width.dtype).eps)
        sol = diffrax.diffeqsolve(
            term,
            solver,
            t01[0],
            t01[1],
            h,
            y,
            args=args,
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=stepsize_controller,
            max_steps=max_steps,
            adjoint=adjoint,
            throw=throw,
        )
        y1 = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
        if adaptive:  # the next interval starts at this one's mean accepted step
            h = (t01[1] - t01[0]) / jnp.maximum(sol.stats["num_accepted_steps"], 1)
        meter_state = meter.step(meter_state, (t01[1] - ts[0]) / span)
        ok = result == diffrax.RESULTS.successful
        result = diffrax.RESULTS.where(ok, sol.result, result)  # keep the first failure
        return (y1, h, meter_state, result), (y1, jnp.stack([sol.stats[k] for k in keys]))

    init = (y0, dt0, meter.init(), diffrax.RESULTS.successful)
    (_, _, meter_state, result), (ys, counts) = jax.lax.scan(
        interval, init, jnp.stack([ts[:-1], ts[1:]], axis=1)
    )
    meter.close(meter_state)
    ys = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), y0, ys)
    stats: dict[str, Array] = dict(zip(keys, jnp.sum(counts, axis=0), strict=True))
    return ys, stats, result
