"""The free rigid body with its attitude quaternion at fixed steps of an explicit Runge–Kutta
method, as one Pallas kernel that fuses the whole time loop: the GPU counterpart of the CPU
model kernel (`model.cc`), in the style of DiffEqGPU's kernel ensembles. Each program takes a
block of `BLOCK` bodies (one per GPU thread) and keeps their seven state components in
registers over all steps; only the states at the output times go to memory. XLA's own loop
(the component path) instead reads and writes the whole batch state several times a step.

Same steps and arithmetic as the Diffrax path (`ExplicitRK(method)`, the component path of
`simulate`): `n[k]` equal steps of size `h[k]` per output interval, the stages unrolled by the
same code (`solvers._stages`) on the same field (`mechanics._free_field.free_field`), the
quaternion renormalised after each step:

    Euler's equations  dΩ1/dt = c1 Ω2 Ω3, c1 = (I2 − I3)/I1 (cyclic; Zegrya–Parshin 004)
    kinematics         dq/dt = ½ q ∘ (0, Ω)  (Borisov–Mamaev 001)
    one step           z_i = y + h Σ_{l<i} a_il k_l, k_i = f(z_i), u = y + h Σ_l b_l k_l
"""

from __future__ import annotations

import functools
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton
from jaxtyping import Array, Float, Int

from ..mechanics._free_field import free_field
from ..solvers import _stages
from .tableau import DTYPES, METHODS

BLOCK = 128
"""Bodies per program: one per thread of a 4-warp GPU program."""

State = tuple[Array, Array, Array, Array, Array, Array, Array]
"""Ω1, Ω2, Ω3, q0, q1, q2, q3 of a block of bodies, each `(BLOCK,)`."""


def step(tab: diffrax.ButcherTableau, c: tuple[Array, Array, Array], h: Array, y: State) -> State:
    """One step of the tableau `tab` from `y` (`ExplicitRK`'s stages; a stage that never reaches
    the solution, first-same-as-last, is left to the compiler to drop), the quaternion
    renormalised: `q ← u_q · (1 / sqrt(u_q · u_q))`, as in the C++ kernel (in float64 on NVIDIA
    GPUs, IEEE `sqrt.rn` and `div.rn`; `rsqrt` would lower to the approximate
    `rsqrt.approx.f64`)."""

    def field(_, inc):
        z = y if inc is None else tuple(a + b for a, b in zip(y, inc, strict=True))
        dw, dq = free_field(c, z[:3], z[3:])
        return dw + dq

    ks = _stages.stages(tab, 0.0, h, field)
    u = tuple(a + b for a, b in zip(y, _stages.increment(h, tab.b_sol, ks), strict=True))
    r = 1 / jnp.sqrt(u[3] * u[3] + u[4] * u[4] + u[5] * u[5] + u[6] * u[6])
    return (u[0], u[1], u[2], u[3] * r, u[4] * r, u[5] * r, u[6] * r)


def _kernel(tab: diffrax.ButcherTableau, K: int):
    """The kernel of one block: `K` intervals of `n[k]` steps of size `h[k]`, the state
    written at their ends."""

    def kernel(n_ref, h_ref, x0_ref, c_ref, out_ref):
        c = (c_ref[0], c_ref[1], c_ref[2])
        y = tuple(x0_ref[j] for j in range(7))
        for j in range(7):
            out_ref[0, j] = y[j]

        def interval(k, y):
            h = h_ref[k]
            y = jax.lax.fori_loop(0, n_ref[k], lambda _, y: step(tab, c, h, y), y)
            for j in range(7):
                out_ref[k + 1, j] = y[j]
            return y

        jax.lax.fori_loop(0, K, interval, y)

    return kernel


@functools.partial(jax.jit, static_argnames=("method", "interpret"))
def free_body_pallas(
    method: type[diffrax.AbstractERK],
    w0: Float[Array, "B 3"],
    q0: Float[Array, "B 4"],
    coef: Float[Array, "3 Bc"],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
    *,
    interpret: bool = False,
) -> tuple[Float[Array, "B T 3"], Float[Array, "B T 4"]]:
    """Body angular velocities and quaternions `(B, K + 1, ·)` of B bodies at the start and
    after each of K intervals of `n[k]` steps of `method` (a type in `free_body.METHODS`) of
    size `h[k]`, coefficients `c (3, B or 1)` (`c1 = (I2 − I3)/I1`, cyclic). `interpret=True`
    runs the kernel in Pallas' interpreter (any backend: the CPU tests). The batch is padded to
    whole blocks with resting bodies."""
    B, K, dtype = w0.shape[0], h.shape[0], w0.dtype
    Bp = -(-B // BLOCK) * BLOCK
    rest = jnp.zeros((Bp - B, 7), dtype).at[:, 3].set(1)
    x0 = jnp.concatenate([jnp.concatenate([w0, q0], axis=-1), rest]).T  # (7, Bp)
    c = jnp.pad(jnp.broadcast_to(coef.astype(dtype), (3, B)), ((0, 0), (0, Bp - B)))
    out = pl.pallas_call(
        _kernel(_stages.tableau_of(method()), K),
        out_shape=jax.ShapeDtypeStruct((K + 1, 7, Bp), dtype),
        grid=(Bp // BLOCK,),
        in_specs=[
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((7, BLOCK), lambda i: (0, i)),
            pl.BlockSpec((3, BLOCK), lambda i: (0, i)),
        ],
        out_specs=pl.BlockSpec((K + 1, 7, BLOCK), lambda i: (0, 0, i)),
        # Triton, one body per thread (Pallas' default on NVIDIA GPUs is Mosaic GPU)
        compiler_params=pltriton.CompilerParams(num_warps=BLOCK // 32, num_stages=1),
        interpret=interpret,
    )(n.astype(jnp.int32), h.astype(dtype), x0, c)
    out = jnp.moveaxis(out[:, :, :B], 2, 0)  # (B, T, 7)
    return out[..., :3], out[..., 3:]


def serves(solver: diffrax.AbstractSolver, dtype) -> bool:
    """Whether the kernel integrates `solver` (one of `free_body.METHODS`) in `dtype` on the
    default backend: a GPU, float32 or float64, and the kernel checked there (once per method
    and element type: a small batch compiled must give the interpreter's states, else one
    warning and the Diffrax path)."""
    return (
        isinstance(solver, diffrax.AbstractERK)
        and type(solver) in METHODS
        and jax.default_backend() == "gpu"
        and jnp.dtype(dtype).name in DTYPES
        and _checked(type(solver), jnp.dtype(dtype).name)
    )


@functools.cache
def _checked(method: type[diffrax.AbstractERK], dtype: str) -> bool:
    """Whether the compiled kernel runs here and agrees with Pallas' interpreter on two blocks
    of bodies over three intervals (relative 1e-4 in float32, 1e-10 in float64)."""
    rng = np.random.default_rng(0)
    B = BLOCK + 3
    w0 = jnp.asarray(rng.normal(size=(B, 3)), dtype)
    q = rng.normal(size=(B, 4))
    q0 = jnp.asarray(q / np.linalg.norm(q, axis=1, keepdims=True), dtype)
    coef = jnp.asarray(rng.normal(size=(3, B)), dtype)
    n, h = jnp.asarray([3, 0, 5], jnp.int32), jnp.asarray([0.01, 0.02, 0.005], dtype)
    try:
        got = free_body_pallas(method, w0, q0, coef, n, h)
        want = free_body_pallas(method, w0, q0, coef, n, h, interpret=True)
        tol = 1e-4 if dtype == "float32" else 1e-10
        agree = all(np.allclose(a, b, rtol=tol, atol=tol) for a, b in zip(got, want, strict=True))
        if not agree:
            raise ValueError("its states differ from Pallas' interpreter's")
    except Exception as e:  # a lowering or compile failure, or wrong numbers: not served
        warnings.warn(
            f"rigidjax's Pallas kernel for {method.__name__} in {dtype} does not work on this "
            f"GPU ({type(e).__name__}: {e}); the same integration runs through Diffrax and XLA "
            "instead.",
            RuntimeWarning,
            stacklevel=2,
        )
        return False
    return True
