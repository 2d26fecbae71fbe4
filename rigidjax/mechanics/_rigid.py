"""The rigid body's one solve below `simulate`: its arguments checked and flattened into a
`RigidCall` (the bodies, the problem `_paths.Problem`, the event), then `solve_rigid` integrates
it: one state for the batch, or each body its own solve where each takes its own adaptive steps
or has an event (the one-body solve mapped over the bodies); failures raised per batch."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._batch import first_failure
from .._checks import broadcast_batch, check_frame
from .._custom_types import Frame, RealLike
from .._integrate import SolveOptions
from ..events import Event
from ..kinematics.formulations import Quaternion
from ..solvers.exact_free_body import ExactFreeBody
from ..solvers.splitting import LiePoissonSplitting
from . import _per_body as _pb
from ._initial import initial_rotation
from ._paths import Problem, solve_flat
from .body import RigidBody
from .trajectory import Trajectory

__all__ = ["RigidCall", "rigid_call", "solve_rigid"]


class RigidCall(eqx.Module):
    """One `simulate` call, its B bodies flattened: the problem, the operator's arrays
    `args (B, ...)`, `omega0 (B, 3)`, `q0 (B, 4)`, the event (flattened), the batch's shape and
    whether one body's parameters serve the whole batch (`shared`)."""

    problem: Problem
    args: tuple[Array, ...]
    omega0: Array
    q0: Array
    event: Event | None
    batch: tuple[int, ...] = eqx.field(static=True)
    shared: bool = eqx.field(static=True)


def rigid_call(
    body: RigidBody,
    omega0: RealLike,
    q0: RealLike | None,
    ts: RealLike | None,
    torque: Any,
    kinematics: Any,
    torque_frame: Frame,
    event: Any,
    options: SolveOptions,
    check: bool,
) -> RigidCall:
    """`simulate`'s arguments checked (clear errors) and flattened into a `RigidCall`."""
    check_frame(torque_frame, "torque_frame")
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
    lead = len(body.batch_shape)
    args = tuple(
        jnp.broadcast_to(a.astype(dtype), (*batch, *a.shape[lead:])).reshape(B, *a.shape[lead:])
        for a in body.operator()
    )
    quaternion = kinematics == "quat" or (
        type(kinematics) is Quaternion and kinematics.frame == "body"
    )
    structured = isinstance(options.solver, ExactFreeBody | LiePoissonSplitting)
    if event is not None:
        event = _pb.checked(event, options.solver if structured else None, batch)
    problem = Problem(ts, torque, torque_frame, kinematics, (structured, quaternion, body.diagonal))
    omega0 = jnp.broadcast_to(omega0, (*batch, 3)).reshape(B, 3)
    q0 = jnp.broadcast_to(q0, (*batch, 4)).reshape(B, 4)
    if event is not None:
        omega0 = _pb.finite_at_start(event, ts[0], omega0, q0, batch)
    return RigidCall(problem, args, omega0, q0, event, batch, body.batch_shape == ())


def solve_rigid(call: RigidCall, options: SolveOptions) -> Trajectory:
    """Integrate `call`: the batch as one state where its bodies share their steps (fixed steps,
    the structured solvers; the components path maps adaptive solves over the bodies itself,
    `models.solve`), else each body its own solve; failures raised as `options.throw` asks."""
    problem, batch, event = call.problem, call.batch, call.event
    ts, B = problem.ts, call.omega0.shape[0]
    adaptive = not isinstance(options.stepsize_controller, diffrax.ConstantStepSize)
    own_steps = adaptive and not problem.structured and not problem.components
    if event is None and not (own_steps and B > 1):
        solved = solve_flat(problem, options, call.args, call.omega0, call.q0, call.shared)
        omega, q, stats, result, _ = solved
        if adaptive and batch and not problem.structured:  # each body's own step counts
            stats = _pb.per_body(stats, batch)
        return _trajectory(ts, batch, omega, q, stats, result)
    quiet = dataclasses.replace(options, throw=False)

    def one(a, w, q, ev):
        a, w, q = (tuple(x[None] for x in a), w[None], q[None])
        return solve_flat(problem, quiet, a, w, q, False, ev)

    if B == 1:
        ev = None if event is None else _pb.of_body(event)
        firsts = (tuple(x[0] for x in call.args), call.omega0[0], call.q0[0])
        omega, q, stats, result, event_t = one(*firsts, ev)
    else:
        axes = (0, 0, 0, None if event is None else event.in_axes())
        out = eqx.filter_vmap(one, in_axes=axes)(call.args, call.omega0, call.q0, event)
        omega, q = (jnp.moveaxis(x[:, :, 0], 0, 1) for x in out[:2])  # (B, T, 1, .) -> (T, B, .)
        stats, results, event_t = out[2], out[3], out[4]
        stats, result = first_failure(stats, results)
    first = stats.pop("failed_body", None)
    if options.throw:
        ys, args = (omega, q), (options.max_steps, problem.torque, batch, first)
        omega = _pb.raise_batch(result, stats, ts, ys, *args)
    traj = _trajectory(ts, batch, omega, q, _pb.per_body(stats, batch), result)
    if event_t is not None:
        traj = dataclasses.replace(traj, event_t=jnp.reshape(event_t, batch))
    return traj


def _check_torque(torque: Any, ts: Array, omega0: Array, q0: Array) -> None:
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
