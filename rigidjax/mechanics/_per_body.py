"""`simulate`'s per-body solves: each body its own adaptive steps and events (the one-body
solve mapped over the bodies), and how their outcomes join into the batch's."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PyTree

from .._batch import failed_body
from .._checks import is_concrete, validate
from .._integrate import IntegrationError, nonfinite_field, raise_failure
from ..events import Event
from ..kinematics.formulations import AbstractKinematics
from ..rotations import quat


def checked(event: Any, flow_solver: Any, batch: tuple[int, ...]) -> Event:
    """`event` for the flattened batch (`Event.flat`), with clear errors for what is not an
    `Event` and for a solver without an interpolant (`flow_solver`, the flow solvers')."""
    if not isinstance(event, Event):
        raise TypeError(f"event must be a rigidjax.Event(condition, ...), got {event!r}")
    if flow_solver is not None:
        raise ValueError(
            "events need a solver with an interpolant (the event is located on the step's), "
            f"not {type(flow_solver).__name__}: use a Runge–Kutta solver (the default, or "
            "ExplicitRK(method))"
        )
    return event.flat(batch)


def finite_at_start(
    event: Event, t0: Array, omega0: Array, q0: Array, batch: tuple[int, ...]
) -> Array:
    """`omega0 (B, 3)`, with a clear error where the flattened `event`'s condition is not
    finite at a body's initial state (`q0 (B, 4)`, at `t0`): a NaN condition never changes
    sign, and its `event_t` would be `inf` unmarked (a run-time check under `jit`). A condition
    of the wrong shape or type is left to the solve's own message."""
    # (an array even where the condition returns a Python constant: else filter_vmap would
    # hand that back unbatched and the check would pass it over)
    values = eqx.filter_vmap(
        lambda ev, w, q: jnp.asarray(ev.condition(t0, w, q)), in_axes=(event.in_axes(), 0, 0)
    )(event, omega0, q0)
    if jnp.shape(values) != omega0.shape[:1] or not jnp.issubdtype(values.dtype, jnp.floating):
        return omega0

    def detail(v: np.ndarray) -> str:
        b = int(np.argmax(~np.isfinite(v)))
        return f" ({failed_body(batch, jnp.asarray(b)) or 'the body'}: {v[b]})"

    return validate(
        values,
        lambda xp, v: ~xp.isfinite(v),
        "the Event's condition(t, omega, q) is not finite at the initial state",
        detail,
        hint="; it would never cross zero (event_t = inf): give a condition finite there",
        on=omega0,
    )


def of_body(event: Event, b: int = 0) -> Event:
    """The event of body `b` of a flattened batch (`Event.flat`)."""
    if not event.per_body:
        return event
    dynamic, static = eqx.partition(event, eqx.is_array)
    return eqx.combine(jax.tree.map(lambda a: a[b], dynamic), static).shared()


def per_body(stats: dict[str, Array], batch: tuple[int, ...]) -> dict[str, Array]:
    """The step counts `(B,)` of per-body solves in the batch's shape (`num_valid` stays the
    batch's; a count of one body broadcast)."""

    def shaped(v):
        return jnp.broadcast_to(v, batch) if jnp.ndim(v) == 0 else jnp.reshape(v, batch)

    return {k: v if k == "num_valid" else shaped(v) for k, v in stats.items()}


def raise_batch(
    result,
    stats,
    ts,
    ys,
    max_steps: int,
    torque: Callable | None,
    batch: tuple[int, ...],
    first: Array | None = None,
) -> Array:
    """`raise_failure` for a batch (`batch`, flattened in `ys`' second axis): `IntegrationError`
    naming the interval and the body (concrete; `first`, the body that failed first of per-body
    solves, `first_failure`'s `failed_body`, else the first non-finite one), or a runtime check
    (traced); a torque that returned a non-finite value is named (probed on that body);
    returns `ys[0]`."""
    omega, q = ys

    def body(k: int) -> str | None:
        return failed_body(batch, first, omega[k])

    if torque is None:
        return raise_failure(result, stats["num_valid"], ts, omega, max_steps, None, body)
    field: Callable = torque

    def probe(k: int) -> str | None:
        b = first if first is not None else jnp.argmax(~jnp.all(jnp.isfinite(omega[k]), -1))
        ys_b = (omega[:, b], q[:, b])
        return nonfinite_field(lambda t, y: field(t, *y), ts, ys_b, k, True)

    return raise_failure(result, stats["num_valid"], ts, omega, max_steps, probe, body)


def split_components(y: Array) -> tuple[Array, Array]:
    """`(Ω, q)` of one body's component state `(Ω, q) (7,)`."""
    return y[:3], y[3:7]


class OneBodyState(eqx.Module):
    """`(Ω (3,), q (4,))` of one body's state on the Diffrax path: `(att (..., 1), Ω (3, 1))`
    batch last for the kinematics `kin` (`att` the chart's components: `(4, 1)` for a
    quaternion, `(3, 3, 1)` for a matrix, `(2, 2, 2, 1)` Cayley–Klein), `(R (1, 3, 3),
    Ω (1, 3))` for RKMK (`kin` None)."""

    kin: AbstractKinematics | None

    def __call__(self, y) -> tuple[Array, Array]:
        if self.kin is None:
            return y[1][0], quat.from_matrix(y[0][0], assume_valid=True)
        return y[1][..., 0], self.kin.to_quat(y[0][..., 0])


def raise_rerun(
    result,
    num_valid: Array,
    first: Array,
    ts: Array,
    ys: PyTree,
    max_steps: int,
    batch: tuple[int, ...],
    rerun: Callable[[int], Any],
) -> PyTree:
    """`raise_failure` for per-body solves whose causes are found by the one-body solve itself
    (a torque's, a controller's non-finite value: the gyrostat's): concrete, the failed body
    `first` is solved again alone, raising, and its error names the body; traced, a runtime
    check. Returns `ys`."""
    if is_concrete(num_valid) and result != diffrax.RESULTS.successful:
        where = failed_body(batch, first)
        try:
            rerun(int(first))
        except IntegrationError as e:  # (the same failure: the bodies' solves are independent)
            named = str(e).replace("integration failed", f"integration failed for {where}", 1)
            raise IntegrationError(named) from None
        return raise_failure(result, num_valid, ts, ys, max_steps, None, lambda k: where)
    return raise_failure(result, num_valid, ts, ys, max_steps)
