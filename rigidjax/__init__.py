"""rigidjax: JAX-accelerated, differentiable rigid-body rotation maps, kinematics and dynamics.

The package is layered; each layer uses only the ones above it:

- `rotations`: rotation maps (`so3`, `quat`, `euler`, `gibbs`, `mrp`, `andoyer`);
- `solvers`: Diffrax solvers (`ExplicitRK`, `RK4`, `RKMK`, `StepEndMap`, `ExactFreeBody`,
  `LiePoissonSplitting`);
- `_integrate`: the one driver from `SolveOptions` to `diffrax.diffeqsolve` to a trajectory;
- `kinematics`: the Darboux problem (`darboux`, the kinematics formulations);
- `mechanics`: bodies, inertia, Euler's equations (`simulate`), gyrostat, heavy top, 6-DOF,
  Kepler, ...;
- `control`: sampled-data control laws (`quaternion_pd`, `bdot`), controllers with memory;
- `sensors`, `estimation`: a rate gyro and a star tracker, the multiplicative EKF (`mekf`) and
  the estimator in the loop (`estimated`);
- `analytic`: closed forms (Jacobi elliptic functions, Euler–Poinsot, the symmetric top);
- `fit`: identification (`identify_inertia`) and experiment design (`design_excitation`);
- `cli`: the `rigidjax` command.
"""

import sys as _sys
from typing import TYPE_CHECKING

from . import (
    analytic,
    control,
    estimation,
    events,
    fit,
    kinematics,
    mechanics,
    observables,
    rotations,
    sensors,
    solvers,
)

if TYPE_CHECKING:  # imported on first use: see __getattr__
    from . import sweep
from ._integrate import IntegrationError, SolveOptions
from .events import Event
from .fit import ExcitationDesign, InertiaEstimate, design_excitation, identify_inertia
from .kinematics import (
    AbstractKinematics,
    CayleyKlein,
    EulerAngles,
    PoissonMatrix,
    Quaternion,
    RotationVector,
    darboux,
    omega_path,
)
from .mechanics import (
    Gyrostat,
    GyrostatTrajectory,
    HeavyTop,
    RigidBody,
    Trajectory,
    angular_momentum,
    energy,
    gyrostat,
    heavy_top,
    inertia,
    invariants,
    kepler,
    satellite,
    simulate,
    simulate_heavy_top,
    sixdof,
    stability,
)
from .rotations import RotationSpline, Slerp, andoyer, euler, gibbs, mrp, quat, so3
from .solvers import RK4, RKMK, ExactFreeBody, ExplicitRK, LiePoissonSplitting, LieTerm, StepEndMap

# The modules' flat names of rigidjax 0.1 (`import rigidjax.quat`, `rigidjax.heavy_top`, ...)
# keep working: they are the same module objects as in the layered packages.
_sys.modules.update(
    {
        f"{__name__}.{_m.__name__.rpartition('.')[2]}": _m
        for _m in (
            andoyer,
            euler,
            gibbs,
            gyrostat,
            heavy_top,
            inertia,
            invariants,
            kepler,
            mrp,
            quat,
            satellite,
            sixdof,
            so3,
            stability,
        )
    }
)

__all__ = [
    "RK4",
    "RKMK",
    "AbstractKinematics",
    "CayleyKlein",
    "EulerAngles",
    "Event",
    "ExactFreeBody",
    "ExplicitRK",
    "ExcitationDesign",
    "Gyrostat",
    "GyrostatTrajectory",
    "HeavyTop",
    "InertiaEstimate",
    "LiePoissonSplitting",
    "LieTerm",
    "PoissonMatrix",
    "Quaternion",
    "RigidBody",
    "RotationSpline",
    "RotationVector",
    "IntegrationError",
    "Slerp",
    "SolveOptions",
    "StepEndMap",
    "Trajectory",
    "analytic",
    "andoyer",
    "control",
    "angular_momentum",
    "darboux",
    "design_excitation",
    "energy",
    "estimation",
    "euler",
    "events",
    "fit",
    "gibbs",
    "gyrostat",
    "heavy_top",
    "identify_inertia",
    "inertia",
    "invariants",
    "kepler",
    "kinematics",
    "mechanics",
    "mrp",
    "observables",
    "omega_path",
    "quat",
    "rotations",
    "satellite",
    "sensors",
    "simulate",
    "simulate_heavy_top",
    "sixdof",
    "so3",
    "solvers",
    "sweep",
    "stability",
]
__version__ = "0.1.0"


def __getattr__(name: str):
    """`rigidjax.sweep` is imported on first use (it brings in xarray and zarr)."""
    if name == "sweep":
        import importlib

        return importlib.import_module(".sweep", __name__)
    raise AttributeError(f"module 'rigidjax' has no attribute {name!r}")
