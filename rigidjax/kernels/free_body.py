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


def _call(targets: dict[str, str], dtype, shapes: list[tuple[int, ...]], *args: Array) -> list:
    """The kernel `targets[dtype]` on `args` (floats cast to `dtype`, step counts to int32),
    with outputs of `shapes`. The kernel takes leading batch dimensions (`jax.vmap`
    broadcasts every argument): one is added here and removed from the outputs."""
    call = jax.ffi.ffi_call(
        targets[jnp.dtype(dtype).name],
        [jax.ShapeDtypeStruct((1, *shape), dtype) for shape in shapes],
        vmap_method="broadcast_all",
    )
    cast = [a.astype(jnp.int32 if jnp.issubdtype(a.dtype, jnp.integer) else dtype) for a in args]
    return [out[0] for out in call(*(a[None] for a in cast))]


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
    K, B = h.shape[0], w0.shape[0]
    w, q = _call(_TARGETS, w0.dtype, [(B, K + 1, 3), (B, K + 1, 4)], w0, q0, coef, n, h)
    return w, q


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
    K, B = h.shape[0], w.shape[0]
    shapes = [(B, 3), (B, 4), (3, B), (K, B)]
    w0b, q0b, coefb, hb = _call(_BACK, w.dtype, shapes, w, q, coef, n, h, gw, gq)
    return w0b, q0b, coefb, hb
