"""Data of one or several experiments, brought to one layout `(E, T, ...)` and checked.

An experiment is one record of a motion: times `ts (T,)`, gyro samples `omega_obs (T, 3)`
and/or attitude samples `quat_obs (T, 4)`. Several experiments (several manoeuvres of the same
body) come as `omega_obs (E, T, 3)` / `quat_obs (E, T, 4)`, with shared times `ts (T,)` or
their own `ts (E, T)`. The fits give each experiment its own initial state and share the
inertia tensor (and the sensor errors) between them.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import as_float, check_finite, check_times, validate, vector, zero_vector
from .._custom_types import RealLike
from ..rotations import quat

__all__ = ["Experiments", "angular_rate", "experiments", "guess", "initial_states"]


class Experiments(NamedTuple):
    """`ts (E, T)`, `omega (E, T, 3)` or None, `quat (E, T, 4)` (unit) or None; `several`:
    whether the data came with the experiment axis (the results then keep it). Made by
    `experiments` with the arrays as given (checked), and brought to the layout `(E, T, ...)`
    by `arranged` (inside the compiled fit: no eager operations to compile one by one)."""

    ts: Float[Array, "*E T"]
    omega: Float[Array, "*E T 3"] | None
    quat: Float[Array, "*E T 4"] | None
    several: bool
    E: int
    T: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.E, self.T

    def arranged(self) -> Experiments:
        E, T = self.shape
        ts = jnp.broadcast_to(self.ts, (E, T))
        w = None if self.omega is None else self.omega.reshape(E, T, 3)
        q = None if self.quat is None else quat.normalize(self.quat.reshape(E, T, 4))
        return Experiments(ts, w, q, self.several, E, T)


def _samples(x: RealLike, n: int, name: str, dtype) -> Array:
    x = check_finite(vector(x, n, name).astype(dtype), name)
    if x.ndim not in (2, 3):
        raise ValueError(
            f"{name} must have shape (T, {n}) (one experiment) or (E, T, {n}) (E experiments), "
            f"got {tuple(x.shape)}"
        )
    return x


def experiments(ts: RealLike, omega_obs: RealLike | None, quat_obs: RealLike | None) -> Experiments:
    """Check the data of one or several experiments (see the module docstring)."""
    if omega_obs is None and quat_obs is None:
        raise ValueError("give omega_obs (gyro data), quat_obs (attitude data), or both")
    ts = as_float(ts, "ts")
    dtype = ts.dtype
    w = None if omega_obs is None else _samples(omega_obs, 3, "omega_obs", dtype)
    q = None if quat_obs is None else _samples(quat_obs, 4, "quat_obs", dtype)
    first = w if w is not None else q
    assert first is not None
    several = first.ndim == 3
    if ts.ndim == 1:
        ts = check_times(ts)
    elif ts.ndim == 2 and several:
        for e in range(ts.shape[0]):  # each row checked, the error names it
            check_times(ts[e], f"ts[{e}]")
    elif ts.ndim == 2:
        raise ValueError(
            f"ts of shape {tuple(ts.shape)} (E, T) needs data of E experiments: omega_obs "
            "(E, T, 3) and/or quat_obs (E, T, 4); for one experiment give ts of shape (T,)"
        )
    else:
        raise ValueError(f"ts must have shape (T,) or (E, T), got {tuple(ts.shape)}")
    T = ts.shape[-1]
    E = first.shape[0] if several else 1
    if ts.ndim == 2 and ts.shape[0] != E:
        raise ValueError(f"ts must have shape ({T},) or ({E}, {T}), got {tuple(ts.shape)}")
    for x, n, name in ((w, 3, "omega_obs"), (q, 4, "quat_obs")):
        want = (E, T, n) if several else (T, n)
        if x is not None and tuple(x.shape) != want:
            other = " and the other data" if w is not None and q is not None else ""
            raise ValueError(
                f"{name} must have shape {want} to match ts {tuple(ts.shape)}{other}, got "
                f"{tuple(x.shape)}"
            )
    if q is not None:
        q = validate(
            q,
            zero_vector,
            "quat_obs must hold non-zero quaternions (they are normalised)",
            hint="; drop the samples without attitude",
        )
    return Experiments(ts, w, q, several, E, T)


def angular_rate(data: Experiments) -> Float[Array, " E"]:
    """An upper estimate of each experiment's angular speed `|Ω|`, for the integrator's step:
    the largest gyro sample, or the largest attitude change per sample interval."""
    if data.omega is not None:
        return jnp.max(jnp.linalg.norm(data.omega, axis=-1), axis=-1)
    return jnp.max(_attitude_steps(data) / jnp.diff(data.ts, axis=-1), axis=-1)


def _attitude_steps(data: Experiments) -> Float[Array, "E _"]:
    """The angle of each attitude change between consecutive samples (arranged data)."""
    assert data.quat is not None
    return jnp.linalg.norm(quat.local(data.quat[:, :-1], data.quat[:, 1:]), axis=-1)


def turned_angle(data: Experiments) -> Float[Array, "E T"]:
    """The angle through which each experiment's body has turned by each sample: `∫|Ω| dt`
    (trapezoidal) from the gyro data, else the sum of the attitude changes (arranged data)."""
    if data.omega is not None:
        speed = jnp.linalg.norm(data.omega, axis=-1)
        steps = 0.5 * (speed[:, 1:] + speed[:, :-1]) * jnp.diff(data.ts, axis=-1)
    else:
        steps = _attitude_steps(data)
    return jnp.concatenate([jnp.zeros_like(steps[:, :1]), jnp.cumsum(steps, axis=1)], axis=1)


def initial_states(
    data: Experiments, omega0_guess: Array | None, q0_guess: Array | None
) -> tuple[Float[Array, "E 3"], Float[Array, "E 4"]]:
    """Starting points `(Ω0, q0)` per experiment: the guesses given (`(3,)` for every
    experiment or `(E, 3)`, checked by `guess`), else the first gyro sample (or the attitude
    change over the first interval) and the first attitude sample (or the identity)."""
    E, _ = data.shape
    dtype = data.ts.dtype
    if omega0_guess is not None:
        w = jnp.broadcast_to(omega0_guess, (E, 3)).astype(dtype)
    elif data.omega is not None:
        w = data.omega[:, 0]
    else:
        assert data.quat is not None
        w = quat.local(data.quat[:, 0], data.quat[:, 1]) / (data.ts[:, 1:2] - data.ts[:, :1])
    if q0_guess is not None:
        q = quat.normalize(jnp.broadcast_to(q0_guess, (E, 4)).astype(dtype))
    elif data.quat is not None:
        q = data.quat[:, 0]
    else:
        q = jnp.broadcast_to(quat.identity(dtype=dtype), (E, 4))
    return w, q


def guess(x: RealLike | None, n: int, E: int, name: str, dtype) -> Array | None:
    """A checked initial guess `(n,)` (every experiment) or `(E, n)` (one per experiment)."""
    if x is None:
        return None
    x = check_finite(vector(x, n, name).astype(dtype), name)
    if x.ndim == 1 or tuple(x.shape) == (E, n):
        return x
    raise ValueError(
        f"{name} must have shape ({n},) or ({E}, {n}) (one per experiment), got {tuple(x.shape)}"
    )
