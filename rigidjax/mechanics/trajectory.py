"""The trajectory of a rigid body: what `simulate` returns."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from .._trajectory import AbstractTrajectory
from ..rotations import quat

__all__ = ["Trajectory"]


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
