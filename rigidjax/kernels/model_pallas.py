"""Any model's ODE `ẏ = f(t, y, p)` at fixed steps of an explicit Runge–Kutta method, as one
Pallas kernel that fuses the whole time loop: the GPU counterpart of the CPU model kernel
(`model.cc`), in the style of DiffEqGPU's kernel ensembles. Each program takes a block of
`BLOCK` bodies (one per GPU thread) and keeps their N state components in registers over all
steps; only the states at the output times go to memory. XLA's own loop (the Diffrax path)
instead reads and writes the whole batch state several times a step.

The field is the model's own scalar program (`Hoisted.components`, the Diffrax path's field)
evaluated on `(BLOCK,)` register vectors, so a torque written in JAX runs inside the kernel.
Same steps and arithmetic as the CPU kernel and the Diffrax path (`ExplicitRK(method)`):
`n[k]` equal steps of size `h[k]` from `t0[k]` per output interval, stage `i` at
`t0 + s h + c_i h`, each unit group divided by its norm after each step:

    z_i = y + h Σ_{l<i} a_il k_l,  k_i = f(t + c_i h, z_i, p),  u = y + h Σ_l b_l k_l
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

from ..solvers import _stages
from .model import Hoisted
from .tableau import DTYPES, METHODS

BLOCK = 128
"""Bodies per program: one per thread of a 4-warp GPU program."""

Unit = tuple[tuple[int, int], ...]


def step(fn, tab: diffrax.ButcherTableau, unit: Unit, p, c, t, h, y: tuple) -> tuple:
    """One step of the tableau `tab` from `y` at time `t` (`ExplicitRK`'s stages; a stage that
    never reaches the solution, first-same-as-last, is left to the compiler to drop), each unit
    group renormalised: `q ← u_q · (1 / sqrt(u_q · u_q))`, as in the C++ kernel (in float64 on
    NVIDIA GPUs, IEEE `sqrt.rn` and `div.rn`; `rsqrt` would lower to the approximate
    `rsqrt.approx.f64`)."""

    def field(ts, inc):
        z = y if inc is None else tuple(a + b for a, b in zip(y, inc, strict=True))
        return fn(ts, z, p, c)

    ks = _stages.stages(tab, t, h, field)
    u = [a + b for a, b in zip(y, _stages.increment(h, tab.b_sol, ks), strict=True)]
    for a, m in unit:
        r = 1 / jnp.sqrt(sum(u[j] * u[j] for j in range(a, a + m)))
        for j in range(a, a + m):
            u[j] = u[j] * r
    return tuple(u)


def _kernel(fn, tab: diffrax.ButcherTableau, unit: Unit, K: int, N: int, P: int, Pc: int):
    """The kernel of one block: `K` intervals of `n[k]` steps of size `h[k]` from `t0[k]`, the
    state written at their ends."""

    def kernel(n_ref, h_ref, t0_ref, x0_ref, p_ref, out_ref):
        p = tuple(p_ref[j] for j in range(P))
        c = tuple(p_ref[P + j] for j in range(Pc))
        y = tuple(x0_ref[j] for j in range(N))
        for j in range(N):
            out_ref[0, j] = y[j]

        def interval(k, y):
            h, t0 = h_ref[k], t0_ref[k]

            def one(s, y):
                return step(fn, tab, unit, p, c, t0 + s.astype(h.dtype) * h, h, y)

            y = jax.lax.fori_loop(0, n_ref[k], one, y)
            for j in range(N):
                out_ref[k + 1, j] = y[j]
            return y

        jax.lax.fori_loop(0, K, interval, y)

    return kernel


def run(
    hoisted: Hoisted,
    unit: Unit,
    method: type[diffrax.AbstractERK],
    y0: Float[Array, "B N"],
    p: Float[Array, "P Bc"],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
    t0: Float[Array, " K"],
    *,
    interpret: bool = False,
) -> Float[Array, "B T N"]:
    """States `(B, K + 1, N)` of B bodies at the start and after each of K intervals of `n[k]`
    steps of `method` (a type in `tableau.METHODS`) of size `h[k]` from `t0[k]`; `p (P + Pc, B
    or 1)` holds the parameters and the lifted constants, as `model.run` takes them.
    `interpret=True` runs the kernel in Pallas' interpreter (any backend: the CPU tests). The
    batch is padded to whole blocks with copies of the first body. Under `jax.vmap` over the
    bodies (a sweep of one-body solves), the mapped bodies join one kernel call."""
    call = functools.partial(_blocks, hoisted, unit, method, interpret=interpret)
    batched = jax.custom_batching.custom_vmap(call)

    @batched.def_vmap
    def _(size: int, mapped: list[bool], y0, p, n, h, t0):
        if any(mapped[2:]):  # steps of their own per member: one kernel call each
            axes = tuple(0 if m else None for m in mapped)
            return jax.vmap(call, in_axes=axes)(y0, p, n, h, t0), True
        y = y0 if mapped[0] else jnp.broadcast_to(y0, (size, *y0.shape))
        V, B, N = y.shape
        pv = p if mapped[1] else jnp.broadcast_to(p, (size, *p.shape))
        pv = jnp.moveaxis(jnp.broadcast_to(pv, (V, p.shape[-2], B)), 0, 1)
        out = batched(y.reshape(V * B, N), pv.reshape(-1, V * B), n, h, t0)
        return out.reshape(V, B, *out.shape[1:]), True

    return batched(y0, p, n, h, t0)


def _blocks(
    hoisted: Hoisted, unit: Unit, method: type[diffrax.AbstractERK], *arrays: Array, interpret: bool
) -> Float[Array, "B T N"]:
    """`run` of one batch (`arrays`: its `y0, p, n, h, t0`): the `pallas_call` over its
    blocks."""
    y0, p, n, h, t0 = arrays
    B, N, K, dtype = y0.shape[0], y0.shape[1], h.shape[0], y0.dtype
    P = hoisted.p
    Bp = -(-B // BLOCK) * BLOCK
    x0 = jnp.concatenate([y0, jnp.broadcast_to(y0[:1], (Bp - B, N))]).T  # (N, Bp)
    pp = jnp.broadcast_to(p.astype(dtype), (p.shape[0], B))
    pp = jnp.concatenate([pp, jnp.broadcast_to(pp[:, :1], (p.shape[0], Bp - B))], axis=1)
    out = pl.pallas_call(
        _kernel(hoisted.components, _stages.tableau_of(method()), unit, K, N, P, p.shape[0] - P),
        out_shape=jax.ShapeDtypeStruct((K + 1, N, Bp), dtype),
        grid=(Bp // BLOCK,),
        in_specs=[
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((N, BLOCK), lambda i: (0, i)),
            pl.BlockSpec((p.shape[0], BLOCK), lambda i: (0, i)),
        ],
        out_specs=pl.BlockSpec((K + 1, N, BLOCK), lambda i: (0, 0, i)),
        # Triton, one body per thread (Pallas' default on NVIDIA GPUs is Mosaic GPU)
        compiler_params=pltriton.CompilerParams(num_warps=BLOCK // 32, num_stages=1),
        interpret=interpret,
    )(n.astype(jnp.int32), h.astype(dtype), t0.astype(dtype), x0, pp)
    return jnp.moveaxis(out[:, :, :B], 2, 0)  # (B, T, N)


def serves(hoisted: Hoisted, unit: Unit, solver: diffrax.AbstractSolver) -> bool:
    """Whether the kernel integrates `hoisted` with `solver` (one of `tableau.METHODS`) on the
    default backend: a GPU, float32 or float64, and the kernel checked there (once per model,
    method and element type: a small batch compiled must give the interpreter's states, else
    one warning and the Diffrax path)."""
    return (
        type(solver) in METHODS
        and jax.default_backend() == "gpu"
        and hoisted.dtype.name in DTYPES
        and _checked(_Key(hoisted, unit), type(solver))
    )


class _Key:
    """A model as `_checked` caches it: by its jaxpr's text, sizes and unit groups (the
    lowering depends on nothing else; the constants' values are the check's random ones)."""

    def __init__(self, hoisted: Hoisted, unit: Unit):
        self.hoisted, self.unit = hoisted, unit
        self.text = (str(hoisted.forward), hoisted.n, hoisted.p, hoisted.c.shape, unit)
        self.text += (hoisted.dtype.name,)

    def __hash__(self) -> int:
        return hash(self.text)

    def __eq__(self, other) -> bool:
        return isinstance(other, _Key) and other.text == self.text


@functools.cache
def _checked(key: _Key, method: type[diffrax.AbstractERK]) -> bool:
    """Whether the compiled kernel runs here and agrees with Pallas' interpreter on two blocks
    of bodies over three intervals (random states, unit groups normalised, parameters in
    [1, 2]; relative 1e-4 in float32, 1e-10 in float64)."""
    hoisted, dtype = key.hoisted, key.hoisted.dtype
    rng = np.random.default_rng(0)
    B = BLOCK + 3
    y = rng.normal(size=(B, hoisted.n))
    for a, m in key.unit:
        y[:, a : a + m] /= np.linalg.norm(y[:, a : a + m], axis=1, keepdims=True)
    p = rng.uniform(1, 2, size=(hoisted.p + hoisted.c.shape[0], B))
    n, h = np.array([3, 0, 5], np.int32), np.array([0.01, 0.02, 0.005])
    args = tuple(a.astype(dtype) for a in (y, p, h, np.array([0.0, 0.03, 0.03])))
    args = (*args[:2], n, *args[2:])
    try:
        # compiled ahead and called: run at once, also where `simulate` is being traced
        got, want = (
            np.asarray(
                jax.jit(functools.partial(run, hoisted, key.unit, method, interpret=i))
                .lower(*args)
                .compile()(*args)
            )
            for i in (False, True)
        )
        tol = 1e-4 if dtype.name == "float32" else 1e-10
        if not np.allclose(got, want, rtol=tol, atol=tol, equal_nan=True):
            raise ValueError("its states differ from Pallas' interpreter's")
    except Exception as e:  # a lowering or compile failure, or wrong numbers: not served
        warnings.warn(
            f"rigidjax's Pallas kernel for {method.__name__} in {dtype.name} does not work on "
            f"this GPU ({type(e).__name__}: {e}); the same integration runs through Diffrax and "
            "XLA instead.",
            RuntimeWarning,
            stacklevel=2,
        )
        return False
    return True
