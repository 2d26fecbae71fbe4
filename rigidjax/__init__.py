"""rigidjax: JAX-accelerated, differentiable rigid-body rotation maps, kinematics and dynamics."""

from . import (
    analytic,
    andoyer,
    euler,
    gibbs,
    heavy_top,
    inertia,
    invariants,
    kepler,
    kinematics,
    mrp,
    quat,
    satellite,
    sixdof,
    so3,
    stability,
)
from .attitude import darboux, omega_path
from .body import RigidBody
from .dynamics import Trajectory, simulate
from .explicit_rk import ExplicitRK
from .heavy_top import HeavyTop, simulate_heavy_top
from .identify import InertiaEstimate, identify_inertia
from .invariants import angular_momentum, energy
from .kinematics import (
    AbstractKinematics,
    CayleyKlein,
    EulerAngles,
    PoissonMatrix,
    Quaternion,
    RotationVector,
)
from .lie_solver import RKMK, LieTerm
from .projected_solver import StepEndMap
from .rk4 import RK4

__all__ = [
    "RK4",
    "RKMK",
    "RigidBody",
    "Trajectory",
    "AbstractKinematics",
    "CayleyKlein",
    "EulerAngles",
    "ExplicitRK",
    "HeavyTop",
    "InertiaEstimate",
    "LieTerm",
    "PoissonMatrix",
    "Quaternion",
    "RotationVector",
    "StepEndMap",
    "analytic",
    "andoyer",
    "angular_momentum",
    "darboux",
    "energy",
    "euler",
    "gibbs",
    "heavy_top",
    "identify_inertia",
    "inertia",
    "kepler",
    "invariants",
    "kinematics",
    "mrp",
    "omega_path",
    "quat",
    "satellite",
    "simulate",
    "simulate_heavy_top",
    "sixdof",
    "stability",
    "so3",
]
__version__ = "0.1.0"
