"""rigidjax: JAX-accelerated, differentiable rigid-body rotation maps, kinematics and dynamics."""

from . import andoyer, euler, gibbs, kinematics, mrp, quat, so3
from .attitude import darboux, omega_path
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

__all__ = [
    "RKMK",
    "AbstractKinematics",
    "CayleyKlein",
    "EulerAngles",
    "LieTerm",
    "PoissonMatrix",
    "Quaternion",
    "RotationVector",
    "StepEndMap",
    "andoyer",
    "darboux",
    "euler",
    "gibbs",
    "kinematics",
    "mrp",
    "omega_path",
    "quat",
    "so3",
]
__version__ = "0.1.0"
