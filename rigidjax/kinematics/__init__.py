"""Kinematics, the Darboux problem: every formulation of the attitude's equation of motion
(`formulations`, one registry `METHODS`) and `darboux`, the attitude from a given angular
velocity (`darboux`)."""

from .darboux import darboux, omega_path
from .formulations import (
    METHODS,
    AbstractKinematics,
    CayleyKlein,
    EulerAngles,
    PoissonMatrix,
    Quaternion,
    RotationVector,
    check_omega,
)

__all__ = [
    "METHODS",
    "AbstractKinematics",
    "CayleyKlein",
    "EulerAngles",
    "PoissonMatrix",
    "Quaternion",
    "RotationVector",
    "check_omega",
    "darboux",
    "omega_path",
]
