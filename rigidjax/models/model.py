"""A model: one body's ODE `ẏ = f(t, y, p)` on a flat state, written once in JAX and run by
every backend (`rigidjax.models.solve`)."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
from jaxtyping import Array

Field = Callable[[Array, Array, Array], Array]


class Model(eqx.Module):
    """One body's vector field `field(t, y (size,), p (params,)) -> ẏ (size,)`, with the state's
    unit-norm groups `unit` (`(start, length)`: a quaternion, renormalised after every step) and
    `name` for messages. The parameters `p` are per body (moments, masses); constants the field
    closes over (torque gains) are the field's own and reach `jax.grad` as well."""

    field: Field = eqx.field(static=True)
    size: int = eqx.field(static=True)
    params: int = eqx.field(static=True)
    unit: tuple[tuple[int, int], ...] = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="model")
