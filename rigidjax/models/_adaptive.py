"""The adaptive CPU kernel as a backend of `models.solve`: what options it serves, its solve,
and its per-body results folded into `solve_saved`'s."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, cast

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from .._batch import first_failure
from .._integrate import SolveOptions
from .._tolerances import default_controller, warn_unattainable
from ..events import Event
from ..kernels import adaptive, tableau
from ._diffrax_path import method_of


def controls(
    options: SolveOptions, norm: Callable, dtype, event: Event | None = None
) -> np.ndarray | None:
    """The adaptive kernel's controller values (`kernels.adaptive.controls`) for `options`, or
    None where they ask for what it does not do: a solver other than an embedded pair of
    `tableau.ADAPTIVE` (`ExplicitRK(method)` asks for the Diffrax path), a controller other
    than a plain `PIDController`, another adjoint than the default, a progress meter.
    Without a controller, `solve_saved`'s: a `PIDController` at `options.rtol`, `options.atol`
    (`default_tolerances`) with `norm`. An `event`'s direction and termination go with them.
    Fixed steps (`diffrax.ConstantStepSize`, one of `tableau.METHODS`): the per-body kernel's
    at fixed steps (`kernels.adaptive.fixed_controls`), with an `event` only (without one,
    the fixed-step kernel steps the bodies in lockstep)."""
    fixed = isinstance(options.stepsize_controller, diffrax.ConstantStepSize)
    if fixed:
        solver = method_of(options)
    else:
        solver = diffrax.Tsit5() if options.solver is None else options.solver
    if (
        type(solver) not in (tableau.METHODS if fixed else tableau.ADAPTIVE)
        or not isinstance(options.adjoint, None | diffrax.RecursiveCheckpointAdjoint)
        or not isinstance(options.progress_meter, None | diffrax.NoProgressMeter)
    ):
        return None
    if fixed:
        if event is None or options.dt0 is None:
            return None
        args = (options.dt0, options.max_steps, dtype, event.direction, event.terminate)
        return adaptive.fixed_controls(*args)
    controller = options.stepsize_controller
    if controller is None:
        controller = default_controller(dtype, options.rtol, options.atol, norm=norm)
    elif isinstance(controller, diffrax.PIDController) and not (
        controller.norm is optx.rms_norm or type(controller.norm) is type(norm)
    ):
        return None  # a norm of the user's (the kernel's is the RMS of one body's state)
    values = adaptive.controls(
        controller,
        solver,
        options.dt0,
        options.max_steps,
        dtype,
        None if event is None else event.direction,
        True if event is None else event.terminate,
    )
    if values is not None:
        warn_unattainable(dtype, options.rtol, options.atol)
    return values


@functools.partial(jax.jit, static_argnums=1)
def per_body(st: Array, single: bool, kept: Array | np.ndarray) -> tuple[dict[str, Array], Any]:
    """`(stats, result)` from the kernel's per-body counts `st (B, 5)`: the steps of each body
    (`(B,)`; scalars for one body, `single`) and the batch's first failure (`num_valid`: the
    leading kept output times every body reached, `kept` the indices of those kept; `result`:
    that of a body that failed first). One compiled program: eagerly, op by op, a first call
    compiled some twenty."""
    counts = st[0] if single else st.T
    stats = {
        "num_steps": counts[0],
        "num_accepted_steps": counts[1],
        "num_rejected_steps": counts[2],
    }
    results = jax.vmap(_result)(st[:, 4])
    stats, result = first_failure({**stats, "num_valid": st[:, 3]}, results)
    # (the leading kept output times every body reached)
    stats["num_valid"] = jnp.sum(kept < stats["num_valid"])
    return stats, result


def _result(code: Array) -> Any:
    """The Diffrax result of the kernel's code: 0 successful, 1 max_steps reached, 2
    non-finite."""
    return diffrax.RESULTS.where(
        code == 0,
        diffrax.RESULTS.successful,
        diffrax.RESULTS.where(
            code == 1,
            cast(diffrax.RESULTS, diffrax.RESULTS.max_steps_reached),
            cast(diffrax.RESULTS, diffrax.RESULTS.nonfinite),
        ),
    )
