"""Scalar observables of one `Trajectory` of `rigidjax.simulate`, for sweeps and sensitivities.

Each is a pure JAX function of the trajectory (and the body): it works under `jit`, `vmap` and
`grad` (finite gradients everywhere, also where an angle or a deviation is 0), and it accepts the
leading batch dimensions of a batched trajectory (`omega (..., T, 3)`, `quat (..., T, 4)`, a
batched body broadcasting against them), returning one value per member. The states of a failed
solve (NaN) give NaN, never an error. The maxima are over the saved samples `traj.ts` only:
refine `ts` to resolve a peak between samples.

The *initially dominant axis* `d` is the body coordinate axis `e_d` with the largest `|Ω0_d|`
(`Ω0 = traj.omega[..., 0, :]`; on a tie the first one; with a body given by its principal moments
these are principal axes), the same contract as `rigidjax.analytic.time_of_first_flip`.

`flip_event(omega0)` (from `rigidjax.events`) is the first flip as an event of `simulate`: its
time located by the solver, not interpolated between samples as `first_flip_time` does.

Closed loops (a `Gyrostat` with wheels and a controller: `GyrostatTrajectory`):
`pointing_error`, `settling_time` (and `settling_bracket`, the samples around it),
`peak_wheel_speed`, `saturation_count`.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._checks import as_float, check_nonnegative, vector
from ._custom_types import QuatLike, Scalar, ScalarLike
from .events import flip_event
from .mechanics import RigidBody, Trajectory, angular_momentum, energy
from .mechanics.gyrostat import GyrostatTrajectory
from .rotations import _quat_core, quat

__all__ = [
    "energy_drift",
    "first_flip_time",
    "flip_event",
    "max_nutation",
    "momentum_drift",
    "peak_wheel_speed",
    "pointing_error",
    "saturation_count",
    "settling_bracket",
    "settling_time",
]


def _safe_norm(x: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
    """`|x|` with a finite (zero) gradient at `x = 0` (the double-`where` trick)."""
    x2 = jnp.sum(x * x, axis=-1)
    zero = x2 == 0  # (NaN stays NaN)
    return jnp.where(zero, 0, jnp.sqrt(jnp.where(zero, 1, x2)))


def _rotate(
    q: Float[Array, "*#batch 4"], v: Float[Array, "*#batch 3"]
) -> Float[Array, "*#batch 3"]:
    """`P(q) v = v + 2(λ0 λ × v + λ × (λ × v))/|q|²` without `quat.rotate`'s finiteness check:
    the states of a failed solve (`SolveOptions(throw=False)`) give NaN observables, no error."""
    w, u = q[..., :1], q[..., 1:]
    u = jnp.broadcast_to(u, jnp.broadcast_shapes(u.shape, v.shape))
    t = jnp.cross(u, v)
    return v + 2 * (w * t + jnp.cross(u, t)) / jnp.sum(q * q, axis=-1, keepdims=True)


def _dominant_axis(traj: Trajectory) -> Float[Array, "*batch 3"]:
    """The unit vector `e_d` (body components) of the initially dominant axis, `(..., 3)`."""
    w0 = traj.omega[..., 0, :]
    d = jnp.argmax(jnp.abs(w0), axis=-1)
    return (jnp.arange(3) == d[..., None]).astype(w0.dtype)


def _relative(dev: Float[Array, "*batch T"], ref: Float[Array, "*batch"]) -> Scalar:
    """`max_t dev(t) / ref`, the absolute `max_t dev` where `ref = 0`."""
    return jnp.max(dev, axis=-1) / jnp.where(ref == 0, 1, ref)


def max_nutation(traj: Trajectory) -> Scalar:
    """Largest angle (radians, in `[0, π]`) by which the initially dominant body axis `e_d`
    (module docstring) has turned away from its initial direction in space:
    `max_t ∠(n(t), n(0))`, `n(t) = P(t) e_d`, with `∠(a, b) = atan2(|a × b|, a·b)` (accurate
    near 0 and π). 0 for a steady rotation about a principal axis (a kink: nearby it grows like
    the size of the perturbation; the derivative there is finite but one-sided); `2θ`
    (`2π − 2θ` if θ > π/2) after half a precession period for a symmetric top spun mostly about
    its symmetry axis, θ the constant angle between that axis and M; towards π as the
    intermediate axis turns over (the tennis-racket flip). Derivatives are those at the
    maximising sample."""
    e = _dominant_axis(traj)
    n = _rotate(traj.quat, e[..., None, :])  # (..., T, 3)
    n0 = n[..., :1, :]
    sin = _safe_norm(jnp.cross(n0, n))
    cos = jnp.sum(n0 * n, axis=-1)
    return jnp.max(jnp.arctan2(sin, cos), axis=-1)


def first_flip_time(traj: Trajectory) -> Scalar:
    """First time at which `c(t) = Ω(t)·e_d`, the body angular-velocity component along the
    initially dominant axis (module docstring), changes sign; `inf` if it never does within
    `traj.ts`. With `s_j = c(t_j) sign c(t_0)` and `i` the first sample index with
    `s_{i+1} < 0` (a touch of zero without a change of sign is not a flip), the crossing is
    linearly interpolated: `t_i + (t_{i+1} − t_i) s_i / (s_i − s_{i+1})`, error O(Δt²), also in
    its gradient (O(Δt³) for a torque-free body in principal axes, whose `Ω̇_d ∝ Ω_i Ω_j` has
    `Ω̈_d = 0` where `Ω_d = 0`). It approximates `rigidjax.analytic.time_of_first_flip` of the
    same body and `Ω0`. The derivative flows through `s_i`, `s_{i+1}` (0 where `inf`); NaN
    states give NaN. The exact alternative: `simulate(..., event=flip_event(omega0))` locates
    the same crossing by the solver, to its tolerance (`traj.event_t`, `flip_event`)."""
    e = _dominant_axis(traj)
    c = jnp.sum(traj.omega * e[..., None, :], axis=-1)  # (..., T)
    s = c * jnp.sign(c[..., :1])
    neg = s[..., 1:] < 0
    flips = jnp.any(neg, axis=-1)
    i = jnp.argmax(neg, axis=-1)[..., None]  # the first True (0 when there is none)
    a = jnp.take_along_axis(s, i, axis=-1)[..., 0]
    b = jnp.take_along_axis(s, i + 1, axis=-1)[..., 0]
    ts = jnp.broadcast_to(traj.ts, s.shape)  # ts (T,), or (..., T) from a vmapped simulate
    t_a = jnp.take_along_axis(ts, i, axis=-1)[..., 0]
    t_b = jnp.take_along_axis(ts, i + 1, axis=-1)[..., 0]
    frac = a / jnp.where(flips, a - b, 1)  # a ≥ 0 > b where it flips
    t = jnp.where(flips, t_a + (t_b - t_a) * frac, jnp.inf)
    return jnp.where(jnp.any(jnp.isnan(c), axis=-1), jnp.nan, t)


def energy_drift(body: RigidBody, traj: Trajectory) -> Scalar:
    """Largest relative deviation of the kinetic energy `T = ½ Ω·IΩ` from its initial value:
    `max_t |T(t) − T(0)| / T(0)` (the absolute deviation where `T(0) = 0`). Conserved by the
    torque-free motion, so there this measures the integration error (under a torque, the
    work done)."""
    T = energy(body, traj.omega)  # (..., T)
    T0 = T[..., :1]
    return _relative(jnp.abs(T - T0), T0[..., 0])


def momentum_drift(body: RigidBody, traj: Trajectory) -> Scalar:
    """Largest relative deviation of the angular momentum VECTOR in space, `M = P IΩ`, from its
    initial value: `max_t |M(t) − M(0)| / |M(0)|` (the absolute deviation where `M(0) = 0`).
    The whole vector is conserved by the torque-free motion, so this measures the errors of both
    Euler's equations and the attitude; it bounds the drift of `|M|` (`||M| − |M0|| ≤ |M − M0|`)."""
    M = _rotate(traj.quat, angular_momentum(body, traj.omega))  # (..., T, 3)
    M0 = M[..., :1, :]
    return _relative(_safe_norm(M - M0), _safe_norm(M0[..., 0, :]))


def pointing_error(traj: Trajectory, q_target: QuatLike) -> Float[Array, "*batch T"]:
    """Angle (radians, in `[0, π]`) between the attitude and the target attitude `q_target`
    (unit, body → space) at each sample: the rotation angle of the error quaternion
    `q_e = q_target⁻¹ ∘ q` (Wie, *Space Vehicle Dynamics and Control*, §7.3),
    `2 atan2(|q_e,1:3|, |q_e0|)` (the shorter way round; accurate near 0 and π). Finite
    gradients at 0 (the double-`where` trick on the norm). A non-unit `q_target` is normalised;
    a zero or non-finite one is an error."""
    target = _quat_core._unit(vector(q_target, 4, "q_target"), "q_target")
    qe = quat.mul(quat.conj(target.astype(traj.quat.dtype)), traj.quat)
    return 2 * jnp.arctan2(_safe_norm(qe[..., 1:]), jnp.abs(qe[..., 0]))


def settling_bracket(
    traj: Trajectory, q_target: QuatLike, tolerance: ScalarLike
) -> tuple[Scalar, Scalar]:
    """The samples around the settling: `(ts[i], ts[i + 1])`, `i` the last sample at which the
    pointing error (`pointing_error`) exceeds `tolerance` (radians), so that the last entry
    into the tolerance lies in `(ts[i], ts[i + 1]]`. `(-inf, ts[0])` if the error never
    exceeds it, `(ts[-1], inf)` if it does at the last sample (not settled within
    `traj.ts`); NaN states give NaN. `simulate(..., event=events.settling_event(q_target,
    tolerance, ts[i]))` locates the entry (`traj.event_t`), as `rigidjax sweep` does."""
    tolerance = check_nonnegative(as_float(tolerance, "tolerance"), "tolerance", "radians")
    err = pointing_error(traj, q_target)
    T = err.shape[-1]
    last = jnp.max(jnp.where(err > tolerance, jnp.arange(T), -1), axis=-1)
    ts = jnp.broadcast_to(traj.ts, err.shape)

    def at(i):
        return jnp.take_along_axis(ts, jnp.clip(i, 0, T - 1)[..., None], axis=-1)[..., 0]

    nan = jnp.any(jnp.isnan(err), axis=-1)
    before = jnp.where(nan, jnp.nan, jnp.where(last >= 0, at(last), -jnp.inf))
    after = jnp.where(nan, jnp.nan, jnp.where(last + 1 < T, at(last + 1), jnp.inf))
    return before, after


def settling_time(traj: Trajectory, q_target: QuatLike, tolerance: ScalarLike) -> Scalar:
    """First sample time after which the pointing error (`pointing_error`) stays within
    `tolerance` (radians) up to the last sample: `ts[i + 1]`, `i` the last sample outside;
    `ts[0]` if it never leaves, `inf` if the last sample is outside (it has not settled within
    `traj.ts`). Resolution: the sample spacing (`settling_bracket` gives the sample before,
    from which an event locates the exact time). NaN states give NaN."""
    return settling_bracket(traj, q_target, tolerance)[1]


def peak_wheel_speed(traj: Trajectory) -> Scalar:
    """Largest `|ω_w|` (rad/s, relative to the body) of any wheel at any sample of a gyrostat's
    trajectory with wheels."""
    if not isinstance(traj, GyrostatTrajectory) or traj.wheel_speed is None:
        raise ValueError("peak_wheel_speed needs a trajectory of a gyrostat with wheels")
    return jnp.max(jnp.abs(traj.wheel_speed), axis=(-2, -1))


def saturation_count(traj: Trajectory, torque_max: float) -> Array:
    """Number of control samples at which some wheel's motor torque was held at its bound
    `torque_max` (the command is clipped to `±wheel_torque_max`; counted within a relative
    1e-12 of it), for a trajectory with a controller."""
    if not isinstance(traj, GyrostatTrajectory) or traj.command is None:
        raise ValueError("saturation_count needs a trajectory with a controller (its commands)")
    at_bound = jnp.abs(traj.command) >= torque_max * (1 - 1e-12)
    return jnp.sum(jnp.any(at_bound, axis=-1), axis=-1)
