"""Six-degree-of-freedom rigid-body motion: translation of the centre of mass and rotation about
it (Zegrya–Parshin 004, "Уравнения движения твердого тела"; THEORY §6).

State and frames
----------------
`RigidState(R, V, q, omega)`:

* `R` — position of the centre of mass (COM) in space (inertial) axes; `V = Ṙ` in space axes;
* `q` — attitude, unit quaternion (scalar first, Hamilton), `P(q)` maps body → space components;
* `omega` — body angular velocity Ω in BODY axes.

Equations (004 (12.13), (12.16), (12.20) and Euler's equations):

    Ṙ = V,     m V̇ = F                     (F the total external force, space axes)
    q̇ = ½ q ∘ (0, Ω),   I Ω̇ + Ω × IΩ = K   (K the total torque about the COM, body axes)

A force `f` applied at a body point whose position relative to the COM is `a` has the moment
`a × f` about the COM, so a load `(f, a)` adds `F += f`, `K += a × f`; this is 004's change of
origin `K = K' + a × F` (12.19) with `K' = 0` about the point of application. `wrench_at_point`
does this bookkeeping (body-axis `a`, force in space or body axes). The velocity of a body point
is `v = V + Ω × r` (004 (11.3)); in space components `v = V + P (Ω × r_body)`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Unpack

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._checks import (
    as_float,
    check_frame,
    check_times,
    check_unit_norm,
    initial_vector,
    vector,
)
from .._custom_types import Frame, RealLike, Vec3
from .._integrate import SolveKwargs, SolveOptions
from .._trajectory import AbstractTrajectory
from ..kinematics.formulations import Quaternion
from ..models.solve import solve_tree
from ..rotations import quat
from .body import RigidBody, euler_rhs
from .invariants import _batched_inertia

__all__ = [
    "RigidState",
    "SixDofTrajectory",
    "Wrench",
    "WrenchFn",
    "angular_momentum",
    "initial_state",
    "kinetic_energy",
    "linear_momentum",
    "point_position",
    "point_velocity",
    "pure_torque",
    "simulate_6dof",
    "wrench_at_point",
]


class RigidState(eqx.Module):
    """6-DOF state: COM position `R` and velocity `V` (space axes), attitude `q` (unit quaternion,
    body → space) and body angular velocity `omega` (body axes). Leaves may carry the same
    leading batch/time dimensions (a `SixDofTrajectory.state` has a leading time axis)."""

    R: Float[Array, "*batch 3"]
    V: Float[Array, "*batch 3"]
    q: Float[Array, "*batch 4"]
    omega: Float[Array, "*batch 3"]

    @property
    def matrix(self) -> Float[Array, "*batch 3 3"]:
        """Rotation tensor P (body → space)."""
        return quat.to_matrix(self.q)

    @property
    def omega_space(self) -> Vec3:
        """Angular velocity in space axes `ω = P Ω`."""
        return quat.rotate(self.q, self.omega)


class Wrench(eqx.Module):
    """Total load on the body: `force` F in SPACE axes (acts on the COM motion) and `torque` K
    about the COM in BODY axes (enters Euler's equations). Wrenches add with `+`."""

    force: Float[Array, "*batch 3"]
    torque: Float[Array, "*batch 3"]

    def __add__(self, other: Wrench) -> Wrench:
        if not isinstance(other, Wrench):
            return NotImplemented
        return Wrench(self.force + other.force, self.torque + other.torque)

    def total(self) -> Wrench:
        """Sum over all leading dimensions (several loads given as one batched Wrench)."""
        f, k = self.force.reshape(-1, 3), self.torque.reshape(-1, 3)
        return Wrench(jnp.sum(f, axis=0), jnp.sum(k, axis=0))


def wrench_at_point(
    force: RealLike,
    point: RealLike,
    q: RealLike,
    *,
    force_frame: Frame = "space",
) -> Wrench:
    """Wrench of a force applied at a body point: `F = f` (space axes) and
    `K = a × f` about the COM in body axes (004 (12.19), `K = K' + a × F`), where `point` a is the
    position of the point of application relative to the COM in BODY axes and `force` is given in
    `force_frame` axes (`"body"` for e.g. a thruster fixed to the body). Shapes broadcast; use
    `.total()` to add several loads given as arrays `(n, 3)`."""
    check_frame(force_frame, "force_frame")
    f = vector(force, 3, "force")
    a = vector(point, 3, "point")
    q = vector(q, 4, "q")
    if force_frame == "space":
        f_space = f
        f_body = quat.rotate(quat.conj(q), f)
    else:
        f_body = f
        f_space = quat.rotate(q, f)
    a, f_body = jnp.broadcast_arrays(a, f_body)
    return Wrench(f_space, jnp.cross(a, f_body))


def pure_torque(torque: RealLike, q: RealLike, *, frame: Frame = "body") -> Wrench:
    """A couple (zero net force; 004: its moment is the same about every origin), given in
    `frame` axes."""
    check_frame(frame)
    K = vector(torque, 3, "torque")
    if frame == "space":
        K = quat.rotate(quat.conj(vector(q, 4, "q")), K)
    return Wrench(jnp.zeros_like(K), K)


def point_position(state: RigidState, point: RealLike) -> Vec3:
    """Space position of the body point with body coordinates `point` (relative to the COM):
    `R + P r`."""
    return state.R + quat.rotate(state.q, vector(point, 3, "point"))


def point_velocity(state: RigidState, point: RealLike) -> Vec3:
    """Space velocity of a body point: `v = V + Ω × r` (004 (11.3)), i.e.
    `V + P (Ω × r_body)` with Ω and r in body axes."""
    r = vector(point, 3, "point")
    return state.V + quat.rotate(state.q, jnp.cross(state.omega, r))


def _mass(body: RigidBody, V: Array) -> Array:
    """The mass `(...,)` broadcast against `V (..., [T,] 3)` (the time axis inserted, as
    `_batched_inertia` does for the inertia)."""
    m = jnp.broadcast_to(body.mass, body.batch_shape)
    return m.reshape(m.shape + (1,) * max(V.ndim - 1 - m.ndim, 0))


def linear_momentum(body: RigidBody, state: RigidState) -> Vec3:
    """`P = m V` (space axes)."""
    return _mass(body, state.V)[..., None] * state.V


def angular_momentum(body: RigidBody, state: RigidState, *, frame: Frame = "space") -> Vec3:
    """Angular momentum about the COM: `M = I Ω` in body axes, `P I Ω` in space axes."""
    check_frame(frame)
    M = jnp.einsum("...ij,...j->...i", _batched_inertia(body, state.omega), state.omega)
    return quat.rotate(state.q, M) if frame == "space" else M


def kinetic_energy(body: RigidBody, state: RigidState) -> Array:
    """`T = ½ m V² + ½ Ω·IΩ` (004 (11.8): translation of the COM plus rotation about it)."""
    M = angular_momentum(body, state, frame="body")
    return 0.5 * _mass(body, state.V) * jnp.sum(state.V**2, axis=-1) + 0.5 * jnp.sum(
        state.omega * M, axis=-1
    )


WrenchFn = Callable[[Array, RigidState], "Wrench | tuple[ArrayLike, ArrayLike]"]


def _as_wrench(w, dtype) -> Wrench:
    if isinstance(w, Wrench):
        F, K = w.force, w.torque
    elif isinstance(w, tuple | list) and len(w) == 2:
        F, K = w
    else:
        raise TypeError(
            "wrench(t, state) must return a rigidjax.sixdof.Wrench or a pair "
            f"(force_space (3,), torque_body (3,)), got {type(w).__name__}"
        )
    F = vector(F, 3, "wrench force").astype(dtype)
    K = vector(K, 3, "wrench torque").astype(dtype)
    if F.shape != (3,) or K.shape != (3,):
        raise ValueError(
            f"wrench(t, state) must return force and torque of shape (3,) (call .total() to sum "
            f"several loads), got {F.shape} and {K.shape}"
        )
    return Wrench(F, K)


_QUATERNION = Quaternion(frame="body")  # q̇ = ½ q ∘ (0, Ω) and its step-end normalisation


class _SixDofField(eqx.Module):
    wrench: WrenchFn | None

    def __call__(self, t, y: RigidState, args):
        I, I_inv, inv_m = args  # 1/m: no division per stage
        q, _ = _QUATERNION.step_end(y.q)  # the load sees a unit quaternion
        if self.wrench is None:
            F = K = jnp.zeros_like(y.V)
        else:
            w = _as_wrench(self.wrench(t, RigidState(y.R, y.V, q, y.omega)), y.V.dtype)
            F, K = w.force, w.torque
        return RigidState(
            R=y.V,
            V=F * inv_m,
            q=_QUATERNION.vector_field(y.q, y.omega),
            omega=euler_rhs(I, I_inv, y.omega, K),
        )


def initial_state(R0: RealLike, V0: RealLike, q0: RealLike | None, omega0: RealLike, dtype):
    """The checked initial `RigidState` (one body; `q0=None`: the identity)."""
    R0 = initial_vector(R0, 3, "R0", dtype)
    V0 = initial_vector(V0, 3, "V0", dtype)
    omega0 = initial_vector(omega0, 3, "omega0", dtype)
    q0 = quat.identity(dtype=dtype) if q0 is None else initial_vector(q0, 4, "q0", dtype)
    return RigidState(R0, V0, check_unit_norm(q0, "q0"), omega0)


class SixDofTrajectory(AbstractTrajectory):
    """Solution of `simulate_6dof`: times `ts (T,)`, centre-of-mass position `R (T, 3)` and
    velocity `V (T, 3)` (space axes), attitude `quat (T, 4)` (unit, as integrated: its sign is
    continuous in time) and body angular velocity `omega (T, 3)`; `state` bundles them as a
    `RigidState` with a leading time axis."""

    R: Float[Array, "T 3"]
    V: Float[Array, "T 3"]
    quat: Float[Array, "T 4"]
    omega: Float[Array, "T 3"]

    @property
    def state(self) -> RigidState:
        return RigidState(self.R, self.V, self.quat, self.omega)

    @property
    def matrix(self) -> Float[Array, "T 3 3"]:
        return self.state.matrix


def simulate_6dof(
    body: RigidBody,
    R0: RealLike,
    V0: RealLike,
    q0: RealLike | None,
    omega0: RealLike,
    ts: RealLike,
    wrench: WrenchFn | None = None,
    *,
    options: SolveOptions | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> SixDofTrajectory:
    """Integrate the 6-DOF equations `Ṙ = V`, `m V̇ = F`, `q̇ = ½ q ∘ (0, Ω)`,
    `I Ω̇ + Ω × IΩ = K` (Zegrya–Parshin 004) from `(R0, V0, q0, omega0)` at `ts[0]`, saving at `ts`.

    `R0`, `V0`: COM position and velocity (space axes); `q0`: unit quaternion body → space
    (identity if None); `omega0`: body angular velocity (body axes). `wrench(t, state)` gives the
    load: a `Wrench` (force in space axes, torque about the COM in body axes) or a pair
    `(F_space, K_body)`; build it with `wrench_at_point`, `pure_torque` and `+`. The state passed
    to it has a unit quaternion. `None` is free flight. `body` must be a single body (no batch
    dimensions): `jax.vmap` over `simulate_6dof` for batches.

    The quaternion is renormalised after every step (`StepEndMap` around the solver); defaults:
    Tsit5 with unrolled stages (`ExplicitRK`), PID at `rtol = atol = 1e-10` in float64 (1e-6 in
    float32); mind the scales — `atol` applies to positions, velocities, quaternion and Ω alike.
    """
    options = SolveOptions.of(options, solve_kwargs)
    if not isinstance(body, RigidBody):
        raise TypeError(f"body must be a rigidjax.RigidBody, got {type(body).__name__}")
    if body.batch_shape != ():
        raise ValueError(
            f"simulate_6dof integrates one body; got a batch {body.batch_shape} (use jax.vmap)"
        )
    if wrench is not None and not callable(wrench):
        raise TypeError(f"wrench must be a callable (t, state) -> Wrench, got {wrench!r}")
    ts = check_times(as_float(ts, "ts"))
    dtype = ts.dtype
    I, I_inv = (a.astype(dtype) for a in body.operator())
    ys, stats, result = solve_tree(
        _SixDofField(wrench),
        ts,
        initial_state(R0, V0, q0, omega0, dtype),
        (I, I_inv, 1 / body.mass.astype(dtype)),
        options,
        unit=(2,),
        name="6-DOF body",
    )
    # step-end states: normalised, with the sign of the integrated solution (continuous)
    return SixDofTrajectory(
        ts=ts, R=ys.R, V=ys.V, quat=ys.q, omega=ys.omega, stats=stats, result=result
    )
