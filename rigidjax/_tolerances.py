"""The integrators' tolerances and step: their defaults per dtype, the warning for unreachable
ones, and their checks (`rtol`, `atol`: positive finite numbers; `dt0`: a positive number,
`inf` for one step per output interval, as `ExactFreeBody` takes by default)."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from ._checks import concrete_value, validate
from ._custom_types import RealScalarLike


def python_int(value: Any) -> Any:
    """A NumPy integer as a Python int, anything else unchanged (for static step counts such as
    `SolveOptions.max_steps`: a static field is hashed and printed; its check follows)."""
    return int(value) if isinstance(value, np.integer) else value


def default_tolerances(dtype, *, tight: bool = False) -> tuple[float, float]:
    """The defaults of every integrator, per dtype, decided here only: `(rtol, atol)` = 1e-10 in
    float64 (1e-12 with `tight`, for orbits followed over many periods) and 1e-6 in float32."""
    if jnp.finfo(dtype).eps < 1e-10:
        return (1e-12, 1e-12) if tight else (1e-10, 1e-10)
    return (1e-6, 1e-6)


def default_controller(
    dtype,
    rtol: RealScalarLike | None,
    atol: RealScalarLike | None,
    *,
    norm: Callable | None = None,
    tight: bool = False,
) -> diffrax.PIDController:
    """The step-size controller of a solve given none: Diffrax's `PIDController` at `rtol`,
    `atol` (`default_tolerances` where None; a traced one in `dtype`) with error norm `norm`
    (Diffrax's RMS norm by default)."""
    d_rtol, d_atol = default_tolerances(dtype, tight=tight)
    return diffrax.PIDController(
        rtol=d_rtol if rtol is None else in_dtype(rtol, dtype),
        atol=d_atol if atol is None else in_dtype(atol, dtype),
        norm=optx.rms_norm if norm is None else norm,
    )


def attainable(dtype) -> float:
    """The smallest tolerance `dtype` can meet: a few ulps, 4 eps (8.9e-16 in float64)."""
    return 4 * float(jnp.finfo(dtype).eps)


def warn_unattainable(dtype, rtol: RealScalarLike | None, atol: RealScalarLike | None) -> None:
    """Warn when a tolerance known now asks for more than `dtype` can give (`attainable`)."""
    floor = attainable(dtype)
    wider = (
        ""
        if jnp.finfo(dtype).eps < 1e-10
        else ", or float64 (jax.config.update('jax_enable_x64', True) and float64 inputs)"
    )
    for name, given in (("rtol", rtol), ("atol", atol)):
        value = None if given is None else concrete_value(given)
        if value is not None and value < floor:
            warnings.warn(
                f"{name} = {value:g} is below what {jnp.dtype(dtype).name} can reach (about "
                f"{floor:.1g}); the solver will take tiny steps and may not converge. Use "
                f"{name} >= {floor:.1g}{wider}",
                stacklevel=4,
            )


def _bad(name: str, xp, v):
    """Not a valid `name` (see the module docstring): the predicate of both checks."""
    ok = (v > 0) if name == "dt0" else (v > 0) & xp.isfinite(v)
    return ~ok


def check_discretisation(value: RealScalarLike | None, name: str) -> None:
    """A ValueError if a known `rtol`, `atol` or `dt0` is not valid (traced: `discretisation`)."""
    v = None if value is None else concrete_value(value)
    if v is not None and (v.ndim != 0 or v.dtype == bool or _bad(name, np, v)):
        raise ValueError(f"{name} must be a positive number, got {value}")


def discretisation(value: RealScalarLike, name: str) -> float | Array:
    """`rtol`, `atol` or `dt0` as the solvers take it: a known value as a Python float (weakly
    typed: a float64 value must not promote a float32 solve), a traced one checked when the
    program runs. They set the discretisation, not the motion: their derivatives are zero (fixed
    steps round to a whole number per interval)."""
    if jnp.ndim(value) != 0:
        raise ValueError(f"{name} must be a number, got shape {jnp.shape(value)}")
    known = concrete_value(value)
    if known is not None:
        return float(known)
    bad = lambda xp, v: _bad(name, xp, v)  # noqa: E731
    traced = jax.lax.stop_gradient(jnp.asarray(value))
    return validate(traced, bad, f"{name} must be a positive number")


def in_dtype(value: RealScalarLike, dtype) -> RealScalarLike:
    """A traced tolerance in the solve's dtype (a float64 one would promote a float32 state in
    Diffrax's controller); a Python float as it is."""
    return value if type(value) is float else jnp.asarray(value, dtype)
