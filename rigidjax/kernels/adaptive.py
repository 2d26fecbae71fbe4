"""Any model's ODE at adaptive steps of an embedded Runge–Kutta pair (Bosh3, Tsit5, Dopri5,
Dopri8) on the CPU, each body its own step size (built `fixed`: each body its own fixed steps of
any `tableau.METHODS`, for what the fixed-step kernel's bodies in lockstep cannot do, an
event): the model kernel (`kernels.model`, `model.cc`) built with `model_adaptive.h`, step for
step Diffrax's `PIDController` on the Diffrax path of one body (its error norm, coefficients,
initial-step heuristic and the clipping of the last step to each output time), so that a body's
trajectory is the same alone, in a batch or under `jax.vmap`. Reverse mode: the kernel's
discrete adjoint of the accepted steps (whose sizes are constants, as Diffrax's `stop_gradient`
of the controller makes them), recomputed interval by interval from the saved states."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, cast

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float, Int

from .._custom_types import RealScalarLike
from . import tableau
from ._build import load
from ._source import header, headers, linked
from .model import _NAME, Hoisted, Schedule, block_cotangents, call, forward_part

__all__ = ["AdaptiveKernel", "build", "controls", "run"]

CONTROLS = 14
"""The controller's values, as `Ctl` of `model_adaptive.h` reads them: rtol, atol, safety,
factormin, factormax, dtmax (∞ for none), dt0 (NaN: the heuristic), the exponents β1, β2, β3
of the inverse scaled errors, 1 / the error order, max_steps; the event's direction (0 either,
1 rising, −1 falling) and whether it terminates (1) or not (0)."""


class AdaptiveKernel(NamedTuple):
    """A built adaptive kernel: its forward handler's name, the header of its reverse mode
    (built and registered on the first gradient), sizes (P counts the lifted constants) and the
    components `(R0, NR)` that each jump records."""

    forward: str
    backward_header: tuple[str, str]
    n: int
    p: int
    record: tuple[int, int]
    event: bool = False  # the model has an event condition (`Model::G`)

    def __repr__(self) -> str:
        return f"AdaptiveKernel({self.forward}, n={self.n}, p={self.p}, record={self.record})"

    def backward(self) -> str:
        """The reverse mode's handler, built and registered on the first call."""
        text, name = self.backward_header
        if load(_NAME, (name,), headers(text, adaptive=True), linked(text)) is None:
            raise RuntimeError(
                "the reverse mode of rigidjax's adaptive model kernel could not be built (see "
                "the warning); pass solver=rigidjax.ExplicitRK(method) to differentiate "
                "through Diffrax"
            )
        return name


def controls(
    controller: diffrax.AbstractStepSizeController,
    solver: diffrax.AbstractSolver,
    dt0: RealScalarLike | None,
    max_steps: int,
    dtype,
    direction: int | None = None,
    terminate: bool = True,
) -> np.ndarray | None:
    """The controller's values for the kernel (`CONTROLS`), or None where `controller` asks for
    what the kernel does not do: a controller other than a plain `diffrax.PIDController`
    (`dtmin`, `step_ts`, `jump_ts` unset), a solver without an adaptive kernel, traced values."""
    if type(solver) not in tableau.ADAPTIVE or type(controller) is not diffrax.PIDController:
        return None
    pid = cast(diffrax.PIDController, controller)
    if pid.dtmin is not None or pid.error_order is not None:
        return None
    if getattr(pid, "step_ts", None) is not None or getattr(pid, "jump_ts", None) is not None:
        return None
    order = solver.error_order(diffrax.ODETerm(lambda t, y, args: y))
    assert order is not None
    coeffs = (
        pid.icoeff + pid.pcoeff + pid.dcoeff,
        -(pid.pcoeff + 2 * pid.dcoeff),
        pid.dcoeff,
    )
    values = [
        pid.rtol,
        pid.atol,
        pid.safety,
        pid.factormin,
        pid.factormax,
        math.inf if pid.dtmax is None else pid.dtmax,
        math.nan if dt0 is None else dt0,
        *(c / order for c in coeffs),
        1 / order,
        max_steps,
        0 if direction is None else direction,
        1 if terminate else 0,
    ]
    try:  # NumPy: constants of the program (no tracer for the custom rules to close over)
        return np.asarray([float(v) for v in values], dtype=dtype)
    except (TypeError, jax.errors.ConcretizationTypeError):
        return None  # a traced tolerance: the Diffrax path


def fixed_controls(
    dt0: RealScalarLike,
    max_steps: int,
    dtype,
    direction: int | None = None,
    terminate: bool = True,
) -> np.ndarray | None:
    """The values (`CONTROLS`) of the per-body kernel at fixed steps (`build(..., fixed=True)`):
    the fewest equal steps of at most `dt0` per output interval, at most `max_steps`, and the
    event's direction and termination (the controller's values unused); None where `dt0` is
    traced."""
    try:
        step = float(dt0)
    except (TypeError, jax.errors.ConcretizationTypeError):
        return None
    values = [0, 0, 0, 0, 0, math.inf, step, 0, 0, 0, 0, max_steps]
    values += [0 if direction is None else direction, 1 if terminate else 0]
    return np.asarray(values, dtype=dtype)


def build(
    hoisted: Hoisted,
    unit: tuple[tuple[int, int], ...],
    solver: diffrax.AbstractSolver,
    record: tuple[int, int] = (0, 0),
    fixed: bool = False,
) -> AdaptiveKernel | None:
    """The adaptive kernel of `hoisted` for `solver` (one of `tableau.ADAPTIVE`; with `fixed`,
    the per-body kernel of fixed steps, one of `tableau.METHODS`) in its dtype, its forward
    part built and registered on first use; None where kernels cannot run here."""
    built = forward_part(hoisted, unit, solver, record, adaptive=True, fixed=fixed)
    if built is None:
        return None
    method, source, name = built
    back = header(method, hoisted.dtype, source, "backward", False, adaptive=True, fixed=fixed)
    size = hoisted.p + hoisted.c.shape[0]
    return AdaptiveKernel(name, back, hoisted.n, size, record, hoisted.events)


Through = Callable[[Array, tuple, Array, Any], tuple[Array, Array, Array]]
"""`(y0, blocks, ts, extra) -> (ys (B, S, N), recorded (B, R, NR), event times (B,))`: the same
solve through Diffrax, whose reverse mode differentiates the output times and the events
(`extra`: `run`'s, e.g. the event's arrays)."""


def run(
    kernel: AdaptiveKernel,
    y0: Float[Array, "B N"],
    blocks: Sequence[Float[Array, "#B _"]],
    ts: Float[Array, " T"],
    ctl: Float[np.ndarray, " 14"],
    through: Through,
    jump: np.ndarray | None = None,
    keep: np.ndarray | None = None,
    extra: Any = (),
) -> tuple[Float[Array, "B S N"], Float[Array, "B R NR"], Int[Array, "B 5"], Float[Array, " B"]]:
    """The states `(B, S, N)` at the times `keep (T,)` selects (all by default), the components
    `kernel.record` after each jump `(B, R, NR)` (the intervals `jump (T − 1,)` flags start with
    the jump map), and per body `(B, 5)`: attempted, accepted and rejected steps, the leading
    output times reached, and the result (0 successful, 1 max_steps reached, 2 non-finite), and
    the first event's time `(B,)` (∞ where none; a kernel with an event).
    The parameters and lifted constants come in `blocks`, each `(B or 1, Pj)`; the controller
    in `ctl` (`controls`). Reverse mode by the kernel's adjoint of the accepted steps; where the
    output times are differentiated, or there is an event, by `through`'s, which alone reads
    `extra` (a PyTree of arrays, an operand: e.g. the event condition's arrays, which a
    closure would leak out of this rule's trace)."""
    K, B, dtype = ts.shape[0] - 1, y0.shape[0], y0.dtype
    sc = Schedule.of(K, jump, keep, kernel.record[1])
    kept, every_kept = sc.kept, sc.kept.size == K + 1

    def run_call(y0, blocks, ts, ctl, save, S):
        shapes = [
            jax.ShapeDtypeStruct((B, S, kernel.n), dtype),
            jax.ShapeDtypeStruct((B, sc.at.size, kernel.record[1]), dtype),
            jax.ShapeDtypeStruct((B, K), dtype),
            jax.ShapeDtypeStruct((B, 5), jnp.int32),
            jax.ShapeDtypeStruct((B,), dtype),
        ]
        return call(kernel.forward, shapes, y0, ts, sc.jump, save, ctl, *blocks)

    def forward(y0, blocks, ts, ctl, extra):
        y, rec, _, st, ev = run_call(y0, blocks, ts, ctl, sc.save, kept.size)
        return y, rec, st, ev

    def run_fwd(y0, blocks, ts, ctl, extra):
        differentiated = ts.perturbed or kernel.event
        y0, ts, ctl = y0.value, ts.value, ctl.value
        blocks, extra = (jax.tree.map(lambda x: x.value, x) for x in (blocks, extra))
        if differentiated:
            out = forward(y0, blocks, ts, ctl, extra)
            _, pullback = jax.vjp(through, y0, blocks, ts, extra)
            return out, (pullback,)
        y, rec, hk, st, ev = run_call(y0, blocks, ts, ctl, sc.every, K + 1)
        return (y if every_kept else y[:, kept], rec, st, ev), (y, blocks, ts, ctl, hk)

    def run_bwd(residuals, g):
        if len(residuals) == 1:
            shapes = [(B, kept.size, kernel.n), (B, sc.at.size, kernel.record[1]), (B,)]
            dense = tuple(
                jnp.zeros(shape, dtype) if isinstance(x, SymbolicZero) else x
                for x, shape in zip((g[0], g[1], g[3]), shapes, strict=True)
            )
            y0b, gb, tb, eb = residuals[0](dense)
            return y0b, gb, tb, None, eb
        y, blocks, ts, ctl, hk = residuals
        gy = sc.cotangent(y, g[:2], kernel.n, kernel.record)
        out = [jax.ShapeDtypeStruct((B, m), dtype) for m in (kernel.n, kernel.p)]
        y0b, pb = call(kernel.backward(), out, y, ts, sc.jump, sc.every, ctl, hk, gy, *blocks)
        return y0b, block_cotangents(pb, blocks), None, None, None

    solve = jax.custom_vjp(forward)
    solve.defvjp(run_fwd, run_bwd, symbolic_zeros=True)
    return solve(y0, tuple(blocks), ts, ctl, extra)
