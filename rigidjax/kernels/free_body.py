"""The free rigid body with its attitude quaternion at fixed steps of an explicit Runge–Kutta
method on the CPU: the model kernel (`rigidjax.kernels.model`) of the torque-free body, the
fast path of `simulate(..., solver=method, stepsize_controller=diffrax.ConstantStepSize(),
dt0=...)` for bodies in principal axes. Same steps and arithmetic as the Diffrax path
(`ExplicitRK(method)`: one interval of `n` equal steps per output interval, the quaternion
renormalised after each step)."""

from __future__ import annotations

import diffrax

from ..mechanics._rigid_model import rigid_body_model
from . import model
from .tableau import DTYPES, METHODS, coefficients, stage_times

__all__ = ["DTYPES", "METHODS", "coefficients", "serves", "stage_times"]


def serves(solver: diffrax.AbstractSolver, dtype) -> bool:
    """Whether a kernel integrates the free body with `solver` (one of `METHODS`, exactly) in
    `dtype` on the default backend: the CPU, float32 or float64, and the kernel built here (the
    first use of a method and element type builds it, once per machine: 0.6 s measured for RK4
    on a 2-core CPU, plus, the first time, its XLA handler's object, compiled alongside)."""
    free = rigid_body_model(None)
    hoisted = model.hoist(free.field, free.size, free.params, dtype)
    return model.build(hoisted, free.unit, solver) is not None
