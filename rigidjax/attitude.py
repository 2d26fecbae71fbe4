"""The Darboux problem: the rotation P(t) from a given angular velocity (Zhilin 3.12–3.14)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from . import so3
from ._util import as_float, matrix, norm_tolerance, validate
from .explicit_rk import unrolled as _unrolled
from .kinematics import METHODS, AbstractKinematics, check_omega
from .lie_solver import RKMK, LieTerm
from .projected_solver import StepEndMap

Frame = Literal["space", "body"]
OmegaLike = Callable[[Array], Array] | diffrax.AbstractPath | tuple[ArrayLike, ArrayLike]


def omega_path(omega: OmegaLike) -> Callable[[Array], Array]:
    """A callable `t -> (3,)` from a callable, a Diffrax path, or sampled data `(t_k, ω_k)`.

    Samples (e.g. gyro readings) are interpolated by a C¹ cubic Hermite spline with backward
    differences (`diffrax.backward_hermite_coefficients`), so the solver can step freely.
    """
    if isinstance(omega, diffrax.AbstractPath):
        return omega.evaluate
    if isinstance(omega, tuple):
        if len(omega) != 2:
            raise ValueError("sampled omega must be a pair (t_samples (N,), omega_samples (N, 3))")
        t_s, w_s = as_float(omega[0], "omega t_samples"), as_float(omega[1], "omega samples")
        if t_s.ndim != 1 or w_s.shape != (t_s.shape[0], 3) or t_s.shape[0] < 2:
            raise ValueError(
                f"sampled omega must be (t (N,), omega (N, 3)) with N ≥ 2, got shapes "
                f"{tuple(t_s.shape)} and {tuple(w_s.shape)}"
            )
        coeffs = diffrax.backward_hermite_coefficients(t_s, w_s)
        return diffrax.CubicInterpolation(t_s, coeffs).evaluate
    if callable(omega):
        return omega
    raise TypeError(
        f"omega must be a callable t -> (3,), a diffrax path or (t, omega), got {omega!r}"
    )


class _KinematicsField(eqx.Module):
    """`(t, y) -> ẏ` of a kinematics formulation driven by `omega(t)` (a stable, hashable
    callable, so repeated solves with the same `omega` reuse one compilation)."""

    kin: AbstractKinematics
    omega: Callable

    def __call__(self, t, y, args):
        return self.kin.vector_field(y, check_omega(self.omega(t)).astype(y.dtype))


class _LieField(eqx.Module):
    """`(t, (R, None)) -> (ω, None)` for the RKMK solver."""

    omega: Callable

    def __call__(self, t, y, args):
        return check_omega(self.omega(t)).astype(y[0].dtype), None


def check_times(ts: Array) -> Array:
    """`ts` as a 1-D strictly increasing array of at least two times (clear error otherwise)."""
    if ts.ndim != 1 or ts.shape[0] < 2:
        raise ValueError(f"ts must be a 1-D array of at least 2 times, got shape {tuple(ts.shape)}")

    def detail(t):
        k = int(np.flatnonzero(~(np.diff(t) > 0))[0])
        return f": ts[{k + 1}] = {t[k + 1]} follows ts[{k}] = {t[k]}"

    return validate(
        ts, lambda xp, t: ~(xp.diff(t) > 0), "ts must be strictly increasing and finite", detail
    )


def default_tolerances(dtype) -> tuple[float, float]:
    """(rtol, atol): 1e-10 in float64, 1e-6 in float32."""
    return (1e-10, 1e-10) if jnp.finfo(dtype).eps < 1e-10 else (1e-6, 1e-6)


def solve_saved(
    term: diffrax.AbstractTerm,
    solver: diffrax.AbstractSolver,
    ts: Array,
    y0,
    *,
    args=None,
    step_end: Callable | None = None,
    stepsize_controller: diffrax.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    tolerances: tuple[float, float] | None = None,
    norm: Callable | None = None,
    dt0: float | None = None,
    max_steps: int = 100_000,
    adjoint: diffrax.AbstractAdjoint | None = None,
    progress_meter: diffrax.AbstractProgressMeter | None = None,
):
    """Integrate `term` from `ts[0]` through every output time `ts[k]`, with the integrators'
    shared defaults; returns `(ys (T, ...), stats)` (step counts summed over the intervals).

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

    `solver` is wrapped in `StepEndMap` with `step_end` when given (for `adjoint`, default
    `RecursiveCheckpointAdjoint`). Without `stepsize_controller`, a `PIDController` at `rtol`,
    `atol` (defaults `tolerances`, else `default_tolerances(ts.dtype)`), with error norm `norm`
    when given."""
    adjoint = diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint
    meter = diffrax.NoProgressMeter() if progress_meter is None else progress_meter
    if step_end is not None:
        solver = StepEndMap.wrap(solver, step_end, adjoint)
    if stepsize_controller is None:
        d_rtol, d_atol = default_tolerances(ts.dtype) if tolerances is None else tolerances
        stepsize_controller = diffrax.PIDController(
            rtol=d_rtol if rtol is None else rtol,
            atol=d_atol if atol is None else atol,
            **({} if norm is None else {"norm": norm}),
        )
    adaptive = isinstance(stepsize_controller, diffrax.AbstractAdaptiveStepSizeController)
    if not adaptive and not isinstance(stepsize_controller, diffrax.ConstantStepSize):
        raise ValueError(
            "stepsize_controller must be diffrax.ConstantStepSize (with dt0) or an adaptive "
            f"controller such as diffrax.PIDController, got {type(stepsize_controller).__name__}"
            " (steps always end at the output times ts)"
        )
    if not adaptive and dt0 is None:
        raise ValueError("dt0 (the step size) is required with diffrax.ConstantStepSize")
    dt0 = None if dt0 is None else jnp.asarray(dt0, ts.dtype)  # traced: no recompiling per value
    return _solve_intervals(
        term, solver, stepsize_controller, ts, y0, args, dt0, max_steps, adjoint, meter
    )


@eqx.filter_jit  # one compilation per problem structure, as `diffrax.diffeqsolve` itself
def _solve_intervals(
    term, solver, stepsize_controller, ts, y0, args, dt0, max_steps, adjoint, meter
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
        y, h, meter_state = carry
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
        )
        y1 = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
        if adaptive:  # the next interval starts at this one's mean accepted step
            h = (t01[1] - t01[0]) / jnp.maximum(sol.stats["num_accepted_steps"], 1)
        meter_state = meter.step(meter_state, (t01[1] - ts[0]) / span)
        return (y1, h, meter_state), (y1, jnp.stack([sol.stats[k] for k in keys]))

    (_, _, meter_state), (ys, counts) = jax.lax.scan(
        interval, (y0, dt0, meter.init()), jnp.stack([ts[:-1], ts[1:]], axis=1)
    )
    meter.close(meter_state)
    ys = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), y0, ys)
    return ys, dict(zip(keys, jnp.sum(counts, axis=0), strict=True))


def darboux(
    omega: OmegaLike,
    ts: ArrayLike,
    P0: ArrayLike | None = None,
    frame: Frame = "space",
    method: str | AbstractKinematics = "rotvec",
    *,
    seq: str = "ZXZ",
    solver: diffrax.AbstractSolver | None = None,
    stepsize_controller: diffrax.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt0: float | None = None,
    max_steps: int = 100_000,
    adjoint: diffrax.AbstractAdjoint | None = None,
    return_state: bool = False,
) -> Float[Array, "T 3 3"] | tuple[Float[Array, "T 3 3"], Array]:
    """Solve `Ṗ = ω(t) × P` (`frame="space"`) or `Ṗ = P (Ω(t) × E)` (`frame="body"`) with
    `P(ts[0]) = P0` and return P at `ts` (Zhilin 3.12; the solution is unique and a rotation).

    `omega`: a callable `t -> (3,)`, a Diffrax path, or samples `(t_k, ω_k)` (gyro data; see
    `omega_path`). `method`: `"rotvec"` (θ̇ = Z(θ) ω with shadow switching, Zhilin 3.14),
    `"quat"`, `"matrix"` (Poisson equation, drifts off SO(3)), `"euler"` (sequence `seq`; errors at
    gimbal lock), `"cayley_klein"`, `"geometric"` (RKMK Lie-group solver, exactly on SO(3)), or an
    `AbstractKinematics` instance. Defaults: Tsit5 with unrolled stages (`ExplicitRK`;
    RKMK-Dopri5 for `"geometric"`) with a PID controller at `rtol = atol = 1e-10` (1e-6 in
    float32). Steps end at every output time and the values at `ts` are step-end states
    (`solve_saved`). `return_state=True` also returns the native states at `ts` (normalised
    quaternions, shadowed rotation vectors, ...).
    """
    ts = check_times(as_float(ts, "ts"))
    P0 = jnp.eye(3, dtype=ts.dtype) if P0 is None else matrix(P0, "P0")
    if P0.shape != (3, 3):
        raise ValueError(f"P0 must have shape (3, 3) (vmap for batches), got {tuple(P0.shape)}")
    P0 = so3.check_rotation(P0.astype(ts.dtype), norm_tolerance(ts.dtype), "P0")
    w = omega_path(omega)

    if method == "geometric":
        solver = RKMK(frame=frame) if solver is None else RKMK(method=solver, frame=frame)
        term = LieTerm(_LieField(w))
        y0 = (P0, None)
        step_end = None

        def to_matrix(y):
            return y[0]

    else:
        if isinstance(method, AbstractKinematics):
            kin = method
        elif method in METHODS:
            kwargs = {"seq": seq} if method == "euler" else {}
            kin = METHODS[method](frame=frame, **kwargs)
        else:
            raise ValueError(
                f"method must be one of {sorted([*METHODS, 'geometric'])} or an "
                f"AbstractKinematics instance, got {method!r}"
            )
        solver, step_end = _unrolled(solver), kin.step_end
        term = diffrax.ODETerm(_KinematicsField(kin, w))
        y0 = kin.from_matrix(P0)
        to_matrix = jax.vmap(kin.to_matrix)

    ys, _ = solve_saved(
        term,
        solver,
        ts,
        y0,
        step_end=step_end,
        stepsize_controller=stepsize_controller,
        rtol=rtol,
        atol=atol,
        dt0=dt0,
        max_steps=max_steps,
        adjoint=adjoint,
    )
    P = to_matrix(ys)
    return (P, P if method == "geometric" else ys) if return_state else P
