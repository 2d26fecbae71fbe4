"""The integrators' tolerances: their defaults per dtype and the warning for unreachable ones."""

from __future__ import annotations

import warnings

import jax.numpy as jnp

from ._checks import concrete_value
from ._custom_types import RealScalarLike


def default_tolerances(dtype, *, tight: bool = False) -> tuple[float, float]:
    """The defaults of every integrator, per dtype, decided here only: `(rtol, atol)` = 1e-10 in
    float64 (1e-12 with `tight`, for orbits followed over many periods) and 1e-6 in float32."""
    if jnp.finfo(dtype).eps < 1e-10:
        return (1e-12, 1e-12) if tight else (1e-10, 1e-10)
    return (1e-6, 1e-6)


def warn_unattainable(dtype, rtol: RealScalarLike | None, atol: RealScalarLike | None) -> None:
    """Warn when a tolerance known now asks for more than `dtype` can give (a few ulps)."""
    attainable = 4 * float(jnp.finfo(dtype).eps)
    for name, given in (("rtol", rtol), ("atol", atol)):
        value = None if given is None else concrete_value(given)
        if value is not None and value < attainable:
            warnings.warn(
                f"{name} = {value:g} is below what {jnp.dtype(dtype).name} can reach (about "
                f"{attainable:.1g}); the solver will take tiny steps and may not converge. Use "
                f"{name} >= {attainable:.1g}, or float64 (jax.config.update('jax_enable_x64', "
                "True) and float64 inputs)",
                stacklevel=4,
            )
