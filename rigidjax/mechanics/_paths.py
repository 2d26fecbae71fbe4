"""The paths of one rigid-body solve (`solve_flat`), chosen once from what the problem asks:
quaternion kinematics as a `Model` (`_rigid_model`: principal axes or a full tensor, on the
CPU kernels, Pallas or Diffrax, `models.solve`), the exact-flow and splitting solvers, the RKMK
Lie-group solver, and every other kinematics formulation through Diffrax (`_BatchField`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import vector
from .._custom_types import Frame
from .._integrate import SolveOptions, solve_saved
from ..events import Event
from ..kinematics.formulations import AbstractKinematics, lookup
from ..models.solve import BatchMaxRMS, solve_model
from ..rotations import quat
from ..solvers.exact_free_body import ExactFreeBody, RigidBodyField, flow_from_start
from ..solvers.rkmk import LieTerm
from . import _per_body as _pb
from ._rigid_model import Torque, moments_params, rigid_body_model, tensor_params
from .body import euler_rhs

__all__ = ["Problem", "fixed_steps", "solve_flat"]


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


class Problem(eqx.Module):
    """What `solve_flat` integrates, besides the options and the bodies: the output times, the
    torque (in `torque_frame`), the kinematics, whether the solver is a structured one (the
    exact flow, the splitting), whether the attitude is the body-frame quaternion and the body
    in principal axes."""

    ts: Array
    torque: Any
    torque_frame: Frame = eqx.field(static=True)
    kinematics: Any = eqx.field(static=True)
    flags: tuple[bool, bool, bool] = eqx.field(static=True)  # structured, quaternion, diagonal

    @property
    def structured(self) -> bool:
        return self.flags[0]

    @property
    def quaternion(self) -> bool:
        return self.flags[1]

    @property
    def diagonal(self) -> bool:
        return self.flags[2]

    @property
    def components(self) -> bool:
        """Quaternion kinematics with a Runge–Kutta solver: a `Model` (`_rigid_model`)."""
        return self.quaternion and not self.structured


def solve_flat(
    problem: Problem,
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
    elif problem.components:  # quaternion kinematics: the model, on a kernel or Diffrax
        model = rigid_body_model(torque, torque_frame, tensor=not problem.diagonal)
        # one body for the whole batch: its parameters shared, not streamed (B,) copies
        ops = tuple(a[:1] if shared else a for a in args)
        p = moments_params(ops[0]) if problem.diagonal else tensor_params(*ops)
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
