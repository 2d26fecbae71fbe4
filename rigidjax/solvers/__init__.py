"""Diffrax solvers: explicit Runge–Kutta with unrolled stages (`ExplicitRK`), classical `RK4`,
the Lie-group Runge–Kutta–Munthe-Kaas solver on SO(3) (`RKMK`, `LieTerm`), the step-end
projection wrapper (`StepEndMap`), and the exact and structure-preserving rigid-body solvers
(`ExactFreeBody`, `LiePoissonSplitting`, with their vector field `RigidBodyField`). The stage
machinery is written once, in `_stages`."""

from .exact_free_body import ExactFreeBody, RigidBodyField
from .explicit_rk import ExplicitRK
from .rk4 import RK4
from .rkmk import RKMK, LieTerm
from .splitting import LiePoissonSplitting
from .step_end_map import StepEndMap

__all__ = [
    "RK4",
    "RKMK",
    "ExactFreeBody",
    "ExplicitRK",
    "LiePoissonSplitting",
    "LieTerm",
    "RigidBodyField",
    "StepEndMap",
]
