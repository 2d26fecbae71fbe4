"""The free rigid body with its attitude quaternion, fixed-step RK4, as one CPU kernel
(`free_body_rk4.cc`): the fast path of `simulate(..., solver=RK4(),
stepsize_controller=diffrax.ConstantStepSize(), dt0=...)` for torque-free bodies in principal
axes. Same steps and arithmetic as the Diffrax path (one interval of `n` equal steps per output
interval, the quaternion renormalised after each step)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ._build import load

_NAME = "free_body_rk4"
_TARGETS = {"float64": "RigidjaxFreeBodyRK4F64", "float32": "RigidjaxFreeBodyRK4F32"}
_BACK = {"float64": "RigidjaxFreeBodyRK4BackF64", "float32": "RigidjaxFreeBodyRK4BackF32"}


def available(dtype) -> bool:
    """Whether the kernel serves `dtype` on the default backend: the CPU, float32 or float64,
    and the kernel built here (the first call builds it: a few seconds, once per machine)."""
    return (
        jax.default_backend() == "cpu"
        and jnp.dtype(dtype).name in _TARGETS
        and load(_NAME, (*_TARGETS.values(), *_BACK.values())) is not None
    )


def steps(
    ts: Float[Array, " T"], dt0: Float[Array, ""], max_steps: int
) -> tuple[Int[Array, " T-1"], Float[Array, " T-1"], Int[Array, " T-1"]]:
    """Per output interval: the fewest equal steps `n` of at most `dt0` (to a relative 1e-6, so
    that rounding in `ts` never adds a step; as `solve_saved`), their size `h`, and the steps
    taken `min(n, max_steps)` (an interval that needs more stops where Diffrax stops)."""
    width = ts[1:] - ts[:-1]
    n = jnp.maximum(jnp.ceil(width / dt0 * (1 - 1e-6)), 1)
    return n.astype(jnp.int32), width / n, jnp.minimum(n, max_steps).astype(jnp.int32)


def free_body_rk4(
    y0: Float[Array, "7 B"],
    coef: Float[Array, "3 B"],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
) -> Float[Array, "K+1 7 B"]:
    """The states `(Ω1, Ω2, Ω3, q0, q1, q2, q3)` of B bodies after each of K intervals of `n[k]`
    RK4 steps of size `h[k]` (`ys[0] = y0`); `coef` = `(c1, c2, c3)`, `c1 = (I2 − I3)/I1`
    (cyclic). Under `jax.vmap` the mapped bodies join one kernel call. No derivatives of its
    own: `free_body_rk4_back` gives them, and the caller joins the two (`jax.custom_vjp`)."""
    dtype = y0.dtype
    K, B = h.shape[0], y0.shape[1]
    call = jax.ffi.ffi_call(
        _TARGETS[jnp.dtype(dtype).name],
        jax.ShapeDtypeStruct((1, K + 1, 7, B), dtype),
        vmap_method="broadcast_all",
    )
    ys = call(y0[None], coef.astype(dtype)[None], n.astype(jnp.int32)[None], h.astype(dtype)[None])
    return ys[0]


def free_body_rk4_back(
    ys: Float[Array, "T 7 B"],
    coef: Float[Array, "3 B"],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
    g: Float[Array, "T 7 B"],
) -> tuple[Float[Array, "7 B"], Float[Array, "3 B"], Float[Array, "K B"]]:
    """Reverse mode of `free_body_rk4`: from the cotangents `g` of its states `ys`, those of
    `y0`, `coef` and (per body) `h`. The discrete adjoint of the same RK4 steps with
    renormalisation, each output interval reversed from its saved start state with its steps
    recomputed (in checkpointed segments of about √n steps when n > 512)."""
    dtype = ys.dtype
    K, B = h.shape[0], ys.shape[2]
    call = jax.ffi.ffi_call(
        _BACK[jnp.dtype(dtype).name],
        (
            jax.ShapeDtypeStruct((1, 7, B), dtype),
            jax.ShapeDtypeStruct((1, 3, B), dtype),
            jax.ShapeDtypeStruct((1, K, B), dtype),
        ),
        vmap_method="broadcast_all",
    )
    y0b, coefb, hb = call(
        ys[None],
        coef.astype(dtype)[None],
        n.astype(jnp.int32)[None],
        h.astype(dtype)[None],
        g.astype(dtype)[None],
    )
    return y0b[0], coefb[0], hb[0]
