"""The reverse mode of the adaptive Pallas kernel (`model_pallas_adaptive`), for a model without a
jump map or an event: a second kernel of the same layout that goes interval by interval
backwards, recomputes each interval's attempts from its first state with the same controller (so
the same steps) into a scratch of `WINDOW` attempts per body, and reverses each accepted step
through `jax.vjp` of the same step, its size a constant (as Diffrax's `stop_gradient` of the
controller, and the adaptive CPU kernel's adjoint, make it)."""

from __future__ import annotations

import functools
from typing import cast

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton
from jaxtyping import Array, Float, Int

from . import adaptive, model_pallas_adaptive
from .model_pallas import (
    BLOCK,
    Spec,
    _compare,
    _joining,
    _padded,
    _parameters,
    _per_body,
    _sample,
    step,
)
from .model_pallas_adaptive import _attempts, _Controls, _finite, _start, floors
from .model_pallas_back import backwards

WINDOW = 32
"""Attempts of an interval whose steps `run_back` reverses at once (kept in a scratch of WINDOW
states per body); an interval of more is reversed window by window, each recomputed from the
interval's start."""


def run_back(
    spec: Spec,
    ys: Float[Array, "B T N"],
    hk: Float[Array, "B K"],
    nk: Int[Array, "B K"],
    g: Float[Array, "B T N"],
    p: Float[Array, "P Bc"],
    ts: Float[Array, " T"],
    ctl: Float[np.ndarray, " 14"] | Float[Array, " 14"],
    *,
    interpret: bool = False,
) -> tuple[Float[Array, "B N"], Float[Array, "P B"]]:
    """The reverse mode of `run` (a model without a jump map or an event): from its states at
    every output time `ys`, each interval's first step size `hk` and attempts `nk` (`run(...,
    adjoint=True)`) and the cotangents `g` of the states, the cotangents of `y0 (B, N)` and of
    the parameters and lifted constants `(P + Pc, B)`, per body: interval by interval
    backwards, the interval's attempts recomputed from its first state (the same controller,
    so the same steps) into a scratch of `WINDOW` per body, and each accepted step reversed
    through `jax.vjp` of the same step (the step sizes constants, as Diffrax's
    `stop_gradient` of the controller and the CPU kernel's adjoint make them). Under
    `jax.vmap` the mapped bodies join one call."""
    call = functools.partial(_back_blocks, spec, interpret=interpret)
    args = (ts, floors(ts), jnp.asarray(ctl, ts.dtype))
    return cast(tuple, _joining(call, states=4, out_body_axes=(0, -1))(ys, hk, nk, g, p, *args))


def _back_blocks(spec: Spec, *arrays: Array, interpret: bool) -> tuple[Array, Array]:
    """`run_back` of one batch (`arrays`: its `ys, hk, nk, g, p, ts, floors, ctl`): the
    `pallas_call` over its blocks, with a scratch of `WINDOW` attempts per body."""
    ys, hk, nk, g, p, ts, fl, ctl = arrays
    B, T, N = g.shape
    dtype, P = g.dtype, p.shape[0]
    Bp = -(-B // BLOCK) * BLOCK
    pp = _parameters(p, B, Bp, dtype)
    R = pp.shape[0]
    y0b, pb, _ = pl.pallas_call(
        _back_kernel(spec, T - 1, N, P, P - spec.hoisted.p),
        out_shape=(
            jax.ShapeDtypeStruct((N, Bp), dtype),
            jax.ShapeDtypeStruct((R, Bp), dtype),
            jax.ShapeDtypeStruct((WINDOW, N + 3, Bp), dtype),
        ),
        grid=(Bp // BLOCK,),
        in_specs=[
            pl.BlockSpec((T,), lambda i: (0,)),
            pl.BlockSpec((T - 1,), lambda i: (0,)),
            pl.BlockSpec(ctl.shape, lambda i: (0,)),
            _per_body((T, N)),
            _per_body((T - 1,)),
            _per_body((T - 1,)),
            _per_body((T, N)),
            _per_body((R,)),
        ],
        out_specs=(_per_body((N,)), _per_body((R,)), _per_body((WINDOW, N + 3))),
        compiler_params=pltriton.CompilerParams(num_warps=BLOCK // 32, num_stages=1),
        interpret=interpret,
    )(ts.astype(dtype), fl.astype(dtype), ctl.astype(dtype), _padded(ys.astype(dtype), Bp),
      _padded(hk.astype(dtype), Bp), _padded(nk.astype(jnp.int32), Bp),
      _padded(g.astype(dtype), Bp), pp)  # fmt: skip
    return y0b[:, :B].T, pb[:P, :B]


def _back_kernel(spec: Spec, K: int, N: int, P: int, Pc: int):
    """The reverse mode of one block (`run_back`): interval by interval backwards, window by
    window of `WINDOW` attempts from the last, the window's attempts recomputed from the
    interval's first state (those before it without keeping them), then its accepted steps
    reversed."""
    M = WINDOW

    def kernel(ts_ref, floor_ref, ctl_ref, ys_ref, hk_ref, nk_ref, g_ref, p_ref, *refs):
        y0b_ref, pb_ref, seg_ref = refs
        ctl = _Controls.read(ctl_ref)
        pc = tuple(p_ref[j] for j in range(P))
        p, c = pc[: P - Pc], pc[P - Pc :]

        def at(ref, k):
            return tuple(ref[k, j] for j in range(N))

        def interval(i, carry):
            k = K - 1 - i
            a, floor = ts_ref[k], floor_ref[k]
            y = at(ys_ref, k)
            zero, none = jnp.zeros_like(y[0]), jnp.zeros(y[0].shape, jnp.int32)
            b = jnp.where(_finite(y), ts_ref[k + 1], a)
            _, one = _attempts(spec, ctl, p, c, b, floor)
            start = _start(ctl, y, a, b, hk_ref[k], (zero, zero + jnp.inf, none != 0))
            count = jnp.max(nk_ref[k])  # the block's loop: its longest body's attempts
            windows = (count + M - 1) // M

            def window(iw, carry):
                lo = (windows - 1 - iw) * M
                hi = jnp.minimum(count, lo + M)
                s = jax.lax.fori_loop(0, lo, lambda _, s: one(s), start)

                def keep(it, s):
                    after = one(s)
                    j = it - lo
                    for x in range(N):
                        seg_ref[j, x] = s[0][x]
                    seg_ref[j, N] = s[1]
                    seg_ref[j, N + 1] = s[2] - s[1]
                    seg_ref[j, N + 2] = (after[6] - s[6]).astype(zero.dtype)  # accepted
                    return after

                jax.lax.fori_loop(lo, hi, keep, s)

                def back(i3, carry):
                    j = hi - lo - 1 - i3
                    lam, pbar = carry
                    t, size, taken = seg_ref[j, N], seg_ref[j, N + 1], seg_ref[j, N + 2] != 0

                    def stepped(y, pc):
                        return step(spec, pc[: P - Pc], pc[P - Pc :], t, size, y)

                    ybar, pcbar = jax.vjp(stepped, at(seg_ref, j), pc)[1](lam)
                    lam = tuple(jnp.where(taken, u, v) for u, v in zip(ybar, lam, strict=True))
                    pbar = tuple(
                        jnp.where(taken, u + v, u) for u, v in zip(pbar, pcbar, strict=True)
                    )
                    return lam, pbar

                return jax.lax.fori_loop(0, hi - lo, back, carry)

            lam, pbar = jax.lax.fori_loop(0, windows, window, carry)
            return tuple(u + v for u, v in zip(lam, at(g_ref, k), strict=True)), pbar

        backwards(interval, g_ref, y0b_ref, pb_ref, K, N, P)

    return kernel


def serves_back(spec: Spec) -> bool:
    """Whether the reverse-mode kernel (`run_back`) works here: checked once per model, pair
    and element type as `serves` (the compiled kernel's cotangents against the
    interpreter's), else one warning and reverse mode through Diffrax."""
    return _checked_back(spec)


@functools.cache
def _checked_back(spec: Spec) -> bool:
    """Whether the compiled forward kernel with the adjoint's residuals and the reverse-mode
    kernel agree with the interpreter's on `_checked`'s problem."""
    y, p, _ = _sample(spec)
    ts = np.array([0.0, 0.03, 0.03, 0.3], y.dtype)
    pid = diffrax.PIDController(rtol=1e-6, atol=1e-6)
    ctl = adaptive.controls(pid, spec.method(), None, 1000, spec.hoisted.dtype)
    forward = functools.partial(model_pallas_adaptive.run, spec, adjoint=True)
    if not _compare("adaptive kernel with its adjoint's residuals", spec, forward, (y, p, ts, ctl)):
        return False
    interpreted = jax.jit(functools.partial(forward, interpret=True))
    ys, _, _, hk, nk = (
        np.asarray(a) for a in interpreted.lower(y, p, ts, ctl).compile()(y, p, ts, ctl)
    )
    g = np.random.default_rng(1).normal(size=ys.shape).astype(ys.dtype)
    back = functools.partial(run_back, spec)
    return _compare("adaptive reverse-mode kernel", spec, back, (ys, hk, nk, g, p, ts, ctl))
