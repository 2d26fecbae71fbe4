"""Any model's ODE `ẏ = f(t, y, p)` at fixed steps of an explicit Runge–Kutta method, as one CPU
kernel written from the JAX field itself (`model.cc`): the fast path of every model with a
torque, the heavy top, the satellite and the 6-DOF body.

The field of one body, `f(t, y (N,), p (P,)) -> (N,)`, is traced once. Its traced constants
(torque gains swept under `jax.vmap`, differentiated by `jax.grad`) are lifted into a runtime
parameter vector `c`, and so are its concrete float constants and literals (`_lift`: a gain
changed between eager calls), so that the C++ depends on them through their shapes only (built
once, cached on disk, `_build`). 0, the powers of two and non-finite values stay compile-time
constants (folded: `e_Z` selects a row of a matrix instead of multiplying by 0 and 1).
`model.h` holds the field as C++ statements (`_scalar.unroll` + `_emit.CEmitter`), its
transposed Jacobian-vector product written the same way from the jaxpr of `jax.vjp`, and the
tableau from Diffrax's coefficients.
The same scalar program, evaluated with JAX on one array per component (`_components.Components`),
is the Diffrax path's field (`Hoisted.components`), so the two cannot drift apart."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, cast

import diffrax
import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float, Int

from .._checks import is_concrete
from . import _lift, tableau
from ._build import load
from ._components import Components
from ._objects import _is_const, scalars
from ._scalar import Unsupported, unroll
from ._source import consts, header, headers, linked, model_source, program

MAX_OPERATIONS = 600
"""The largest field (scalar statements of its program, `Hoisted.operations`) that the kernels
and the Diffrax path's scalar program take; larger ones run on the Diffrax path with the
model's own field, whose matrix products XLA batches. The library's own models have at most
~190. An MLP torque 7 → w → w → 3 (256 bodies, 200 RK4 steps, fresh caches; kernel / own
field): w = 8, 328 statements: forward 21 / 13 ms, gradient 77 / 111 ms, first gradient
3.7 / 7.0 s; w = 16, 872: 47 / 18 ms, 199 / 143 ms, 9.1 / 6.6 s; w = 32, 2728: the kernel's
first gradient 48 s to 2 min, the own field's 6.8 s."""
Field = Callable[[Array, Array, Array], Array]
"""`f(t, y (N,), p (P,)) -> ẏ (N,)` of one body."""
_NAME = "model"


class Hoisted:
    """A field of N states and P parameters with its traced float constants lifted out:
    `fn(t, y, p, c)`, the constants' values `c (Pc,)` (traced or not), and the jaxprs of `fn`
    and of its cotangent map, traced once; optionally a jump map `jump_fn(t, y, p, c) -> y`
    (applied at the start of flagged intervals: a sampled command) and a step-end map
    `end_fn(t, y, p, c) -> y` (after every step; `t` unused), with the same constants."""

    def __init__(
        self,
        fns: Callable,
        c: Array,
        n: int,
        p: int,
        dtype,
        jumps: bool,
        ends: bool,
        events: bool = False,
    ):
        self.fns, self.c, self.n, self.p, self.dtype = fns, c, n, p, jnp.dtype(dtype)
        self.jumps, self.ends, self.events = jumps, ends, events
        self._sources: dict[tuple, str] = {}
        self._jaxprs: dict[tuple, Any] = {}

    def fn(self, t, y, p, c):
        return self.fns(t, y, p, c)[0]

    def jump_fn(self, t, y, p, c):
        return self.fns(t, y, p, c)[1]

    def end_fn(self, t, y, p, c):
        return self.fns(t, y, p, c)[1 + self.jumps]

    def event_fn(self, t, y, p, c):
        return self.fns(t, y, p, c)[1 + self.jumps + self.ends][:1]

    def _avals(self):
        dt = self.dtype
        return (
            jax.ShapeDtypeStruct((), dt),
            jax.ShapeDtypeStruct((self.n,), dt),
            jax.ShapeDtypeStruct((self.p,), dt),
            jax.ShapeDtypeStruct(self.c.shape, dt),
        )

    @functools.cached_property
    def forward(self):
        """The jaxpr of the field `fn(t, y, p, c)`."""
        return self.jaxpr(self.fn)

    @functools.cached_property
    def forward_program(self) -> tuple[list[str], list]:
        """The field's scalar program as C++ statements (the kernels' `F`) and its outputs,
        unrolled once for both `operations` and the kernel's source."""
        return program(self.forward, "k", "f", self.n, self.p, self.c.shape[0])

    @functools.cached_property
    def operations(self) -> int:
        """The statements of the field's scalar program (the kernels' `F`): its size."""
        return len(self.forward_program[0])

    @functools.cached_property
    def backward(self):
        """The jaxpr of its cotangent map `(t, y, p, c, v) -> (t̄, ȳ, p̄, c̄)`."""
        return self.jaxpr(self.fn, cotangent=True)

    def jaxpr(self, fn: Callable, cotangent: bool = False):
        """The jaxpr of `fn(t, y, p, c)` (`fn`: the field or the jump map), or of its cotangent
        map `(t, y, p, c, v) -> vjp(fn)(v)`; traced once each (kept with this object)."""
        key = (fn, cotangent)
        if key not in self._jaxprs:

            def cotangents(t, y, p, c, v):
                return jax.vjp(fn, t, y, p, c)[1](v)

            avals = self._avals()
            self._jaxprs[key] = (
                jax.make_jaxpr(cotangents)(*avals, avals[1])
                if cotangent
                else jax.make_jaxpr(fn)(*avals)
            )
        return self._jaxprs[key]

    @functools.cached_property
    def components(self) -> Callable:
        """The field as the Diffrax path evaluates it: `(t, y, p, c) -> ẏ` on tuples of
        component arrays (`y`: N arrays, e.g. `(B,)` each; `p`: P arrays, scalars or `(B,)`;
        `c`: `(Pc,)` or Pc arrays), the same scalar operations as the kernel's `F`."""
        return self._on_components(self.forward)

    @functools.cached_property
    def jump_components(self) -> Callable:
        """The jump map on component arrays (as `components`), the kernel's `J`."""
        return self._on_components(self.jaxpr(self.jump_fn))

    @functools.cached_property
    def end_components(self) -> Callable | None:
        """The step-end map on component arrays (as `components`), the kernel's `E`; None
        without one."""
        return self._on_components(self.jaxpr(self.end_fn)) if self.ends else None

    @functools.cached_property
    def event_components(self) -> Callable | None:
        """The event's condition on component arrays (as `components`: a 1-tuple), the
        kernel's `G`; None without one."""
        return self._on_components(self.jaxpr(self.event_fn)) if self.events else None

    def _on_components(self, forward) -> Callable:
        n, p = self.n, self.p

        def fn(t, y, pp, c):
            ins = [
                scalars([t], ()),
                scalars(list(y), (n,)),
                scalars(list(pp), (p,)),
                scalars([c[i] for i in range(len(c))], (len(c),)),
            ]
            (k,) = unroll(forward, Components(), consts(forward), ins)
            like = y[0]
            return tuple(
                jnp.broadcast_to(jnp.asarray(x, like.dtype), jnp.shape(like))
                if _is_const(x)
                else jnp.broadcast_to(x, jnp.broadcast_shapes(jnp.shape(x), jnp.shape(like)))
                for x in k.reshape(-1)
            )

        return fn

    def source(self, unit: tuple[tuple[int, int], ...], record: tuple[int, int] = (0, 0)) -> str:
        """`struct Model` of `model.cc` (`model_source`), written once per unit groups and
        recorded components."""
        key = (unit, record)
        if key not in self._sources:
            self._sources[key] = model_source(self, unit, record)
        return self._sources[key]


class _Traced(Exception):
    """The field closes over traced constants: its hoisting belongs to one trace only."""


def hoist(
    field: Field,
    n: int,
    p: int,
    dtype,
    jump: Field | None = None,
    end: Callable[[Array], tuple[Array, Array]] | None = None,
    event: Field | None = None,
) -> Hoisted:
    """`field` (and the jump map `jump`, step-end map `end(y) -> (y, changed)` and event
    condition `event(t, y, p) -> ()`, if any; the kernels apply `end(y)[0]` to every body,
    whether changed or not) traced on `t ()`, `y (n,)`, `p (p,)` of `dtype`, their traced
    float constants lifted into `c`, then the concrete ones that `_lift` lifts (without
    cotangents); kept (not traced again) for hashable functions whose constants are
    concrete, as `jax.jit` keeps a function's compilation. A traced integer constant (an
    index computed at run time) raises `Unsupported`."""
    maps = (field, jump, end, event)
    name = jnp.dtype(dtype).name
    try:
        hash(maps)
    except TypeError:
        return _sized(_hoist(maps, n, p, name))
    try:
        return _sized(_hoist_concrete(maps, n, p, name))
    except _Traced:
        return _sized(_hoist(maps, n, p, name))


def _sized(hoisted: Hoisted) -> Hoisted:
    """`hoisted` unless its field's scalar program is larger than `MAX_OPERATIONS`
    (`Unsupported`)."""
    if hoisted.operations > MAX_OPERATIONS:
        raise Unsupported(
            f"a field of {hoisted.operations} scalar operations (a kernel takes at most "
            f"{MAX_OPERATIONS}; XLA's batched products are faster there)"
        )
    return hoisted


@functools.lru_cache(maxsize=64)
def _hoist_concrete(maps: tuple, n: int, p: int, dtype: str) -> Hoisted:
    hoisted = _hoist(maps, n, p, dtype)
    if not is_concrete(hoisted.c):
        raise _Traced
    return hoisted


def _hoist(maps: tuple, n: int, p: int, dtype: str) -> Hoisted:
    args = (
        jax.ShapeDtypeStruct((), dtype),
        jax.ShapeDtypeStruct((n,), dtype),
        jax.ShapeDtypeStruct((p,), dtype),
    )

    field, jump, end, event = maps

    def all_maps(t, y, p):
        return (
            field(t, y, p),
            *(() if jump is None else (jump(t, y, p),)),
            *(() if end is None else (end(y)[0],)),
            *(
                ()
                if event is None
                else (jnp.broadcast_to(jnp.asarray(event(t, y, p), y.dtype), (n,)),)
            ),
        )

    closed = _lift.literals_as_consts(jax.make_jaxpr(all_maps)(*args), dtype)
    if any(a.shape != (n,) for a in closed.out_avals):  # pyright: ignore
        raise ValueError(
            f"the model's field, jump and step-end maps must return arrays of shape ({n},)"
        )
    consts = list(closed.consts)
    traced = [i for i, x in enumerate(consts) if not is_concrete(x)]
    floats = [i for i in traced if jnp.issubdtype(jnp.result_type(consts[i]), jnp.floating)]
    if len(floats) < len(traced):
        raise Unsupported("an integer or boolean computed at run time, closed over")
    values = [jnp.asarray(consts[i]) for i in floats]
    masks = {i: _lift.liftable(x, dtype) for i, x in enumerate(consts) if i not in traced}
    masks = {i: m for i, m in masks.items() if m is not None}
    fixed = [np.asarray(consts[i])[m] for i, m in masks.items()]
    c = jnp.concatenate(
        [jnp.ravel(v).astype(dtype) for v in values]
        + [jnp.asarray(np.concatenate([np.zeros((0,), dtype), *fixed]))]
    )

    def fns(t, y, p, c):
        full, offset = list(consts), 0
        for i, v in zip(floats, values, strict=True):
            full[i] = c[offset : offset + v.size].reshape(v.shape).astype(v.dtype)
            offset += v.size
        # the concrete constants lifted: no cotangents (the kernels' reverse modes skip them)
        lifted = jax.lax.stop_gradient(c[offset:])
        for i, mask in masks.items():
            size = int(mask.sum())
            full[i] = _with_lifted(np.asarray(consts[i]), mask, lifted[:size])
            lifted = lifted[size:]
        return jax.core.eval_jaxpr(closed.jaxpr, full, t, y, p)

    jumps, ends, events = (m is not None for m in maps[1:])
    return Hoisted(fns, c, n, p, dtype, jumps, ends, events)


def _with_lifted(value: np.ndarray, mask: np.ndarray, lifted: Array) -> Array:
    """`value` with its elements under `mask` read from `lifted` (in order), the others kept
    as constants."""
    if mask.all():
        return lifted.reshape(value.shape)
    flat, where = value.reshape(-1), mask.reshape(-1)
    edges = [0, *(np.flatnonzero(where[1:] != where[:-1]) + 1), where.size]
    parts, used = [], 0
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if where[a]:
            parts.append(lifted[used : used + b - a])
            used += b - a
        else:
            parts.append(jnp.asarray(flat[a:b]))
    return jnp.concatenate(parts).reshape(value.shape)


class Kernel(NamedTuple):
    """A built model kernel: its forward handler's name, its reverse modes (`backward(times)`:
    built and registered on first use; without, with the cotangents of the steps' times),
    sizes (P counts the lifted constants) and the components `(R0, NR)` that each jump
    records."""

    forward: str
    backward_headers: tuple[tuple[str, str], tuple[str, str]]
    n: int
    p: int
    record: tuple[int, int]

    def backward(self, times: bool) -> str:
        """The handler's name of the reverse mode (with the cotangents of the steps' sizes and
        start times where `times`), built and registered on the first call."""
        text, name = self.backward_headers[times]
        if load(_NAME, (name,), headers(text), linked(text)) is None:
            raise RuntimeError(
                "the reverse mode of rigidjax's model kernel could not be built (see the "
                "warning); pass solver=rigidjax.ExplicitRK(method) to differentiate through "
                "Diffrax"
            )
        return name


def forward_part(
    hoisted: Hoisted,
    unit: tuple[tuple[int, int], ...],
    solver: diffrax.AbstractSolver,
    record: tuple[int, int],
    adaptive: bool = False,
    fixed: bool = False,
) -> tuple[type[diffrax.AbstractERK], str, str] | None:
    """The forward part of a kernel of `hoisted` for `solver` (one of `tableau.METHODS`, or of
    `tableau.ADAPTIVE` for the `adaptive` kernel; `adaptive` and `fixed`: the per-body kernel
    at fixed steps, `tableau.METHODS`) built and registered: `(method, struct Model's source,
    handler name)`; None where kernels cannot run here."""
    dtype = hoisted.dtype
    if not (
        type(solver) in (tableau.ADAPTIVE if adaptive and not fixed else tableau.METHODS)
        and jax.default_backend() == "cpu"
        and dtype.name in tableau.DTYPES
    ):
        return None
    method = cast(type[diffrax.AbstractERK], type(solver))
    source = hoisted.source(unit, record)
    text, name = header(method, dtype, source, "forward", adaptive=adaptive, fixed=fixed)
    if load(_NAME, (name,), headers(text, adaptive=adaptive), linked(text)) is None:
        return None
    return method, source, name


def build(
    hoisted: Hoisted,
    unit: tuple[tuple[int, int], ...],
    solver: diffrax.AbstractSolver,
    record: tuple[int, int] = (0, 0),
) -> Kernel | None:
    """The kernel of `hoisted` for `solver` (one of `tableau.METHODS`) in its dtype, its
    forward part built and registered on first use (its reverse mode on the first gradient);
    None where kernels cannot run here (not the CPU, no compiler). `Unsupported` if the field
    has no scalar form."""
    built = forward_part(hoisted, unit, solver, record)
    if built is None:
        return None
    method, source, name = built
    dtype = hoisted.dtype
    backward = (
        header(method, dtype, source, "backward", False),
        header(method, dtype, source, "backward", True),
    )
    return Kernel(name, backward, hoisted.n, hoisted.p + hoisted.c.shape[0], record)


def call(target: str, shapes: list[jax.ShapeDtypeStruct], *args: Array | np.ndarray) -> list:
    """The kernel `target` on `args` (integers as int32, the rest as `shapes[0]`'s dtype);
    under `jax.vmap` an operand that is not mapped keeps a leading dimension of 1
    (`"expand_dims"`), which the kernel reads for every row: shared parameters and steps are
    never copied per row."""
    dtype = shapes[0].dtype
    ffi = jax.ffi.ffi_call(target, shapes, vmap_method="expand_dims")
    cast = [a.astype(jnp.int32 if jnp.issubdtype(a.dtype, jnp.integer) else dtype) for a in args]
    return list(ffi(*cast))


class Schedule(NamedTuple):
    """What a kernel call saves and where its jumps record (NumPy constants: a JAX array made
    here would be a tracer under `jax.jit`, which a custom VJP's rules must not close over):
    `kept` the saved times' indices, `at` the recorded jumps' intervals, `jump (K,)` 0 or 1 + a
    recorded jump's slot, `every`/`save (K + 1,)` 1 + each time's slot (all, or the kept)."""

    kept: np.ndarray
    at: np.ndarray
    jump: np.ndarray
    every: np.ndarray
    save: np.ndarray

    @classmethod
    def of(cls, K: int, jump: np.ndarray | None, keep: np.ndarray | None, NR: int) -> Schedule:
        jumps = np.zeros(K, bool) if jump is None else np.asarray(jump, bool)
        kept = np.arange(K + 1) if keep is None else np.flatnonzero(np.asarray(keep, bool))
        at = np.flatnonzero(jumps) if NR else np.zeros(0, int)
        slots = np.zeros(K, np.int32)
        slots[at] = np.arange(1, at.size + 1)
        jmp = np.where(jumps, np.maximum(slots, 1), 0).astype(np.int32)
        save = np.zeros(K + 1, np.int32)
        save[kept] = np.arange(1, kept.size + 1)
        return cls(kept, at, jmp, np.arange(1, K + 2, dtype=np.int32), save)

    def cotangent(self, y: Array, g: tuple, n: int, record: tuple[int, int]) -> Array:
        """The cotangent of every saved state `(B, K + 1, n)` (`y`'s shape) from those of the
        kept states and the records, `g` (symbolic zeros allowed)."""
        B, dtype, (R0, NR) = y.shape[0], y.dtype, record
        shapes = [(B, self.kept.size, n), (B, self.at.size, NR)]
        gy_kept, g_rec = (
            jnp.zeros(shape, dtype) if isinstance(x, SymbolicZero) else x
            for x, shape in zip(g, shapes, strict=True)
        )
        every = self.kept.size == y.shape[1]
        gy = gy_kept if every else jnp.zeros_like(y).at[:, self.kept].add(gy_kept)
        if self.at.size:  # a command is held after its jump to the next time
            gy = gy.at[:, self.at + 1, R0 : R0 + NR].add(g_rec)
        return gy


def block_cotangents(pb: Array, blocks: Sequence[Array]) -> tuple[Array, ...]:
    """The cotangents of the parameter blocks from the kernel's per-body `pb (B, P)`: summed
    over the bodies for a shared block."""
    widths = np.cumsum([0, *(b.shape[1] for b in blocks)])
    return tuple(
        pb[:, a:b].sum(axis=0, keepdims=True) if block.shape[0] == 1 else pb[:, a:b]
        for block, a, b in zip(blocks, widths[:-1], widths[1:], strict=True)
    )


def run(
    kernel: Kernel,
    y0: Float[Array, "B N"],
    blocks: Sequence[Float[Array, "#B _"]],
    n: Int[Array, " K"],
    h: Float[Array, " K"],
    t0: Float[Array, " K"],
    jump: np.ndarray | None = None,
    keep: np.ndarray | None = None,
) -> tuple[Float[Array, "B S N"], Float[Array, "B R NR"]]:
    """The states `(B, S, N)` at the start and after each of K intervals of `n[k]` steps of
    size `h[k]` from `t0[k]` where `keep (K + 1,)` (booleans; all by default), each interval
    with `jump[k]` (booleans `(K,)`; none by default) started by the jump map, and the
    components `kernel.record` after each jump `(B, R, NR)`; the parameters and lifted
    constants come in `blocks`, each `(B or 1, Pj)` (per body or shared), `Σ Pj = P`. Reverse
    mode by the kernel's discrete adjoint of the same steps (`jax.custom_vjp`; its forward run
    keeps every state)."""
    K, B, dtype = h.shape[0], y0.shape[0], y0.dtype
    sc = Schedule.of(K, jump, keep, kernel.record[1])
    kept, every_kept = sc.kept, sc.kept.size == K + 1  # (then no gather or scatter)

    def run_call(y0, blocks, n, h, t0, save, S):
        shapes = [(B, S, kernel.n), (B, sc.at.size, kernel.record[1])]
        structs = [jax.ShapeDtypeStruct(shape, dtype) for shape in shapes]
        return call(kernel.forward, structs, y0, n, h, t0, sc.jump, save, *blocks)

    def forward(y0, blocks, n, h, t0):
        return tuple(run_call(y0, blocks, n, h, t0, sc.save, kept.size))

    def run_fwd(y0, blocks, n, h, t0):
        # (symbolic zeros: the cotangents of the steps' times only where they are perturbed)
        times = h.perturbed or t0.perturbed
        y0, n, h, t0 = y0.value, n.value, h.value, t0.value
        blocks = tuple(b.value for b in blocks)
        y, rec = run_call(y0, blocks, n, h, t0, sc.every, K + 1)
        return (y if every_kept else y[:, kept], rec), (y, blocks, n, h, t0, () if times else None)

    def run_bwd(residuals, g):
        y, blocks, n, h, t0, times = residuals
        gy = sc.cotangent(y, g, kernel.n, kernel.record)
        shapes = [(B, kernel.n), (B, kernel.p), (B, K), (B, K)]
        structs = [jax.ShapeDtypeStruct(shape, dtype) for shape in shapes]
        args = (y, n, h, t0, sc.jump, sc.every, gy, *blocks)
        y0b, pb, hb, tb = call(kernel.backward(times is not None), structs, *args)
        gb = block_cotangents(pb, blocks)
        if times is None:
            return y0b, gb, None, None, None
        return y0b, gb, None, jnp.sum(hb, axis=0), jnp.sum(tb, axis=0)

    solve = jax.custom_vjp(forward)
    solve.defvjp(run_fwd, run_bwd, symbolic_zeros=True)
    return solve(y0, tuple(blocks), n, h, t0)
