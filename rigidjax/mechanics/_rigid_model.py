"""The rigid body with its body-frame attitude quaternion and a torque, as a `Model`: the state
`y = (Ω1, Ω2, Ω3, q0, q1, q2, q3)`; in principal axes the parameters
`p = (c1, c2, c3, J1, J2, J3)`, `c1 = (I2 − I3)/I1` (cyclic), `J_i = 1/I_i`; with a full
inertia tensor (as CAD gives it) `p = (I (9), I⁻¹ (9))`, row by row."""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..models import Model
from ..rotations import quat
from ._free_field import free_field, quat_rate
from .body import euler_rhs

Torque = Callable[[Array, Array, Array], Array]


@jax.jit
def moments_params(I: Array) -> Array:
    """`p (..., 6)` of the model from principal moments `I (..., 3)` (one compiled program)."""
    I1, I2, I3 = (I[..., i] for i in range(3))
    return jnp.stack([(I2 - I3) / I1, (I3 - I1) / I2, (I1 - I2) / I3, 1 / I1, 1 / I2, 1 / I3], -1)


def tensor_params(I: Array, I_inv: Array) -> Array:
    """`p (..., 18)` of the full-tensor model from the tensor `I (..., 3, 3)` and its inverse."""
    lead = I.shape[:-2]
    return jnp.concatenate([I.reshape(*lead, 9), I_inv.reshape(*lead, 9)], axis=-1)


def _torque_in_body(torque: Torque, frame: str, t, w, q, dtype) -> Array:
    K = torque(t, w, q)
    if frame == "space":
        K = quat.rotate(quat.conj(q), K)
    return jnp.asarray(K).astype(dtype)


def _tensor_model(torque: Torque | None, frame: str) -> Model:
    """Euler's equations `I Ω̇ + Ω × IΩ = K` with a full tensor (Zegrya–Parshin 004; `euler_rhs`)
    and `q̇ = ½ q ∘ (0, Ω)` (Borisov–Mamaev 001), `K` as in `_rigid_body_model`."""

    def field(t, y, p):
        w, q = y[:3], y[3:]
        I, I_inv = p[:9].reshape(3, 3), p[9:].reshape(3, 3)
        K = (
            jnp.zeros(3, y.dtype)
            if torque is None
            else _torque_in_body(torque, frame, t, w, q, y.dtype)
        )
        dq = quat_rate(tuple(w), tuple(q))
        return jnp.concatenate([euler_rhs(I, I_inv, w, K), jnp.stack(dq)])

    return Model(field, 7, 18, ((3, 4),), "torque" if torque is not None else "free body")


def _rigid_body_model(torque: Torque | None, frame: str) -> Model:
    """Euler's equations in principal axes `Ω̇1 = c1 Ω2 Ω3 + J1 K1` (cyclic; Zegrya–Parshin
    004) with `q̇ = ½ q ∘ (0, Ω)` (Borisov–Mamaev 001), `K = torque(t, Ω, q)` in the body frame
    (or in space, `frame="space"`, turned into the body frame by `q`)."""

    def field(t, y, p):
        w, q = y[:3], y[3:]
        dw, dq = free_field(tuple(p[:3]), tuple(w), tuple(q))
        if torque is not None:
            K = _torque_in_body(torque, frame, t, w, q, y.dtype)
            dw = tuple(d + p[3 + i] * K[i] for i, d in enumerate(dw))
        return jnp.stack([*dw, *dq])

    return Model(field, 7, 6, ((3, 4),), "torque" if torque is not None else "free body")


def rigid_body_model(torque: Torque | None, frame: str = "body", tensor: bool = False) -> Model:
    """The model of `_rigid_body_model` (of `_tensor_model` with `tensor`), one per hashable
    torque, frame and kind (so that the field is traced once per torque, as `jax.jit` traces a
    function once: `kernels.model.hoist`)."""
    try:
        return _cached_model(torque, frame, tensor)
    except TypeError:  # an unhashable torque
        return _model(torque, frame, tensor)


def _model(torque: Torque | None, frame: str, tensor: bool) -> Model:
    return (_tensor_model if tensor else _rigid_body_model)(torque, frame)


_cached_model = functools.lru_cache(maxsize=64)(_model)
