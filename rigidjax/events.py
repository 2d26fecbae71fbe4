"""Events: the first time a scalar condition of the motion crosses zero, located by the solver.

`simulate(..., event=Event(condition))` integrates each body until `condition(t, omega, q)` (of
one body: `t` scalar, `omega (3,)`, `q (4,)`) crosses zero and returns that time as the
trajectory's `event_t` (`inf` where there is none). On the CPU's per-body kernel
(`rigidjax.kernels.adaptive`, adaptive or fixed steps, the gyrostat and its closed loop
included) the crossing is located on the step itself by the Illinois method; on the Diffrax
path by a Newton root find on the step's interpolant (`diffrax.Event` with
`optimistix.Newton(rtol, atol)` at the solver's tolerances). Two ready-made events:
`flip_event(omega0)` (the tennis-racket flip) and `settling_event(q_target, tolerance, after)`
(the entry into a pointing tolerance).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from ._checks import check_nonnegative
from ._custom_types import RealLike
from .rotations import _quat_core

__all__ = ["Event", "flip_event", "settling_event"]


class Event(eqx.Module):
    """A zero crossing of `condition(t, omega, q) -> scalar` (one body, floating point).

    - `direction`: `None` (either way), `+1` (rising: from ≤ 0 to > 0) or `-1` (falling: from
      > 0 to ≤ 0); crossings the other way are ignored.
    - `terminate`: with `True` (default) each body stops at its event: the outputs after it
      hold the state at the event. With `False` the integration goes on unchanged and only the
      first event time is recorded.
    - `per_body`: the condition is a PyTree (an `equinox.Module`, a `jax.tree_util.Partial`)
      whose array leaves carry the batch's leading dimensions: each body gets its own slice
      (`flip_event(omega0)` of a batch builds one). Otherwise every body shares the condition.

    The event is detected where the condition's sign differs between two step ends (a crossing
    and back within one step is not seen), then located to the solver's tolerance. A
    condition exactly zero at the initial time counts as crossing there once it leaves zero
    (upward for `+1`, either way for `None`, never for `−1`: zero is on the ≤ 0 side), as in
    Diffrax: offset such a condition by a margin where the start must not count. The
    attitude `q` is a unit quaternion whose sign depends on the kinematics: use conditions
    that are even in `q` (as every function of the attitude is). Differentiable: `jax.grad`
    of `event_t` (implicit differentiation of the root find) with respect to the initial
    conditions, the body and anything the condition or the torque close over."""

    condition: Any  # condition(t, omega, q) -> scalar
    # (`Any`: checked in `__check_init__`, with a clear error, not by the runtime type check)
    terminate: Any = eqx.field(static=True, default=True)
    direction: Any = eqx.field(static=True, default=None)
    per_body: Any = eqx.field(static=True, default=False, kw_only=True)

    def __check_init__(self):
        if not callable(self.condition):
            raise TypeError(
                "Event's condition must be a callable condition(t, omega, q) -> scalar, got "
                f"{self.condition!r}"
            )
        if isinstance(self.direction, bool) or self.direction not in (None, 1, -1):
            raise ValueError(
                "Event's direction must be None (a crossing either way), +1 (rising: from "
                f"negative to positive) or -1 (falling), got {self.direction!r}"
            )
        if not isinstance(self.terminate, bool):
            raise TypeError(f"Event's terminate must be True or False, got {self.terminate!r}")
        if not isinstance(self.per_body, bool):
            raise TypeError(f"Event's per_body must be True or False, got {self.per_body!r}")

    def on_state(self, to_args: Callable[[Any], tuple[Array, ...]]) -> Event:
        """The same event with its condition on a solve's state `y`: `condition(t,
        *to_args(y))` (`to_args`: an `equinox.Module` or a module-level function, so that
        equal events compile once)."""
        return Event(
            _OnState(self.condition, to_args),
            self.terminate,
            self.direction,
            per_body=self.per_body,
        )

    def shared(self) -> Event:
        """The same event for one body (its slice of a `per_body` condition taken)."""
        return Event(self.condition, self.terminate, self.direction)

    def flat(self, batch: tuple[int, ...]) -> Event:
        """A `per_body` event's leaves with the batch `batch` flattened to one axis `(B, ...)`
        (a clear error where a leaf does not lead with `batch`); a shared event unchanged."""
        if not self.per_body:
            return self
        n = len(batch)

        def one(a):
            if jnp.shape(a)[:n] != batch:
                raise ValueError(
                    f"a per_body Event's arrays must lead with the batch shape {batch}, got "
                    f"shape {jnp.shape(a)}"
                )
            return jnp.reshape(a, (-1, *jnp.shape(a)[n:]))

        dynamic, static = eqx.partition(self, eqx.is_array)
        return eqx.combine(jax.tree.map(one, dynamic), static)

    def rooted(self, controller: Any, given: tuple, defaults: tuple) -> RootedEvent:
        """The event on a solve's state with its root finder's tolerances: the adaptive
        `controller`'s, else the `given` `(rtol, atol)`, else the `defaults`."""
        tols = []
        for i, name in enumerate(("rtol", "atol")):
            tol = getattr(controller, name, None)
            tol = given[i] if tol is None else tol
            tols.append(defaults[i] if tol is None else tol)
        return RootedEvent(self.condition, self.terminate, self.direction, *tols)

    def in_axes(self) -> Any:
        """`equinox.filter_vmap`'s `in_axes` for this event over flattened bodies."""
        return 0 if self.per_body else None


class RootedEvent(eqx.Module):
    """An event on a solve's state (`Event.rooted`), with the tolerances of its root find."""

    condition: Callable
    terminate: bool = eqx.field(static=True)
    direction: int | None = eqx.field(static=True)
    rtol: Any
    atol: Any

    def diffrax_event(self, active: Array) -> diffrax.Event:
        """The `diffrax.Event` (`optimistix.Newton` at `rtol`, `atol`), looked for only where
        `active` (a boolean scalar)."""
        direction = None if self.direction is None else self.direction > 0
        finder = optx.Newton(rtol=self.rtol, atol=self.atol)
        return diffrax.Event(_Active(self.condition, active), finder, direction)


class _Active(eqx.Module):
    """A condition `(t, y) -> c` as Diffrax calls it, constant 1 (no crossing) unless `on`."""

    condition: Callable
    on: Array

    def __call__(self, t, y, args, **kwargs):
        del args, kwargs
        value = self.condition(t, y)
        # in the default float dtype: Diffrax's root find selects it against a Python 0.0, a
        # float64 under x64 (a float32 condition was a type error there)
        value = value.astype(jnp.result_type(float))
        return jnp.where(self.on, value, jnp.ones_like(value))


class _OnState(eqx.Module):
    condition: Callable[..., Any]
    to_args: Callable[[Any], tuple[Array, ...]]

    def __call__(self, t, y):
        value = self.condition(t, *self.to_args(y))
        if jnp.shape(value) != () or not jnp.issubdtype(jnp.result_type(value), jnp.floating):
            raise ValueError(
                "an Event's condition(t, omega, q) must return a floating-point scalar (of one "
                f"body), got {jax.ShapeDtypeStruct(jnp.shape(value), jnp.result_type(value))}"
            )
        return value


class _DominantComponent(eqx.Module):
    """`Ω·e` for the unit axis `e (3,)` (or `(..., 3)`, one per body)."""

    axis: Array

    def __call__(self, t, omega, q):
        del t, q
        return jnp.sum(omega * self.axis.astype(omega.dtype), axis=-1)


def flip_event(omega0, *, direction: int | None = None, terminate: bool = True) -> Event:
    """The tennis-racket flip as an event: `Ω(t)·e_d` crosses zero, `e_d` the body axis with
    the largest `|Ω0_d|` (the first on a tie; `rigidjax.observables` calls it the initially
    dominant axis). `simulate(body, omega0, ..., event=flip_event(omega0))` then gives the
    first flip time located by the solver (`traj.event_t`, to its tolerance), where
    `observables.first_flip_time(traj)` interpolates it between samples; it is
    `analytic.time_of_first_flip(inertia, omega0)` for a torque-free body in principal axes.
    `omega0 (..., 3)`: a batch gives a per-body event (its leading dimensions are the
    batch's)."""
    w = jnp.asarray(omega0)
    if w.ndim == 0 or w.shape[-1] != 3:
        raise ValueError(f"flip_event needs omega0 (..., 3), got shape {w.shape}")
    d = jnp.argmax(jnp.abs(w), axis=-1)
    axis = (jnp.arange(3) == d[..., None]).astype(
        w.dtype if jnp.issubdtype(w.dtype, jnp.floating) else float
    )
    return Event(_DominantComponent(axis), terminate, direction, per_body=w.ndim > 1)


class _Settling(eqx.Module):
    """`max(θ_e − tolerance, after − t)`, `θ_e` the angle of `q_target⁻¹ ∘ q`."""

    target: Array
    tolerance: Array
    after: Array

    def __call__(self, t, omega, q):
        del omega
        dtype = q.dtype
        qe = _quat_core.mul(_quat_core.conj(self.target.astype(dtype)), q)
        error = _quat_core._angle(qe) - self.tolerance.astype(dtype)
        return jnp.maximum(error, self.after.astype(dtype) - t)


def settling_event(
    q_target: RealLike, tolerance: RealLike, after: RealLike = -np.inf, *, terminate: bool = True
) -> Event:
    """The attitude's entry into the pointing tolerance after the time `after`: the first time
    `t > after` at which the pointing error `θ_e(t)` (the rotation angle of `q_target⁻¹ ∘ q`,
    `observables.pointing_error`) falls to `tolerance` (radians), as the event of the
    condition `max(θ_e − tolerance, after − t)` falling through zero. With `after` the last
    sample outside the tolerance (where `observables.settling_time` places the settling on the
    sample grid), `event_t` is the settling time itself, to the solver's tolerance.
    `q_target (4,)` and `tolerance` are shared; `after (...)` may carry the batch (a per-body
    event). A sample `after` outside the tolerance makes the condition continuous there."""
    q_target, tolerance = jnp.asarray(q_target), jnp.asarray(tolerance)
    if q_target.shape != (4,) or tolerance.shape != ():
        raise ValueError(
            "settling_event takes one target attitude q_target (4,) (a unit quaternion) and a "
            f"scalar tolerance (radians), got shapes {q_target.shape} and {tolerance.shape}"
        )
    q_target = _quat_core._unit(q_target, "q_target")  # (a zero or non-finite one: an error)
    tolerance = check_nonnegative(tolerance, "tolerance", "radians")
    after = jnp.asarray(after)
    dtype = after.dtype if jnp.issubdtype(after.dtype, jnp.floating) else float
    batch = after.shape  # (a per-body event: every leaf leads with the batch)
    target = jnp.broadcast_to(q_target.astype(dtype), (*batch, 4))
    tol = jnp.broadcast_to(tolerance.astype(dtype), batch)
    condition = _Settling(target, tol, after.astype(dtype))
    return Event(condition, terminate, -1, per_body=after.ndim > 0)
