"""Sampled-data controllers with memory: flight software that keeps a state between samples (a
filter's estimate, an integrator, a PRNG key for simulated sensors), for
`simulate(gyrostat, ..., controller=c.with_key(key), control_period=...)`.

The memory is part of the solve's state, held (zero derivative) between samples and set by the
sampling jump map with the command (`rigidjax.mechanics._zoh`): the loop stays one model, and a
batch of bodies one vmapped solve, each body with its own memory and key."""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
from jaxtyping import Array, PRNGKeyArray

__all__ = ["StatefulController"]


class StatefulController(eqx.Module):
    """A controller with memory. `simulate` calls, for each body,

    - `init(key, t0, omega0, q0, params, period) -> memory` once (a PyTree of float arrays:
      it is carried in the solve's state, in its dtype; `key` the body's PRNG key from
      `controller_key`, or None), then
    - `step(t_k, omega_k, q_k, params, memory) -> (command, memory, log)` at each sample
      `t_k = t0 + k period`, with the true state `(Ω_k, q_k)` (what the controller may read of
      it is its own business: sensors simulated from it, for instance); the command is held
      until the next sample and `log (L,)` is recorded, as `GyrostatTrajectory.controller_log
      (..., K, L)`.

    `log_size` is `L` (0: nothing recorded). The bodies' keys come from `simulate`'s
    `controller_key` or else from the controller's own `key` (`with_key`)."""

    log_size: ClassVar[int] = 0
    key: Any = eqx.field(default=None, kw_only=True)  # PRNG key(s): one, or one per body

    def with_key(self, key: Any) -> StatefulController:
        """This controller with its PRNG `key`: one key (split over the bodies) or one per body
        (the batch shape of the initial state)."""
        return eqx.tree_at(lambda c: c.key, self, key, is_leaf=lambda x: x is None)

    def __call__(self, *args: Any) -> Array:
        raise TypeError(
            "a StatefulController keeps memory between samples: simulate(gyrostat, ..., "
            "controller=it) calls its init and step; call controller.step(t, omega, q, params, "
            "memory) directly"
        )

    @abc.abstractmethod
    def init(
        self,
        key: PRNGKeyArray | None,
        t0: Array,
        omega0: Array,
        q0: Array,
        params: Any,
        period: float,
    ) -> Any:
        """The memory before the first sample, for one body."""

    @abc.abstractmethod
    def step(
        self, t: Array, omega: Array, q: Array, params: Any, memory: Any
    ) -> tuple[Array, Any, Array]:
        """`(command, memory, log)` at the sample `t` for one body."""
