"""Diffrax solvers: explicit Runge–Kutta with unrolled stages (`ExplicitRK`), classical `RK4`,
the Lie-group Runge–Kutta–Munthe-Kaas solver on SO(3) (`RKMK`, `LieTerm`) and the step-end
projection wrapper (`StepEndMap`). The stage machinery is written once, in `_stages`."""

from .explicit_rk import ExplicitRK
from .rk4 import RK4
from .rkmk import RKMK, LieTerm
from .step_end_map import StepEndMap

__all__ = ["RK4", "RKMK", "ExplicitRK", "LieTerm", "StepEndMap"]
