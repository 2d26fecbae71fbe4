"""Mechanics: rigid bodies and inertia tensors, Euler's equations (`simulate`), invariants,
stability of stationary rotations, the gyrostat, the heavy top, 6-DOF bodies, the Kepler
problem and the gravity-gradient satellite."""

# The submodules not imported for their names below (`body`, `dynamics`, ... come with those).
from . import inertia, kepler, satellite, sixdof, stability
from .body import RigidBody
from .dynamics import Trajectory, simulate
from .gyrostat import Gyrostat, GyrostatTrajectory
from .heavy_top import HeavyTop, simulate_heavy_top
from .invariants import angular_momentum, energy

__all__ = [
    "Gyrostat",
    "GyrostatTrajectory",
    "HeavyTop",
    "RigidBody",
    "Trajectory",
    "angular_momentum",
    "body",
    "dynamics",
    "energy",
    "gyrostat",
    "heavy_top",
    "inertia",
    "invariants",
    "kepler",
    "satellite",
    "simulate",
    "simulate_heavy_top",
    "sixdof",
    "stability",
]
