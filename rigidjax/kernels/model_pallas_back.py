"""The reverse mode of the Pallas kernel (`model_pallas`): a second kernel of the same layout that
goes interval by interval backwards, recomputes the states from checkpoints √n steps apart
(written by the forward kernel of a differentiated solve, or recomputed here) and reverses
each step through `jax.vjp` of the same step (the discrete adjoint of the forward kernel's
arithmetic)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton
from jaxtyping import Array, Float

from . import model_pallas
from .model_pallas import (
    BLOCK,
    Spec,
    Steps,
    _compare,
    _joining,
    _padded,
    _parameters,
    _sample,
    checkpoints,
    step,
)


def run_back(
    spec: Spec,
    src: Float[Array, "B K C N"] | Float[Array, "B T N"],
    g: Float[Array, "B T N"],
    p: Float[Array, "P Bc"],
    steps: Steps,
    *,
    longest: int,
    interpret: bool = False,
) -> tuple[Float[Array, "B N"], Float[Array, "P B"]]:
    """The reverse mode of `run`: from `src`, the checkpoints of its forward run (`run(...,
    longest=longest)`, `(B, K, C, N)`) or its states `(B, K + 1, N)` (then each interval's
    checkpoints are recomputed first, into C slots of scratch), and the cotangents `g (B, K + 1,
    N)` of its states, the cotangents of `y0 (B, N)` and of the parameters and lifted constants
    `(P + Pc, B)`, per body (the steps' sizes and start times get none: their cotangents go
    through Diffrax). Under `jax.vmap` the mapped bodies join one call."""
    call = functools.partial(_back_blocks, spec, *checkpoints(longest), interpret=interpret)
    return _joining(call, states=2, out_body_axes=(0, -1))(src, g, p, *steps)


def stores_checkpoints(n: np.ndarray, longest: int) -> bool:
    """Whether a differentiated solve of the step counts `n (K,)` (known) lets its forward run
    write the checkpoints: the K × C slots waste at most half (intervals of like lengths);
    otherwise `run_back` recomputes them from the states, interval by interval."""
    L, C = checkpoints(longest)
    used = int(np.sum(-(-np.asarray(n) // L)))
    return n.shape[0] * C <= 2 * max(used, n.shape[0])


def _back_blocks(
    spec: Spec, L: int, C: int, *arrays: Array, interpret: bool
) -> tuple[Array, Array]:
    """`run_back` of one batch (`arrays`: its `src, g, p, n, h, t0`): the `pallas_call` over its
    blocks, with L states of scratch per body (and C where the checkpoints are recomputed)."""
    src, g, p, n, h, t0 = arrays
    B, T, N = g.shape
    K, dtype, P = T - 1, g.dtype, p.shape[0]
    stored = src.ndim == 4
    Bp = -(-B // BLOCK) * BLOCK

    pp = _parameters(p, B, Bp, dtype)
    R = pp.shape[0]
    kernel = _back_kernel(spec, K, N, P, P - spec.hoisted.p, L, stored)
    scratch = [(L, N)] if stored else [(L, N), (C, N)]  # a segment's states, the checkpoints
    src_spec = (
        pl.BlockSpec((K, src.shape[2], N, BLOCK), lambda i: (0, 0, 0, i))
        if stored
        else pl.BlockSpec((T, N, BLOCK), lambda i: (0, 0, i))
    )
    y0b, pb, *_ = pl.pallas_call(
        kernel,
        out_shape=(
            jax.ShapeDtypeStruct((N, Bp), dtype),
            jax.ShapeDtypeStruct((R, Bp), dtype),
            *(jax.ShapeDtypeStruct((*shape, Bp), dtype) for shape in scratch),
        ),
        grid=(Bp // BLOCK,),
        in_specs=[
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            src_spec,
            pl.BlockSpec((T, N, BLOCK), lambda i: (0, 0, i)),
            pl.BlockSpec((R, BLOCK), lambda i: (0, i)),
        ],
        out_specs=(
            pl.BlockSpec((N, BLOCK), lambda i: (0, i)),
            pl.BlockSpec((R, BLOCK), lambda i: (0, i)),
            *(pl.BlockSpec((*shape, BLOCK), lambda i: (0, 0, i)) for shape in scratch),
        ),
        compiler_params=pltriton.CompilerParams(num_warps=BLOCK // 32, num_stages=1),
        interpret=interpret,
    )(n.astype(jnp.int32), h.astype(dtype), t0.astype(dtype), _padded(src.astype(dtype), Bp),
      _padded(g.astype(dtype), Bp), pp)  # fmt: skip
    return y0b[:, :B].T, pb[:P, :B]


def _back_kernel(spec: Spec, K: int, N: int, P: int, Pc: int, L: int, stored: bool):
    """The reverse mode of one block: from the forward run's checkpoints (`stored`: each
    interval's states every L steps) or its states at the K + 1 output times (`src_ref`), and
    the cotangents `g` there, the cotangents of the initial states and of the P parameters (the
    lifted constants included). Interval by interval backwards (from the interval's first
    state, its checkpoints recomputed into `ck` unless `stored`) and segment by segment, the
    segment's L states are recomputed from its checkpoint into `seg` (`checkpoints`) and its
    steps reversed through `jax.vjp` of the same step (the discrete adjoint of the forward
    kernel's arithmetic)."""

    def kernel(n_ref, h_ref, t0_ref, src_ref, g_ref, p_ref, y0b_ref, pb_ref, seg_ref, *ck_ref):
        pc = tuple(p_ref[j] for j in range(P))
        dtype = g_ref.dtype

        def at(ref, *i):
            return tuple(ref[(*i, j)] for j in range(N))

        def put(ref, i, y):
            for j in range(N):
                ref[i, j] = y[j]

        def interval(i, carry):
            k = K - 1 - i
            h, t0, n = h_ref[k], t0_ref[k], n_ref[k]
            segments = (n + L - 1) // L

            def stepped(s, y, pc):  # step s of the interval (the parameters and constants pc)
                t = t0 + s.astype(dtype) * h
                return step(spec, pc[: P - Pc], pc[P - Pc :], t, h, y)

            def advance(first, count, y, keep=None):
                def one(m, y):
                    if keep is not None:
                        put(keep, m, y)
                    return stepped(first + m, y, pc)

                return jax.lax.fori_loop(0, count, one, y)

            def checkpoint(s, y):
                put(ck_ref[0], s, y)
                return advance(s * L, jnp.minimum(L, n - s * L), y)

            if not stored:
                jax.lax.fori_loop(0, segments, checkpoint, at(src_ref, k))

            def segment(i2, carry):
                s = segments - 1 - i2
                first, count = s * L, jnp.minimum(L, n - s * L)
                start = at(src_ref, k, s) if stored else at(ck_ref[0], s)
                advance(first, count, start, keep=seg_ref)

                def back(i3, carry):
                    m = count - 1 - i3
                    lam, pbar = carry
                    one = functools.partial(stepped, first + m)
                    ybar, pcbar = jax.vjp(one, at(seg_ref, m), pc)[1](lam)
                    return ybar, tuple(a + b for a, b in zip(pbar, pcbar, strict=True))

                return jax.lax.fori_loop(0, count, back, carry)

            lam, pbar = jax.lax.fori_loop(0, segments, segment, carry)
            return tuple(a + b for a, b in zip(lam, at(g_ref, k), strict=True)), pbar

        backwards(interval, g_ref, y0b_ref, pb_ref, K, N, P)

    return kernel


def backwards(interval, g_ref, y0b_ref, pb_ref, K: int, N: int, P: int) -> None:
    """A reverse kernel's sweep: `interval(i, (λ, p̄))` for the intervals K − 1, …, 0 from the
    cotangent of the last state, then the cotangents of the initial state and of the P
    parameters written (both reverse kernels')."""
    zero = jnp.zeros_like(g_ref[0, 0])
    init = (tuple(g_ref[K, j] for j in range(N)), tuple(zero for _ in range(P)))
    lam, pbar = jax.lax.fori_loop(0, K, interval, init)
    for j in range(N):
        y0b_ref[j] = lam[j]
    for j in range(P):
        pb_ref[j] = pbar[j]


def serves_back(spec: Spec) -> bool:
    """Whether the reverse-mode kernel (`run_back`) works here: checked once per model, method
    and element type as `serves` (the compiled kernel's cotangents against the interpreter's),
    else one warning and reverse mode through Diffrax."""
    return _checked_back(spec)


@functools.cache
def _checked_back(spec: Spec) -> bool:
    """Whether the compiled reverse-mode kernels (from stored and from recomputed checkpoints)
    and the forward kernel that writes the checkpoints agree with the interpreter's on
    `_sample`."""
    y, p, steps = args = _sample(spec)
    forward = functools.partial(model_pallas.run, spec, longest=5)
    if not _compare("kernel with checkpoints", spec, forward, args):
        return False
    interpreted = jax.jit(functools.partial(forward, interpret=True))
    ys, ck = (np.asarray(a) for a in interpreted.lower(*args).compile()(*args))  # now
    g = np.random.default_rng(1).normal(size=ys.shape).astype(ys.dtype)
    fn = functools.partial(run_back, spec, longest=5)
    return all(_compare("reverse-mode kernel", spec, fn, (src, g, p, steps)) for src in (ck, ys))
