"""Rigid-body dynamics: Euler's equations coupled to any attitude formulation, through Diffrax."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Unpack, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import (
    broadcast_batch,
    vector,
)
from .._custom_types import Frame, RealLike
from .._integrate import (
    SolveKwargs,
    SolveOptions,
    solve_saved,
)
from .._trajectory import AbstractTrajectory
from ..events import Event
from ..kinematics.formulations import AbstractKinematics, Quaternion, lookup
from ..models.solve import BatchMaxRMS, solve_model
from ..rotations import quat
from ..solvers.exact_free_body import ExactFreeBody, RigidBodyField, flow_from_start
from ..solvers.rkmk import LieTerm
from ..solvers.splitting import LiePoissonSplitting
from . import _per_body as _pb
from ._gyrostat_body import Gyrostat
from ._initial import initial_rotation
from ._rigid_model import moments_params, rigid_body_model
from .body import RigidBody, euler_rhs

if TYPE_CHECKING:
    Torque = Callable[[Array, Array, Array], Array]
    EventArg = Event
else:  # `simulate` checks them itself (a TypeError that names `torque`, `event`)
    Torque = object
    EventArg = object


__all__ = ["Trajectory", "fixed_steps", "simulate"]


class Trajectory(AbstractTrajectory):
    """Solution of `simulate`: times `ts (T,)`, body angular velocity `omega (..., T, 3)` and
    attitude `quat (..., T, 4)` (unit; P maps body to space; its sign is continuous in time and
    `quat[..., 0, :] = q0`, `quat.canonical` gives λ0 ≥ 0); `matrix (..., T, 3, 3)`.
    `event_t (...)`: with `simulate(..., event=rigidjax.Event(...))`, each body's first event
    time (`inf` where none); None without an event."""

    omega: Float[Array, "*batch T 3"]
    quat: Float[Array, "*batch T 4"]
    event_t: Float[Array, "*batch"] | None = eqx.field(kw_only=True, default=None)

    @property
    def matrix(self) -> Float[Array, "*batch T 3 3"]:
        return quat.to_matrix(self.quat)


class _Dynamics(eqx.Module):
    """Per-body right-hand side `(att, Ω) -> (att', Ω̇)` in body-frame angular velocity."""

    kin: AbstractKinematics | None  # None: RKMK, whose attitude is the rotation matrix itself
    torque: Torque | None
    torque_frame: str = eqx.field(static=True)

    def _quat(self, att):
        if self.kin is None:  # the RKMK state: a rotation by construction
            return quat.from_matrix(att, assume_valid=True)
        return self.kin.to_quat(att)

    def __call__(self, t, att, omega, I, I_inv):
        if self.torque is None:
            K = jnp.zeros_like(omega)
        else:
            q = self._quat(att)
            K = vector(self.torque(t, omega, q), 3, "torque(t, omega, q)").astype(omega.dtype)
            if self.torque_frame == "space":
                K = quat.rotate(quat.conj(q), K)
        domega = euler_rhs(I, I_inv, omega, K)
        datt = omega if self.kin is None else self.kin.vector_field(att, omega)
        return datt, domega


class _BatchField(eqx.Module):
    """Vector field of a flattened batch `(att, Ω)` with the batch on axis `axis`, vmapped inside
    the solve so the whole batch advances in one fused loop. With the batch last (components
    first, "structure of arrays") XLA vectorises over bodies: about 4× faster on CPU than the
    batch-first layout in benchmarks/bench_dynamics.py."""

    dyn: _Dynamics
    axis: int = eqx.field(static=True)

    def __call__(self, t, y, args):
        (att, omega), (I, I_inv), ax = y, args, self.axis
        return jax.vmap(self.dyn, in_axes=(None, ax, ax, ax, ax), out_axes=ax)(
            t, att, omega, I, I_inv
        )


class _BatchStepEnd(eqx.Module):
    """The kinematics' step-end map (normalisation, chart switch) on a flattened batch
    `(att, Ω)` with the batch on axis `axis`; reports a jump if any member jumped."""

    kin: AbstractKinematics
    axis: int = eqx.field(static=True)

    def __call__(self, y):
        step_end = jax.vmap(self.kin.step_end, in_axes=self.axis, out_axes=(self.axis, 0))
        att, jumped = step_end(y[0])
        return (att, y[1]), jnp.any(jumped)


def _from_lie(ys) -> tuple[Array, Array]:
    """`(Ω, q)` from the saved RKMK state `(R, Ω)`."""
    return ys[1], quat.from_matrix(ys[0], assume_valid=True)


class _BatchFinish(eqx.Module):
    """`(Ω (T, B, 3), q (T, B, 4))` from the saved batch-last state `(att, Ω)`."""

    kin: AbstractKinematics

    def __call__(self, ys) -> tuple[Array, Array]:
        att, omega = (jnp.moveaxis(a, -1, 1) for a in ys)  # (T, ..., B) -> (T, B, ...)
        return omega, jax.vmap(jax.vmap(self.kin.to_quat))(att)


def _check_torque(torque: Torque, ts: Array, omega0: Array, q0: Array) -> None:
    """A clear error, before integrating, if `torque(t, Ω, q)` (of one body) does not return
    a 3-vector (its shape is found by tracing it once, `jax.eval_shape`: nothing is computed)."""
    if not callable(torque):
        raise TypeError(f"torque must be a callable torque(t, omega, q) -> (3,), got {torque!r}")
    out = jax.eval_shape(torque, ts[0], omega0.reshape(-1, 3)[0], q0.reshape(-1, 4)[0])
    shape = getattr(out, "shape", None)
    if shape != (3,):
        got = f"shape {shape}" if shape is not None else type(out).__name__
        raise ValueError(
            f"torque(t, omega, q) must return the torque of one body, shape (3,), got {got}: it "
            "is called per body with omega (3,) and q (4,) (the batch is mapped over it)"
        )


def _structured(
    diagonal: bool,
    options: SolveOptions,
    torque: Torque | None,
    torque_frame: Frame,
    quaternion: bool,
    args: tuple[Array, ...],
) -> tuple[diffrax.ODETerm, SolveOptions, Array]:
    """Term, options and args (the principal moments `(B, 3)`) for `ExactFreeBody` and
    `LiePoissonSplitting`, with clear errors for what they cannot integrate. Fixed steps: by
    default one exact step per output interval for `ExactFreeBody`; `dt0` is required for
    `LiePoissonSplitting`."""
    name = type(options.solver).__name__
    exact = isinstance(options.solver, ExactFreeBody)
    if exact and torque is not None:
        raise ValueError(
            "ExactFreeBody integrates the torque-free rigid body (torque=None); for a torque "
            "that depends on the attitude only use solver=rigidjax.LiePoissonSplitting() with "
            "stepsize_controller=diffrax.ConstantStepSize() and dt0, otherwise a Runge–Kutta "
            "solver"
        )
    if not diagonal:
        raise ValueError(
            f"{name} needs the body in principal axes: give RigidBody(principal moments (3,)) and "
            "Ω0, q0 in those axes (rigidjax.inertia.principal_axes diagonalises a tensor)"
        )
    if not quaternion:
        raise ValueError(
            f"{name} integrates the attitude as a unit quaternion: use kinematics='quat' (the "
            "default)"
        )
    options = fixed_steps(options)
    term = diffrax.ODETerm(RigidBodyField(torque, torque_frame))
    return term, options, args[0]


def fixed_steps(options: SolveOptions) -> SolveOptions:
    """`options` for `ExactFreeBody` or `LiePoissonSplitting`: `diffrax.ConstantStepSize`, by
    default one step per output interval for `ExactFreeBody` (exact for any step), `dt0`
    required for `LiePoissonSplitting`; an adaptive controller is a clear error."""
    name = type(options.solver).__name__
    exact = isinstance(options.solver, ExactFreeBody)
    controller = options.stepsize_controller
    if controller is not None and not isinstance(controller, diffrax.ConstantStepSize):
        raise ValueError(
            f"{name} takes fixed steps (it has no error estimate): use "
            "stepsize_controller=diffrax.ConstantStepSize() (or leave it unset) with dt0"
        )
    dt0 = options.dt0
    if dt0 is None:
        if not exact:
            raise ValueError(
                "LiePoissonSplitting takes fixed steps: give the step dt0 (e.g. "
                "simulate(..., solver=LiePoissonSplitting(), dt0=0.01))"
            )
        dt0 = math.inf  # exact for any step: one step per output interval
    return dataclasses.replace(options, stepsize_controller=diffrax.ConstantStepSize(), dt0=dt0)


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
    control_period: float | None = None,
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
    quaternions, no interpolation; `max_steps` bounds each output interval). Bodies in
    principal axes with quaternion kinematics, with or without a torque, at fixed steps
    (`diffrax.ConstantStepSize()` and `dt0`) of an explicit Runge–Kutta method (`RK4()`, the
    default Tsit5, `diffrax.Dopri8()`, ...: `rigidjax.kernels.tableau.METHODS`; the default
    adjoint) run on the CPU in a kernel written from the JAX field and the torque
    (`rigidjax.models`, `rigidjax.kernels.model`), built on first use: the same steps and
    numbers as the Diffrax path, with its own adjoint for `jax.grad` (forward mode, `jax.jacfwd`
    and `jax.hessian` through the Diffrax path on the same steps: `rigidjax._modes`); at least
    the speed of a hand-written C kernel of the same model (benchmarks/results/models.json); a
    torque the kernel cannot take runs through Diffrax with one warning. On a GPU the same
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
    interpolant to the solver's tolerance (Diffrax's events, each body its own solve, on the
    Diffrax path: no kernel), is the trajectory's `event_t` (`inf` where none; differentiable);
    with `terminate=True` each body stops there and the outputs after it hold the state at the
    event, with `False` the trajectory is the one without the event. `rigidjax.events.
    flip_event(omega0)` gives the first flip of the initially dominant axis exactly. Not with
    `ExactFreeBody`, `LiePoissonSplitting` or a gyrostat.

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
        if event is not None:
            raise ValueError(
                "events are not supported for a gyrostat yet: give a rigidjax.RigidBody"
            )
        from .gyrostat import simulate_gyrostat  # it imports this module

        return simulate_gyrostat(
            body, omega0, q0, ts, torque, kinematics, wheel_speed0=wheel_speed0,
            h_rate=h_rate, controller=controller, control_period=control_period,
            controller_params=controller_params, controller_key=controller_key,
            torque_frame=torque_frame, options=options, check=check, **solve_kwargs,
        )  # fmt: skip
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
    ts, omega0, q0 = initial_rotation(ts, omega0, q0, check)
    dtype = ts.dtype
    batch = broadcast_batch(body=body.batch_shape, omega0=omega0.shape[:-1], q0=q0.shape[:-1])
    B = math.prod(batch)
    if B == 0:
        raise ValueError(
            f"the batch is empty: body, omega0 and q0 broadcast to batch shape {batch}; give at "
            "least one body"
        )
    if torque is not None:
        _check_torque(torque, ts, omega0, q0)
    args = tuple(
        jnp.broadcast_to(a.astype(dtype), (*batch, *a.shape[len(body.batch_shape) :])).reshape(
            B, *a.shape[len(body.batch_shape) :]
        )
        for a in body.operator()
    )
    omega0 = jnp.broadcast_to(omega0, (*batch, 3)).reshape(B, 3)
    q0 = jnp.broadcast_to(q0, (*batch, 4)).reshape(B, 4)

    quaternion = kinematics == "quat" or (
        type(kinematics) is Quaternion and kinematics.frame == "body"
    )
    structured = isinstance(options.solver, ExactFreeBody | LiePoissonSplitting)
    components = body.diagonal and quaternion and not structured
    if event is not None:
        event = _pb.checked(event, options.solver if structured else None, batch)
    adaptive = not isinstance(options.stepsize_controller, diffrax.ConstantStepSize)
    problem = _Problem(
        ts, torque, torque_frame, kinematics, structured, components, quaternion, body.diagonal
    )
    if event is None and not (adaptive and B > 1 and not structured and not components):
        # one state for the batch (the components path maps adaptive solves over the bodies
        # itself: `models.solve._diffrax`)
        shared = body.batch_shape == ()
        omega, q, stats, result, _ = _solve_flat(problem, options, args, omega0, q0, shared)
        if adaptive and batch and not structured:  # each body's own step counts
            stats = _pb.per_body(stats, batch)
        return _trajectory(ts, batch, omega, q, stats, result)
    # each body its own solve (its own adaptive steps, its own event): one body mapped
    quiet = dataclasses.replace(options, throw=False)

    def one(a, w, q, ev):
        a, w, q = (tuple(x[None] for x in a), w[None], q[None])
        return _solve_flat(problem, quiet, a, w, q, False, ev)

    if B == 1:
        ev = None if event is None else _pb.first(event)
        omega, q, stats, result, event_t = one(*(tuple(x[0] for x in args), omega0[0], q0[0]), ev)
    else:
        axes = (0, 0, 0, None if event is None else event.in_axes())
        out = eqx.filter_vmap(one, in_axes=axes)(args, omega0, q0, event)
        omega, q = (jnp.moveaxis(x[:, :, 0], 0, 1) for x in out[:2])  # (B, T, 1, .) -> (T, B, .)
        stats, results, event_t = out[2], out[3], out[4]
        stats, result = _pb.first_failure(stats, results)
    if options.throw:
        omega = _pb.raise_batch(result, stats, ts, (omega, q), options.max_steps, torque)
    traj = _trajectory(ts, batch, omega, q, _pb.per_body(stats, batch), result)
    if event_t is not None:
        traj = dataclasses.replace(traj, event_t=jnp.reshape(event_t, batch))
    return traj


class _Problem(eqx.Module):
    """What `_solve_flat` integrates, besides the options and the bodies."""

    ts: Array
    torque: Any
    torque_frame: Frame = eqx.field(static=True)
    kinematics: Any = eqx.field(static=True)
    structured: bool = eqx.field(static=True)
    components: bool = eqx.field(static=True)
    quaternion: bool = eqx.field(static=True)
    diagonal: bool = eqx.field(static=True)


def _solve_flat(
    problem: _Problem,
    options: SolveOptions,
    args: tuple[Array, ...],
    omega0: Array,
    q0: Array,
    shared: bool,
    event: Event | None = None,
) -> tuple[Array, Array, dict[str, Array], Any, Array | None]:
    """`(Ω (T, B, 3), q (T, B, 4), stats, result, event_t)` of the B bodies `args` (the
    operator's arrays `(B, ...)`), `omega0 (B, 3)`, `q0 (B, 4)`, as ONE state (one body where
    `event` is given: `event_t` its time, else None); `shared`: one body for the whole batch."""
    ts, torque, torque_frame = problem.ts, problem.torque, problem.torque_frame
    kinematics = problem.kinematics
    B = omega0.shape[0]
    direct = (
        isinstance(options.solver, ExactFreeBody)
        and options.dt0 is None
        and options.stepsize_controller is None
    )
    event_t = None
    if problem.structured:
        # the exact flow maps each body: batch first
        term, options, moments = _structured(
            problem.diagonal, options, torque, torque_frame, problem.quaternion, args
        )
        args = cast(Any, moments)  # (the flow solvers take the moments (B, 3) as args)
        solver = None
        step_end = None
        axis = 0
        y0 = (omega0, q0)
        finish = tuple
    elif problem.components:  # principal axes, quaternion: the model, on the CPU kernel or
        # Diffrax
        model = rigid_body_model(torque, torque_frame)
        # one body for the whole batch: its parameters shared, not streamed (B,) copies
        p = moments_params(args[0][:1] if shared else args[0])
        y0 = jnp.concatenate([omega0, q0], axis=-1)
        # one body: scalar components (under `jax.vmap`, e.g. in a sweep, they become (N,)
        # arrays, not (N, 1), which XLA vectorises poorly)
        single = B == 1
        on_state = None if event is None else event.on_state(_pb.split_components)
        ys, stats, result = solve_model(model, ts, y0, p, options, single=single, event=on_state)
        if event is not None:
            event_t = stats.pop("event_t")
        return ys[..., :3], ys[..., 3:], stats, result, event_t

    elif kinematics == "geometric":
        solver = options.rkmk("body")
        axis = 0  # RKMK takes the batch on leading axes
        term = LieTerm(_BatchField(_Dynamics(None, torque, torque_frame), axis))
        y0 = (quat.to_matrix(q0), omega0)
        step_end = None
        finish = _from_lie

    else:
        kin = lookup(kinematics, "body", strict_frame=True)  # simulate's Ω is the body one
        axis = -1  # batch last: components first, bodies along the vectorised axis
        step_end = _BatchStepEnd(kin, axis)
        solver = None
        term = diffrax.ODETerm(_BatchField(_Dynamics(kin, torque, torque_frame), axis))
        y0 = (jax.vmap(kin.from_matrix, out_axes=axis)(quat.to_matrix(q0)), omega0.T)
        args = tuple(jnp.moveaxis(a, 0, -1) for a in args)
        finish = _BatchFinish(kin)

    if direct:  # ExactFreeBody without dt0: each output time one exact step from ts[0]
        ys = flow_from_start(args, omega0, q0, ts)
        n = jnp.asarray(ts.shape[0] - 1)
        stats = dict(num_steps=n, num_accepted_steps=n, num_rejected_steps=0 * n, num_valid=n + 1)
        result = diffrax.RESULTS.successful
    else:
        on_state = None
        if event is not None:
            kin = None if kinematics == "geometric" else finish.kin  # type: ignore[attr-defined]
            on_state = event.on_state(_pb.OneBodyState(kin))
        ys, stats, result = solve_saved(
            term,
            ts,
            y0,
            options,
            solver=solver,
            args=args,
            step_end=step_end,
            norm=BatchMaxRMS(axis),
            event=on_state,
        )
        if event is not None:
            event_t = stats.pop("event_t")
    omega, q = finish(ys)
    if not problem.structured:  # other states give q up to sign: continue the integrated q0
        q = quat.continuous(jnp.moveaxis(q, 0, 1))  # (B, T, 4)
        q = jnp.moveaxis(q * jnp.sign(jnp.sum(q[:, :1] * q0[:, None], -1, keepdims=True)), 1, 0)
        q = q.at[0].set(q0)  # `quat[0] = q0` exactly (the chart's round trip is ulp-close)
    return omega, q, stats, result, event_t


def _trajectory(ts, batch, omega, q, stats, result) -> Trajectory:
    """The trajectory of `batch` from `Ω (T, B, 3)` and `q (T, B, 4)`."""
    T = ts.shape[0]
    return Trajectory(
        ts=ts,
        omega=jnp.moveaxis(omega, 0, 1).reshape(*batch, T, 3),
        quat=jnp.moveaxis(q, 0, 1).reshape(*batch, T, 4),
        stats=stats,
        result=result,
    )
