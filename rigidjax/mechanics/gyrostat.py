"""The gyrostat: a rigid body carrying rotors, `I Ω̇ + Ω × (IΩ + h) = τ − ḣ` (body axes).

`h` is the rotors' angular momentum relative to the body, in body axes; `I` the inertia of the
whole system (rotors included, as if locked). Three ways to give `h`:

- constant `h`: the Zhukovsky–Volterra gyrostat (Zhukovsky 1885, Volterra 1899; Wittenburg,
  *Dynamics of Multibody Systems*, 2nd ed., §4.1). Without torque its integrals are the energy
  `T = ½ Ω·IΩ` and the squared momentum `|IΩ + h|²`;
- `h_rate(t)`: `ḣ` a function of time, `h(t) = h(t0) + ∫ ḣ` integrated with the state;
- reaction wheels: unit spin axes `A = [a_1 … a_n] (3, n)`, axial inertias `J (n,)`, wheel
  speeds relative to the body `ω_w (n,)` as states, motor torques `u (n,)` (on the wheels) as
  inputs. Then `h = A J ω_w` and each wheel obeys `J_i (a_i·Ω̇ + ω̇_w,i) = u_i`, so
  `(I − A J Aᵀ) Ω̇ = τ − A u − Ω × (IΩ + h)`, `ω̇_w = u/J − Aᵀ Ω̇`
  (Schaub & Junkins, *Analytical Mechanics of Space Systems*, 4th ed., §4.5; Basilisk's
  `reactionWheelStateEffector`). Without torque the energy
  `½ Ω·(I − A J Aᵀ)Ω + ½ Σ J_i (a_i·Ω + ω_w,i)²` and `|IΩ + h|` are conserved.

The attitude is `q̇ = ½ q ∘ (0, Ω)` (Borisov–Mamaev 001). `simulate(gyrostat, ...)` integrates
the model on `rigidjax.models.solve_tree`: the CPU kernel written from the field at fixed
explicit Runge–Kutta steps, else Diffrax; with a `controller`, sample by sample
(`rigidjax.mechanics._zoh`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Unpack

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._batch import first_failure
from .._checks import (
    broadcast_batch,
    check_finite,
    check_frame,
    concrete_value,
    vector,
)
from .._custom_types import Frame, RealLike, RealScalarLike
from .._integrate import SolveKwargs, SolveOptions
from .._numerics import inv3
from ..control.stateful import StatefulController
from ..kinematics.formulations import Quaternion
from ..models.solve import solve_tree
from ..rotations import quat
from ..solvers.exact_free_body import AbstractFlowSolver
from . import _per_body as _pb
from ._gyrostat_body import Gyrostat
from ._initial import initial_rotation
from ._rigid import rigid_call, solve_rigid
from ._zoh import Controller, held_solve
from .body import _apply
from .trajectory import Trajectory

__all__ = ["Gyrostat", "GyrostatTrajectory", "angular_momentum", "energy", "simulate_gyrostat"]

Torque = Callable[[Array, Array, Array], Array]
_QUATERNION = Quaternion(frame="body")


class GyrostatTrajectory(Trajectory):
    """Solution of `simulate` for a `Gyrostat`: `omega`, `quat` as `Trajectory`, the rotors'
    momentum `h (..., T, 3)`, with wheels `wheel_speed (..., T, n)` (relative to the body), and
    with a controller the sample times `control_ts (K,)` and the commands applied (clipped)
    from each sample to the next, `command (..., K, m)`; with a `StatefulController`, its log
    at each sample `controller_log (..., K, L)`."""

    h: Float[Array, "*batch T 3"]
    wheel_speed: Float[Array, "*batch T n"] | None = None
    control_ts: Float[Array, " K"] | None = None
    command: Float[Array, "*batch K m"] | None = None
    controller_log: Float[Array, "*batch K L"] | None = None


class _Field(eqx.Module):
    """The gyrostat's field on one body's state `(Ω, q)`, `(Ω, q, h)` (`h_rate`) or
    `(Ω, q, ω_w)` (wheels), args `(I, I⁻¹, h, command)` or, with wheels,
    `(I, (I − A J Aᵀ)⁻¹, h, A, J, u)`; the command is a body torque `(3,)` or motor torques."""

    torque: Torque | None
    h_rate: Callable[[Array], Array] | None
    torque_frame: str = eqx.field(static=True)
    wheels: bool = eqx.field(static=True)

    def __check_init__(self):
        check_frame(self.torque_frame, "torque_frame")

    def __call__(self, t, y, args):
        w, q = y[0], y[1]
        K = jnp.zeros_like(w) if self.wheels else args[-1]
        if self.torque is not None:
            tau = jnp.asarray(self.torque(t, w, q)).astype(w.dtype)
            K = K + (quat.rotate(quat.conj(q), tau) if self.torque_frame == "space" else tau)
        dq = _QUATERNION.vector_field(q, w)
        if self.wheels:
            I, M_inv, h0, A, J, u = args
            h = h0 + A @ (J * y[2])
            dw = M_inv @ (K - A @ u - jnp.cross(w, _apply(I, w) + h))
            return dw, dq, u / J - A.T @ dw
        I, I_inv, h = args[0], args[1], args[2]
        if self.h_rate is None:
            return _apply(I_inv, K - jnp.cross(w, _apply(I, w) + h)), dq
        h = y[2]
        hd = jnp.asarray(self.h_rate(t)).astype(w.dtype)
        return _apply(I_inv, K - hd - jnp.cross(w, _apply(I, w) + h)), dq, hd


def _check_callable(f: Any, name: str, call: str, args: tuple, shape: tuple[int, ...]) -> None:
    """A clear error, before integrating, if `f` is not a callable returning `shape` (found by
    tracing it once, `jax.eval_shape`)."""
    if not callable(f):
        raise TypeError(f"{name} must be a callable {call} -> {shape}, got {f!r}")
    out = jax.eval_shape(f, *args)
    got = getattr(out, "shape", None)
    if got != shape:
        raise ValueError(
            f"{name} must return shape {shape} for one body ({call}), got "
            f"{got if got is not None else type(out).__name__}"
        )


def simulate_gyrostat(
    gyrostat: Gyrostat,
    omega0: RealLike,
    q0: RealLike | None = None,
    ts: RealLike | None = None,
    torque: Torque | None = None,
    kinematics: Any = "quat",
    *,
    wheel_speed0: RealLike | None = None,
    h_rate: Callable[[Array], Array] | None = None,
    controller: Controller | StatefulController | None = None,
    control_period: RealScalarLike | None = None,
    controller_params: Any = None,
    controller_key: Any = None,
    torque_frame: Frame = "body",
    event: Any = None,
    options: SolveOptions | None = None,
    check: bool = True,
    **solve_kwargs: Unpack[SolveKwargs],
) -> GyrostatTrajectory:
    """Integrate `I Ω̇ + Ω × (IΩ + h) = τ − ḣ` with `q̇ = ½ q ∘ (0, Ω)` (module docstring);
    `simulate(gyrostat, ...)` calls this.

    `omega0 (..., 3)`, `q0 (..., 4)` (identity by default) and `wheel_speed0 (..., n)` (zero by
    default) broadcast into a batch (each body its own solve, mapped with `jax.vmap`: one kernel
    call per solve for the whole batch). `torque(t, Ω, q)`: an external torque (body frame, or
    space with `torque_frame="space"`); `h_rate(t) -> (3,)`: a prescribed `ḣ` (no wheels);
    `controller(t_k, Ω_k, q_k, controller_params) -> command` evaluated at
    `ts[0] + k control_period` and held until the next sample (zero-order hold), a body torque
    `(3,)` or, with wheels, the motor torques `(n,)` (clipped to `wheel_torque_max`); the solve
    then steps from sample to sample (and to each output time), so that fixed steps never
    straddle a switch; the sample grid is built from the values of `ts` and `control_period`,
    which must therefore be concrete (under `jax.jit`, close over them; derivatives with
    respect to `ts` go through). A `rigidjax.control.StatefulController` (e.g.
    `rigidjax.estimation.estimated`: a law acting on an MEKF's estimate from simulated sensors)
    keeps its memory between samples, each body its own, started from `controller_key` or the
    controller's own `key` (`controller.with_key(key)`; one PRNG key, or one per body: the
    batch shape of `omega0`/`q0`; one key is split over a batch, a single body's is its own),
    and records its log (`controller_log`). `event`: a `rigidjax.Event` on `(t, Ω, q)` as
    `simulate`'s (each body its own solve; the held commands and wheels stop with a terminating
    event, and the sample times after it repeat the last command). Options as `simulate`'s:
    fixed steps of an explicit Runge–Kutta method run on the model's CPU kernel (a jump map it
    cannot take, such as random draws, on the Diffrax path with the same steps). Other
    `kinematics` than `"quat"` are taken for a constant `h` without controller (as the torque
    `−Ω × h` of `simulate`)."""
    options = SolveOptions.of(options, solve_kwargs)
    if isinstance(options.solver, AbstractFlowSolver):  # ExactFreeBody, LiePoissonSplitting
        raise ValueError(
            f"{type(options.solver).__name__} integrates a rigid body, not a gyrostat: give "
            "rigidjax.RigidBody(inertia) as the body, or a Runge–Kutta solver (the default "
            "Tsit5, rigidjax.RK4(), ...) for the gyrostat"
        )
    given = ts
    ts, omega0, q0 = initial_rotation(ts, omega0, q0, check)
    dtype = ts.dtype
    times = None if given is None else concrete_value(given)  # the sample grid needs them
    g = jax.tree_util.tree_map(lambda a: a.astype(dtype), gyrostat)
    n = g.wheels
    if h_rate is not None and n:
        raise ValueError(
            "h_rate prescribes ḣ of a gyrostat without wheels; with wheels ḣ follows from the "
            "motor torques (a controller's command)"
        )
    if wheel_speed0 is not None and not n:
        raise ValueError("wheel_speed0 is the wheels' initial speeds: give Gyrostat(wheel_axes=…)")
    if (controller is None) != (control_period is None):
        raise ValueError(
            "a controller is sampled every control_period: give both controller and "
            "control_period (e.g. control_period=0.1)"
        )
    if kinematics != "quat":
        return _other_kinematics(g, omega0, q0, ts, torque, kinematics, locals())

    ws0 = jnp.zeros(n, dtype) if wheel_speed0 is None else vector(wheel_speed0, n, "wheel_speed0")
    ws0 = check_finite(ws0.astype(dtype), "wheel_speed0")
    batch = broadcast_batch(omega0=omega0.shape[:-1], q0=q0.shape[:-1], wheel_speed0=ws0.shape[:-1])
    event = None if event is None else _pb.checked(event, None, batch)
    one = (ts[0], omega0.reshape(-1, 3)[0], q0.reshape(-1, 4)[0])
    if torque is not None:
        _check_callable(torque, "torque", "torque(t, omega, q)", one, (3,))
    if h_rate is not None:
        _check_callable(h_rate, "h_rate", "h_rate(t)", one[:1], (3,))
    m = n if n else 3
    stateful = isinstance(controller, StatefulController)
    if controller_key is not None and not stateful:
        raise ValueError(
            "controller_key seeds a StatefulController's memory (its simulated sensors): give "
            "one as controller, or leave controller_key out"
        )
    keys = None
    if isinstance(controller, StatefulController):
        assert control_period is not None
        keys = _controller_keys(controller.key if controller_key is None else controller_key, batch)
        one_key = None if keys is None else keys.reshape(-1)[0]
        memory = jax.eval_shape(
            controller.init, one_key, *one, controller_params, float(control_period)
        )
        _check_callable(
            lambda *a: controller.step(*a)[0], "controller.step",
            "controller.step(t_k, omega_k, q_k, params, memory)[0]",
            (*one, controller_params, memory), (m,),
        )  # fmt: skip
    elif controller is not None:
        _check_callable(
            controller, "controller", "controller(t_k, omega_k, q_k, params)",
            (*one, controller_params), (m,),
        )  # fmt: skip
    field = _Field(torque, h_rate, torque_frame, bool(n))
    I = g.body.operator()[0]  # principal moments (3,) where the body is in principal axes
    if n:
        assert g.wheel_axes is not None and g.wheel_inertia is not None
        full = g.body.inertia if g.body.inertia.ndim == 2 else jnp.diag(g.body.inertia)
        M_inv = inv3(full - (g.wheel_axes * g.wheel_inertia) @ g.wheel_axes.T)
        params = (I, M_inv, g.h, g.wheel_axes, g.wheel_inertia)
    else:
        params = (I, g.body.operator()[1]) + (() if h_rate is not None else (g.h,))

    def one_body(ev, w0, qq0, x0, key=None, *, options=options):
        y0 = (w0, qq0) + ((x0,) if n else (g.h,) if h_rate is not None else ())
        cmd0 = jnp.zeros(m, dtype)
        if controller is None:
            ev = None if ev is None else ev.on_state(_omega_quat)
            ys, stats, result = solve_tree(
                field, ts, y0, (*params, cmd0), options, unit=(1,), name="gyrostat", event=ev
            )
            event_t = stats.pop("event_t", None)
            return ys, stats, result, None, None, event_t

        def applied(u):
            return g.clip(jnp.asarray(u).astype(dtype)) if n else jnp.asarray(u).astype(dtype)

        assert control_period is not None
        extra = {}
        if isinstance(controller, StatefulController):
            law = controller

            def command_memory(t, y, mem):
                u, mem, log = law.step(t, y[0], y[1], controller_params, mem)
                mem = jax.tree_util.tree_map(lambda a: jnp.asarray(a).astype(dtype), mem)
                return applied(u), mem, jnp.asarray(log).astype(dtype)

            mem0 = law.init(key, ts[0], w0, qq0, controller_params, float(control_period))
            mem0 = jax.tree_util.tree_map(lambda a: jnp.asarray(a).astype(dtype), mem0)
            extra = dict(memory0=mem0, log_size=law.log_size)
            command: Callable = command_memory
        else:
            stateless = controller

            def command_held(t, y):
                return applied(stateless(t, y[0], y[1], controller_params))

            command = command_held

        return held_solve(
            field, command, y0, params, ts,
            None if times is None else times.astype(dtype), control_period, cmd0, options,
            unit=(1,), name="gyrostat", event=ev, **extra,
        )  # fmt: skip

    B = int(np.prod(batch))
    flat = [
        jnp.broadcast_to(a, (*batch, a.shape[-1])).reshape(B, a.shape[-1])
        for a in (omega0, q0, ws0)
    ]
    if event is not None:
        flat[0] = _pb.finite_at_start(event, ts[0], flat[0], flat[1], batch)
    if keys is not None:
        flat.append(keys.reshape(B))
    if batch:  # each body its own solve; a failure raised once, naming the body
        quiet = dataclasses.replace(options, throw=False)
        axes = (None if event is None else event.in_axes(), *(0,) * len(flat))
        ys, stats, results, cts, cmds, event_t = eqx.filter_vmap(
            lambda *a: one_body(*a, options=quiet), in_axes=axes
        )(event, *flat)
        cts = None if cts is None else cts[0]  # the same sample times for every body
        stats, result = first_failure(stats, results)
        first = stats.pop("failed_body")
        if options.throw:

            def alone(b: int):
                ev = None if event is None else _pb.of_body(event, b)
                return one_body(ev, *(a[b] for a in flat))

            args = (options.max_steps, batch, alone)
            ys = _pb.raise_rerun(result, stats["num_valid"], first, ts, ys, *args)
        stats = _pb.per_body(stats, batch)  # each body's own step counts
    else:
        ev = None if event is None else _pb.of_body(event)
        ys, stats, result, cts, cmds, event_t = one_body(ev, *(a[0] for a in flat))
        ys = jax.tree_util.tree_map(lambda a: a[None], ys)
        cmds = None if cmds is None else cmds[None]
    log = None
    if stateful and cmds is not None:
        cmds, log = cmds[..., :m], cmds[..., m:]
    traj = _trajectory(g, ts, batch, ys, stats, result, cts, cmds, h_rate is not None, log)
    if event_t is not None:
        traj = dataclasses.replace(traj, event_t=jnp.reshape(event_t, batch))
    return traj


def _omega_quat(y: tuple) -> tuple[Array, Array]:
    """`(Ω, q)` of one gyrostat's state `(Ω, q, ...)`."""
    return y[0], y[1]


def _controller_keys(key: Any, batch: tuple[int, ...]) -> Array | None:
    """The bodies' PRNG keys `(*batch,)` (typed) from `controller_key`: None; one per body (a
    single body's one key, so that it draws as at its place in a batch); or one key split over
    the bodies, so that each has its own draws."""
    if key is None:
        return None
    from ..sensors import keys_for

    typed, per_body = keys_for(key, batch, "controller_key")
    if per_body:
        return typed
    return jax.random.split(typed, int(np.prod(batch))).reshape(batch)


def _trajectory(
    g, ts, batch, ys, stats, result, cts, cmds, integrated_h, log=None
) -> GyrostatTrajectory:
    """The trajectory of `batch` from the states `ys` (`(B, T, ...)` leaves)."""
    T = ts.shape[0]

    def shape(a):
        return a.reshape(*batch, T, a.shape[-1])

    omega, q = shape(ys[0]), shape(ys[1])
    ws = shape(ys[2]) if g.wheels else None
    if integrated_h:
        h = shape(ys[2])
    else:
        h = jnp.broadcast_to(g.momentum(ws), (*batch, T, 3))
    return GyrostatTrajectory(
        omega,
        q,
        h,
        ws,
        cts,
        None if cmds is None else cmds.reshape(*batch, *cmds.shape[-2:]),
        None if log is None else log.reshape(*batch, *log.shape[-2:]),
        ts=ts,
        stats=stats,
        result=result,
    )


def _other_kinematics(g, omega0, q0, ts, torque, kinematics, given) -> GyrostatTrajectory:
    """A constant-h gyrostat without wheels or controller in another attitude formulation:
    `simulate(RigidBody, ..., torque=τ − Ω × h)` (the same equations)."""
    if g.wheels or given["h_rate"] is not None or given["controller"] is not None:
        raise ValueError(
            f"kinematics={kinematics!r} is taken for a gyrostat with a constant h and no "
            "controller; with wheels, h_rate or a controller use kinematics='quat'"
        )
    h = g.h

    def total(t, w, q):
        tau = jnp.zeros_like(w) if torque is None else jnp.asarray(torque(t, w, q))
        if given["torque_frame"] == "space":
            tau = quat.rotate(quat.conj(q), tau)
        return tau - jnp.cross(w, h)

    options = SolveOptions.of(given["options"], {})
    event = given["event"]
    call = rigid_call(
        g.body, omega0, q0, ts, total, kinematics, "body", event, options, given["check"]
    )
    traj = solve_rigid(call, options)
    h_t = jnp.broadcast_to(h, traj.omega.shape)
    return GyrostatTrajectory(
        traj.omega, traj.quat, h_t, ts=traj.ts, stats=traj.stats, result=traj.result,
        event_t=traj.event_t,
    )  # fmt: skip


def angular_momentum(gyrostat: Gyrostat, traj: GyrostatTrajectory) -> Float[Array, "*batch T 3"]:
    """The system's angular momentum in body axes, `IΩ + h` (its norm is conserved without
    external torque; `P (IΩ + h)` is constant in space)."""
    return jnp.einsum("ij,...j->...i", gyrostat.body.inertia, traj.omega) + traj.h


def energy(gyrostat: Gyrostat, traj: GyrostatTrajectory) -> Float[Array, "*batch T"]:
    """Kinetic energy: `½ Ω·IΩ` for constant h (the Zhukovsky–Volterra integral); with wheels
    `½ Ω·(I − A J Aᵀ)Ω + ½ Σ J_i (a_i·Ω + ω_w,i)²` (rotor energy included)."""
    I, w = gyrostat.body.inertia, traj.omega
    if gyrostat.wheel_axes is None or gyrostat.wheel_inertia is None or traj.wheel_speed is None:
        return 0.5 * jnp.einsum("...i,ij,...j->...", w, I, w)
    A, J = gyrostat.wheel_axes, gyrostat.wheel_inertia
    M = I - (A * J) @ A.T
    spin = w @ A + traj.wheel_speed
    return 0.5 * jnp.einsum("...i,ij,...j->...", w, M, w) + 0.5 * jnp.sum(J * spin**2, -1)
