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
    w0: Float[Array, "B 3"],
    q0: Float[Array, "B 4"],
    coef: Float[Array, "3 Bc"],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
) -> tuple[Float[Array, "B T 3"], Float[Array, "B T 4"]]:
    """Body angular velocities and quaternions `(B, K + 1, ·)` of B bodies at the start and
    after each of K intervals of `n[k]` RK4 steps of size `h[k]`, the quaternion renormalised
    after each step; `coef = (c1, c2, c3)`, `c1 = (I2 − I3)/I1` (cyclic), per body `(3, B)` or
    shared `(3, 1)`. Under `jax.vmap` the mapped bodies join one kernel call. No derivatives of
    its own: `free_body_rk4_back` gives them, and the caller joins the two (`jax.custom_vjp`)."""
    dtype = w0.dtype
    K, B = h.shape[0], w0.shape[0]
    call = jax.ffi.ffi_call(
        _TARGETS[jnp.dtype(dtype).name],
        (
            jax.ShapeDtypeStruct((1, B, K + 1, 3), dtype),
            jax.ShapeDtypeStruct((1, B, K + 1, 4), dtype),
        ),
        vmap_method="broadcast_all",
    )
    w, q = call(
        w0[None],
        q0.astype(dtype)[None],
        coef.astype(dtype)[None],
        n.astype(jnp.int32)[None],
        h.astype(dtype)[None],
    )
    return w[0], q[0]


def free_body_rk4_back(
    w: Float[Array, "B T 3"],
    q: Float[Array, "B T 4"],
    coef: Float[Array, "3 Bc"],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
    gw: Float[Array, "B T 3"],
    gq: Float[Array, "B T 4"],
) -> tuple[Float[Array, "B 3"], Float[Array, "B 4"], Float[Array, "3 B"], Float[Array, "K B"]]:
    """Reverse mode of `free_body_rk4`: from the cotangents `gw`, `gq` of its outputs `w`, `q`,
    those of `w0`, `q0`, `coef` (per body) and `h` (per body). The discrete adjoint of the same
    RK4 steps with renormalisation; each output interval is reversed from its saved start
    state, its steps recomputed (in checkpointed segments of about √n steps when n > 512)."""
    dtype = w.dtype
    K, B = h.shape[0], w.shape[0]
    call = jax.ffi.ffi_call(
        _BACK[jnp.dtype(dtype).name],
        (
            jax.ShapeDtypeStruct((1, B, 3), dtype),
            jax.ShapeDtypeStruct((1, B, 4), dtype),
            jax.ShapeDtypeStruct((1, 3, B), dtype),
            jax.ShapeDtypeStruct((1, K, B), dtype),
        ),
        vmap_method="broadcast_all",
    )
    w0b, q0b, coefb, hb = call(
        w[None],
        q[None],
        coef.astype(dtype)[None],
        n.astype(jnp.int32)[None],
        h.astype(dtype)[None],
        gw.astype(dtype)[None],
        gq.astype(dtype)[None],
    )
    return w0b[0], q0b[0], coefb[0], hb[0]
