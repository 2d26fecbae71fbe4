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
`t0 + s h + c_i h`, each unit group divided by its norm after each step, then the model's
step-end map, if any:

    z_i = y + h Σ_{l<i} a_il k_l,  k_i = f(t + c_i h, z_i, p),  u = y + h Σ_l b_l k_l

Its reverse mode (`model_pallas_back.run_back`) is a second kernel of the same layout: interval
by interval backwards, the states are recomputed from checkpoints √n steps apart (written by the
forward kernel of a differentiated solve) and each step is reversed through `jax.vjp` of the
same step on register vectors (the discrete adjoint).
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable
from typing import cast

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton
from jaxtyping import Array, Float, Int

from ..solvers import _stages
from .model import Hoisted, Schedule
from .tableau import DTYPES, METHODS

BLOCK = 128
"""Bodies per program: one per thread of a 4-warp GPU program."""

Unit = tuple[tuple[int, int], ...]
Steps = tuple[Int[Array, " K"], Float[Array, " K"], Float[Array, " K"]]
"""`(n, h, t0)`: `n[k]` steps of size `h[k]` from `t0[k]` in output interval k."""


class Spec:
    """What a kernel integrates: a model (`Hoisted`), its unit groups, the method (a type in
    `tableau.METHODS`), for a model with a jump map the components `(R0, NR)` that each jump
    records, and for the adaptive kernel (`model_pallas_adaptive`) whether its bodies take
    fixed steps (`fixed`: an event at fixed steps). Equal (and hashed, as the checks' caches
    key them) by the model's jaxprs' text, sizes, unit groups, element type, method, records
    and steps: the lowering depends on nothing else (the constants' values are the checks'
    random ones)."""

    def __init__(
        self,
        hoisted: Hoisted,
        unit: Unit,
        method: type[diffrax.AbstractERK],
        record: tuple[int, int] = (0, 0),
        fixed: bool = False,
    ):
        self.hoisted, self.unit, self.method, self.record = hoisted, unit, method, record
        self.fixed = fixed
        self.tab = _stages.tableau_of(method())
        end = str(hoisted.jaxpr(hoisted.end_fn)) if hoisted.ends else None
        jump = str(hoisted.jaxpr(hoisted.jump_fn)) if hoisted.jumps else None
        event = str(hoisted.jaxpr(hoisted.event_fn)) if hoisted.events else None
        self.text = (str(hoisted.forward), end, jump, event, hoisted.n, hoisted.p)
        self.text += (hoisted.c.shape, unit)
        self.text += (hoisted.dtype.name, method, record, fixed)

    def __hash__(self) -> int:
        return hash(self.text)

    def __eq__(self, other) -> bool:
        return isinstance(other, Spec) and other.text == self.text


def step(spec: Spec, p, c, t, h, y: tuple) -> tuple:
    """One step of the model and tableau of `spec` from `y` at time `t` (`ExplicitRK`'s stages,
    the field `Hoisted.components` with the parameters `p` and constants `c`; a stage that
    never reaches the solution, first-same-as-last, is left to the compiler to drop), each unit
    group renormalised: `q ← u_q · (1 / sqrt(u_q · u_q))`, as in the C++ kernel (in float64 on
    NVIDIA GPUs, IEEE `sqrt.rn` and `div.rn`; `rsqrt` would lower to the approximate
    `rsqrt.approx.f64`), then the step-end map (`Hoisted.end_components`; None: none)."""
    ks = stages(spec, p, c, t, h, y)
    u = [a + b for a, b in zip(y, _stages.increment(h, spec.tab.b_sol, ks), strict=True)]
    return step_end(spec, p, c, t + h, u)


def stages(spec: Spec, p, c, t, h, y: tuple) -> list:
    """The stage rates `k_i = f(t + c_i h, y + h Σ_{l<i} a_il k_l)` of a step from `y` at `t`
    (`_stages.stages`, every stage of the tableau of `spec`)."""
    fn = spec.hoisted.components

    def field(ts, inc):
        z = y if inc is None else tuple(a + b for a, b in zip(y, inc, strict=True))
        return fn(ts, z, p, c)

    return _stages.stages(spec.tab, t, h, field)


def step_end(spec: Spec, p, c, t, u: list) -> tuple:
    """A step's end `u` at time `t`: each unit group divided by its norm, `u_q · (1 /
    sqrt(u_q · u_q))`, then the step-end map, if any (`step`)."""
    end = spec.hoisted.end_components
    for a, m in spec.unit:
        r = 1 / jnp.sqrt(sum(u[j] * u[j] for j in range(a, a + m)))
        for j in range(a, a + m):
            u[j] = u[j] * r
    return tuple(u) if end is None else end(t, tuple(u), p, c)


def _kernel(spec: Spec, K: int, N: int, P: int, Pc: int, L: int, C: int):
    """The kernel of one block: `K` intervals of `n[k]` steps of size `h[k]` from `t0[k]`, the
    state written at their ends; with `L > 0` also the state every L steps of each interval
    into its C slots of `ck_ref` (the reverse mode's checkpoints: the steps and their order
    unchanged; every slot written, so that the compiled kernel's output is defined).
    A model with a jump map takes `jump (K,)` and `save (K + 1,)` (`model.Schedule`): interval
    k starts with the jump map where `jump[k] ≠ 0`, whose recorded components go to slot
    `jump[k]` of `rec_ref`, and the state at time k goes to slot `save[k]` of `out_ref` (slot 0
    of each: a dummy, written where nothing is kept)."""
    R0, NR = spec.record

    def kernel(n_ref, h_ref, t0_ref, x0_ref, p_ref, *refs):
        names = ("jump", "save", "out", "rec") if spec.hoisted.jumps else ("out", "ck")
        ref = dict(zip(names, refs, strict=False))
        out_ref = ref["out"]
        p = tuple(p_ref[j] for j in range(P))
        c = tuple(p_ref[P + j] for j in range(Pc))
        y = tuple(x0_ref[j] for j in range(N))

        def save(k, y):
            at = ref["save"][k] if spec.hoisted.jumps else k
            for j in range(N):
                out_ref[at, j] = y[j]

        save(0, y)

        def interval(k, y):
            h, t0, n = h_ref[k], t0_ref[k], n_ref[k]
            if spec.hoisted.jumps:
                slot = ref["jump"][k]
                jump = spec.hoisted.jump_components
                y = jax.lax.cond(slot != 0, lambda y: jump(t0, y, p, c), lambda y: y, y)
                for j in range(NR):
                    ref["rec"][slot, j] = y[R0 + j]

            def one(s, y):
                return step(spec, p, c, t0 + s.astype(h.dtype) * h, h, y)

            def slot(s, y):  # a slot past the interval's last segment: its end state, no step
                for j in range(N):
                    ref["ck"][k, s, j] = y[j]
                return jax.lax.fori_loop(s * L, jnp.minimum(s * L + L, n), one, y)

            y = jax.lax.fori_loop(0, C, slot, y) if L else jax.lax.fori_loop(0, n, one, y)
            save(k + 1, y)
            return y

        jax.lax.fori_loop(0, K, interval, y)

    return kernel


def run(
    spec: Spec,
    y0: Float[Array, "B N"],
    p: Float[Array, "P Bc"],
    steps: Steps,
    *,
    interpret: bool = False,
    longest: int = 0,
    schedule: Schedule | None = None,
) -> Float[Array, "B T N"] | tuple[Float[Array, "B _ N"], Float[Array, "B ..."]]:
    """States `(B, K + 1, N)` of B bodies at the start and after each of K intervals of
    `steps` (`Steps`) of the model and method of `spec`; `p (P + Pc, B
    or 1)` holds the parameters and the lifted constants, as `model.run` takes them.
    `interpret=True` runs the kernel in Pallas' interpreter (any backend: the CPU tests). The
    batch is padded to whole blocks with copies of the first body. Under `jax.vmap` over the
    bodies (a sweep of one-body solves), the mapped bodies join one kernel call. With
    `longest` (a bound on the steps of an interval), also `run_back`'s checkpoints: each
    interval's states every L ≈ √longest steps, `(B, K, C, N)` (`checkpoints`).
    A model with a jump map takes its `schedule` (`model.Schedule`: the intervals that start
    with the jump map, the kept times) and gives, as `model.run`, the kept states `(B, S, N)`
    and the components `spec.record` after each recorded jump `(B, R, NR)`."""
    if schedule is not None:
        sizes = (schedule.kept.size, schedule.at.size)
        call = functools.partial(_blocks, spec, 0, 0, sizes, interpret=interpret)
        args = (y0, p, *steps, schedule.jump, schedule.save)
        return cast(tuple, _joining(call, states=1, out_body_axes=(0, 0))(*args))
    L, C = checkpoints(longest)
    call = functools.partial(_blocks, spec, L, C, None, interpret=interpret)
    out = _joining(call, states=1, out_body_axes=(0, 0) if L else (0,))(y0, p, *steps)
    return out if L else out[0]


def checkpoints(longest: int) -> tuple[int, int]:
    """`(L, C)`: checkpoints L ≈ √longest steps apart, at most C per interval, for intervals of at
    most `longest` steps (`(0, 0)` for none); two-level checkpointing (Griewank & Walther,
    *Evaluating Derivatives*, 2nd ed., ch. 12)."""
    if longest <= 0:
        return 0, 0
    L = math.isqrt(longest - 1) + 1
    return L, -(-longest // L)


def _joining(call: Callable, states: int, out_body_axes: tuple[int, ...]) -> Callable:
    """`call(*states, p, *steps)` (each state `(B, ...)`, the parameters `(P, B or 1)`, the
    steps shared by the bodies) returning a tuple of arrays with the bodies on `out_body_axes`
    (0 or −1), such that under `jax.vmap` the mapped members' bodies join one call (a sweep of
    one-body solves fills whole blocks); members with steps of their own take a call each."""

    def wrapped(*args):
        out = call(*args)
        return out if isinstance(out, tuple) else (out,)

    batched = jax.custom_batching.custom_vmap(wrapped)

    @batched.def_vmap
    def _(size: int, mapped: list[bool], *args):
        done = tuple(True for _ in out_body_axes)
        if any(mapped[states + 1 :]):  # steps of their own per member: one kernel call each
            axes = tuple(0 if m else None for m in mapped)
            return jax.vmap(wrapped, in_axes=axes)(*args), done
        xs = [
            a if m else jnp.broadcast_to(a, (size, *a.shape))
            for a, m in zip(args[:states], mapped[:states], strict=True)
        ]
        V, B = xs[0].shape[:2]
        p = args[states]
        pv = p if mapped[states] else jnp.broadcast_to(p, (size, *p.shape))
        pv = jnp.moveaxis(jnp.broadcast_to(pv, (V, p.shape[-2], B)), 0, 1).reshape(-1, V * B)
        joined = [x.reshape(V * B, *x.shape[2:]) for x in xs]
        outs = batched(*joined, pv, *args[states + 1 :])
        return tuple(
            o.reshape(V, B, *o.shape[1:])
            if axis == 0
            else jnp.moveaxis(o.reshape(*o.shape[:-1], V, B), -2, 0)
            for o, axis in zip(outs, out_body_axes, strict=True)
        ), done

    return batched


def _padded(a: Array, Bp: int) -> Array:
    """`a` with its bodies (axis 0) moved last and padded to `Bp` with copies of the first."""
    a = jnp.moveaxis(a, 0, -1)
    return jnp.concatenate([a, jnp.broadcast_to(a[..., :1], (*a.shape[:-1], Bp - a.shape[-1]))], -1)


def _parameters(p: Array, B: int, Bp: int, dtype) -> Array:
    """The parameter rows of a call `(max(P, 1), Bp)`, padded as `_padded`: a model without
    parameters gets one row of zeros, never read (a block cannot be empty)."""
    p = jnp.broadcast_to(p.astype(dtype), (p.shape[0], B))
    return _padded(jnp.concatenate([p, jnp.zeros((int(p.shape[0] == 0), B), dtype)]).T, Bp)


def _per_body(shape: tuple[int, ...]) -> pl.BlockSpec:
    """The block of an output `(*shape, Bp)`: the whole `shape` for the program's bodies."""
    return pl.BlockSpec((*shape, BLOCK), lambda i: (*(0,) * len(shape), i))


def _blocks(
    spec: Spec, L: int, C: int, slots: tuple[int, int] | None, *arrays: Array, interpret: bool
) -> tuple[Array, ...]:
    """`run` of one batch (`arrays`: its `y0, p, n, h, t0` and, with `slots`, `jump, save`):
    the `pallas_call` over its blocks; the states `(B, T, N)` and, with `L`, the checkpoints
    `(B, K, C, N)`; with `slots = (S, R)` (a jump map), the S kept states and R records."""
    y0, p, n, h, t0, *schedule = arrays
    B, N, K, dtype = y0.shape[0], y0.shape[1], h.shape[0], y0.dtype
    P = spec.hoisted.p
    Bp = -(-B // BLOCK) * BLOCK
    x0 = _padded(y0, Bp)  # (N, Bp)
    pp = _parameters(p, B, Bp, dtype)
    # with slots, each output's slot 0 is the kernel's dummy (dropped)
    shapes: list[tuple[int, ...]] = [(K + 1 if slots is None else slots[0] + 1, N)]
    if slots is not None:
        shapes.append((slots[1] + 1, max(spec.record[1], 1)))
    if L:
        shapes.append((K, C, N))
    specs = [_per_body(shape) for shape in shapes]
    ins = [pl.BlockSpec((m,), lambda i: (0,)) for m in (K, K + 1)[: len(schedule)]]
    outs = pl.pallas_call(
        _kernel(spec, K, N, P, p.shape[0] - P, L, C),
        out_shape=[jax.ShapeDtypeStruct((*shape, Bp), dtype) for shape in shapes],
        grid=(Bp // BLOCK,),
        in_specs=[
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((K,), lambda i: (0,)),
            pl.BlockSpec((N, BLOCK), lambda i: (0, i)),
            pl.BlockSpec((pp.shape[0], BLOCK), lambda i: (0, i)),
            *ins,
        ],
        out_specs=specs,
        # Triton, one body per thread (Pallas' default on NVIDIA GPUs is Mosaic GPU)
        compiler_params=pltriton.CompilerParams(num_warps=BLOCK // 32, num_stages=1),
        interpret=interpret,
    )(n.astype(jnp.int32), h.astype(dtype), t0.astype(dtype), x0, pp,
      *(a.astype(jnp.int32) for a in schedule))  # fmt: skip
    if slots is not None:
        ys, rec = outs
        outs = [ys[1:], rec[1:, : spec.record[1]]]
    return tuple(jnp.moveaxis(o[..., :B], -1, 0) for o in outs)  # bodies first


def serves(
    hoisted: Hoisted,
    unit: Unit,
    solver: diffrax.AbstractSolver,
    record: tuple[int, int] = (0, 0),
) -> bool:
    """Whether the kernel integrates `hoisted` (with a jump map: recording the components
    `record`) with `solver` (one of `tableau.METHODS`) on the default backend: a GPU, float32 or
    float64, and the kernel checked there (once per model, method and element type: a small
    batch compiled must give the interpreter's states, else one warning and the Diffrax
    path)."""
    method = cast(type[diffrax.AbstractERK], type(solver))
    return (
        type(solver) in METHODS
        and jax.default_backend() == "gpu"
        and hoisted.dtype.name in DTYPES
        and _checked(Spec(hoisted, unit, method, record))
    )


def _compare(what: str, spec: Spec, fn, args) -> bool:
    """Whether `fn(*args, interpret=...)` compiled here agrees with Pallas' interpreter (relative
    1e-4 in float32, 1e-10 in float64); one warning naming `what` where not."""
    dtype, method = spec.hoisted.dtype, spec.method
    try:
        # compiled ahead and called: run at once, also where `simulate` is being traced
        got, want = (
            jax.tree.map(
                np.asarray,
                jax.jit(functools.partial(fn, interpret=i)).lower(*args).compile()(*args),
            )
            for i in (False, True)
        )
        tol = 1e-4 if dtype.name == "float32" else 1e-10
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            if not np.allclose(a, b, rtol=tol, atol=tol, equal_nan=True):
                raise ValueError("its numbers differ from Pallas' interpreter's")
    except Exception as e:  # a lowering or compile failure, or wrong numbers: not served
        warnings.warn(
            f"rigidjax's Pallas {what} for {method.__name__} in {dtype.name} does not work on "
            f"this GPU ({type(e).__name__}: {e}); the same integration runs through Diffrax and "
            "XLA instead.",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    return True


def _sample(spec: Spec):
    """Two blocks of random states (unit groups normalised), parameters in [1, 2] and three
    intervals of 3, 0 and 5 steps: the checks' problem."""
    hoisted, dtype = spec.hoisted, spec.hoisted.dtype
    rng = np.random.default_rng(0)
    B = BLOCK + 3
    y = rng.normal(size=(B, hoisted.n))
    for a, m in spec.unit:
        y[:, a : a + m] /= np.linalg.norm(y[:, a : a + m], axis=1, keepdims=True)
    p = rng.uniform(1, 2, size=(hoisted.p + hoisted.c.shape[0], B)).astype(dtype)
    h, t0 = np.array([0.01, 0.02, 0.005], dtype), np.array([0.0, 0.03, 0.03], dtype)
    return y.astype(dtype), p, (np.array([3, 0, 5], np.int32), h, t0)


@functools.cache
def _checked(spec: Spec) -> bool:
    """Whether the compiled kernel runs here and agrees with Pallas' interpreter on `_sample`
    (two blocks of bodies over three intervals; a model with a jump map: jumps at the first and
    last, the second time not kept)."""
    y, p, steps = _sample(spec)
    fn = functools.partial(run, spec)
    if spec.hoisted.jumps:
        keep = np.array([True, False, True, True])
        schedule = Schedule.of(3, np.array([True, False, True]), keep, spec.record[1])
        fn = functools.partial(fn, schedule=schedule)
    return _compare("kernel", spec, fn, (y, p, steps))
