"""Rigid-body dynamics: Euler's equations coupled to any attitude formulation (`simulate`, the
front door: a gyrostat goes to `gyrostat.simulate_gyrostat`, a rigid body to `_rigid`'s one
solve, which chooses the path once: `_paths`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Unpack

from jaxtyping import Array

from .._custom_types import Frame, RealLike, RealScalarLike
from .._integrate import SolveKwargs, SolveOptions
from ..events import Event
from ..kinematics.formulations import AbstractKinematics
from ._gyrostat_body import Gyrostat
from ._paths import fixed_steps
from ._rigid import rigid_call, solve_rigid
from .body import RigidBody
from .gyrostat import simulate_gyrostat
from .trajectory import Trajectory

if TYPE_CHECKING:
    Torque = Callable[[Array, Array, Array], Array]
    EventArg = Event
else:  # `simulate` checks them itself (a TypeError that names `torque`, `event`)
    Torque = object
    EventArg = object


__all__ = ["Trajectory", "fixed_steps", "simulate"]


def simulate(
    body: RigidBody | Gyrostat,
    omega0: RealLike,
    q0: RealLike | None = None,
    ts: RealLike | None = None,
    torque: Torque | None = None,
    kinematics: str | AbstractKinematics = "quat",
    *,
    wheel_speed0: RealLike | None = None,
    h_rate: Callable[[Array], Array] | None = None,
    controller: Callable[..., Array] | None = None,
    control_period: RealScalarLike | None = None,
    controller_params: Any = None,
    controller_key: Any = None,
    torque_frame: Frame = "body",
    options: SolveOptions | None = None,
    check: bool = True,
    event: EventArg | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> Trajectory:
    """Integrate Euler's equations `I Ω̇ + Ω × IΩ = K` (body frame, general tensor; Zegrya–Parshin
    004) with the attitude kinematics `kinematics` (`"quat"`, `"rotvec"`, `"matrix"`, `"euler"`,
    `"cayley_klein"`, `"geometric"` for the RKMK Lie-group solver, or an `AbstractKinematics`).

    `omega0`: initial body angular velocity `(..., 3)`; `q0`: initial attitude `(..., 4)`
    (identity by default); leading dimensions of the body, `omega0` and `q0` broadcast into a
    batch. With adaptive steps (the default) each body takes its own steps: the one-body solve
    mapped over the bodies, so a body's trajectory is the same alone or in any batch (to
    rounding) and equals `jax.vmap` of `simulate`; `stats` then holds each body's step counts
    (the batch's shape), `num_valid` and `result` the batch's (its first failure). Fixed steps
    (the same for every body) integrate the batch as ONE state in one fused loop. `torque(t, Ω, q)`
    returns K in the body frame (or in space with `torque_frame="space"`). Solver options:
    `options` (a `rigidjax.SolveOptions`: any Diffrax solver, step-size controller
    (`diffrax.ConstantStepSize` with `dt0`, or adaptive), adjoint and progress meter) or its
    fields as keywords; defaults: Tsit5 with unrolled stages (`ExplicitRK`; RKMK-Dopri5 for
    `"geometric"`), PID at `rtol = atol = 1e-10` in float64 (1e-6 in float32).
    Steps end at every output time and the values at `ts` are step-end states (unit
    quaternions, no interpolation; `max_steps` bounds each output interval). Bodies with
    quaternion kinematics (in principal axes or with a full inertia tensor), with or without a
    torque, run on the CPU in a kernel written from the JAX field and the torque
    (`rigidjax.models`, `rigidjax.kernels`), built on first use: at fixed steps
    (`diffrax.ConstantStepSize()` and `dt0`) of an explicit Runge–Kutta method (`RK4()`, the
    default Tsit5, `diffrax.Dopri8()`, ...: `rigidjax.kernels.tableau.METHODS`), and at
    adaptive steps (the default `PIDController`, Tsit5, Dopri5, Dopri8, Bosh3:
    `rigidjax.kernels.adaptive`, each body its own steps, step for step Diffrax's controller;
    an event too); the same steps and numbers as the Diffrax path, with the kernel's own
    adjoint for `jax.grad` (forward mode, `jax.jacfwd` and `jax.hessian` through the Diffrax
    path on the same steps: `rigidjax._modes`; derivatives of the output times and of events
    through the Diffrax path); at least the speed of a hand-written C kernel of the same model
    (benchmarks/results/models.json, adaptive.json); a torque the kernel cannot take runs
    through Diffrax with one warning. On a GPU the same
    model, torque included, runs in a Pallas kernel that fuses the time loop
    (`rigidjax.kernels.model_pallas`, with its own reverse kernel);
    `ExplicitRK(method)` runs the same scheme through Diffrax.
    `solver=rigidjax.ExactFreeBody()` (no torque) steps by the exact Euler–Poinsot flow, exact
    to rounding for any step (by default one step from `ts[0]` to each output time, without a
    Diffrax loop; with `dt0`, Diffrax steps of at most `dt0`);
    `solver=rigidjax.LiePoissonSplitting()` with `dt0` splits the exact free flow and the torque
    kick for a torque of the attitude only (structure-preserving, fixed steps). Both need the
    body in principal axes and quaternion kinematics.

    `event=rigidjax.Event(condition, terminate=True, direction=None)`: the first time
    `condition(t, Ω, q)` (of one body) crosses zero, located by a root find on the step's
    interpolant to the solver's tolerance (Diffrax's events, each body its own solve; on the
    adaptive kernel, by the Illinois method on the step itself), is the trajectory's `event_t`
    (`inf` where none; differentiable);
    with `terminate=True` each body stops there and the outputs after it hold the state at the
    event, with `False` the trajectory is the one without the event. `rigidjax.events.
    flip_event(omega0)` gives the first flip of the initially dominant axis exactly. At fixed
    steps the event runs on the per-body kernel too (each body its own fixed steps). Also for a
    gyrostat, with or without a controller (a terminating event holds the state: no later
    samples act). Not with `ExactFreeBody` or `LiePoissonSplitting`.

    `check=False` skips the checks of `ts`, `omega0` and `q0` (like `RigidBody(check=False)`)
    for inputs validated beforehand: traced inputs then compile without runtime checks, which
    compiles faster and lets JAX's persistent compilation cache store the program (it refuses
    programs with host callbacks, which runtime checks are). The shapes are still checked.

    A `rigidjax.Gyrostat` as `body` integrates `I Ω̇ + Ω × (IΩ + h) = τ − ḣ` instead
    (`gyrostat.simulate_gyrostat`, which takes `wheel_speed0`, `h_rate`, and a sampled-data
    `controller` with `control_period` and `controller_params`; `controller_key`, a PRNG key
    per body, seeds a `rigidjax.control.StatefulController`'s memory: its simulated sensors).
    """
    if isinstance(body, Gyrostat):
        return simulate_gyrostat(
            body, omega0, q0, ts, torque, kinematics, wheel_speed0=wheel_speed0,
            h_rate=h_rate, controller=controller, control_period=control_period,
            controller_params=controller_params, controller_key=controller_key,
            torque_frame=torque_frame, event=event, options=options, check=check,
            **solve_kwargs,
        )  # fmt: skip
    if not isinstance(body, RigidBody):
        raise TypeError(
            f"body must be a rigidjax.RigidBody or Gyrostat, got {type(body).__name__}: wrap "
            "the inertia, e.g. simulate(RigidBody(inertia), omega0, ...)"
        )
    gyro = dict(
        wheel_speed0=wheel_speed0,
        h_rate=h_rate,
        controller=controller,
        control_period=control_period,
        controller_params=controller_params,
        controller_key=controller_key,
    )
    given = sorted(k for k, v in gyro.items() if v is not None)
    if given:
        raise ValueError(
            f"{', '.join(given)} apply to a gyrostat: give rigidjax.Gyrostat(inertia, ...) as "
            "the body (Gyrostat(inertia) is the rigid body itself, with h = 0)"
        )
    options = SolveOptions.of(options, solve_kwargs)
    call = rigid_call(body, omega0, q0, ts, torque, kinematics, torque_frame, event, options, check)
    return solve_rigid(call, options)
