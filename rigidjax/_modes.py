"""`both_modes`: one function differentiable in every mode and order, from an implementation
whose derivative is reverse mode only (a kernel's discrete adjoint, Diffrax's checkpointed
adjoint: `jax.custom_vjp` inside) and pure-JAX implementations of the same numbers (the Diffrax
path on the same steps with `ForwardMode` and `DirectAdjoint`).

`f = both_modes(reverse, forward, second)` is a `jax.custom_jvp` whose value is `reverse`'s.
Its tangent is one primitive, `tangent_p`, linear in the inputs' tangents:
- evaluated (`jax.jvp`, `jax.jacfwd`): the tangent of `forward` (`jax.jvp`);
- transposed (`jax.grad`, `jax.vjp`, `jax.jacrev`: JAX linearises, then transposes): the
  pullback of `reverse` from the primal run of the same rule (`jax.vjp`, its residuals the
  primitive's operands), so reverse mode runs the fast adjoint once, as `reverse` alone would;
- differentiated again (`jax.hessian`, `jacfwd` of `jacfwd`): `second`'s derivatives, which
  JAX takes to any order;
- batched (`jax.vmap`): the same primitive with one more batch level (`Levels`).

This is the structure JAX's docs recommend for a primitive with rules for both modes ("Custom
derivative rules with hijax primitives", JAX 301; `linear_call` has no batching rule)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jax.core import ShapedArray
from jax.custom_derivatives import SymbolicZero
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir

from ._checks import is_concrete

Aval = tuple[tuple[int, ...], Any]


def closure_free(fn: Callable, *example: Any) -> Callable:
    """`fn` with the tracers it closes over (a torque's gain under `jax.grad`) made explicit
    inputs, as the rules of `both_modes` need (`equinox.filter_closure_convert`, traced on
    `example`); `fn` itself where it closes over none and hashes. The converted jaxpr is a new
    object on every call: as a static argument it made every eager solve on the Diffrax path
    compile again (3-8 s a call), where `fn` itself is the same function each time. As under
    `jax.jit` (and on the kernels), a function is traced once: a global it reads is read
    then."""
    converted = eqx.filter_closure_convert(fn, *example)
    if not all(is_concrete(c) for c in jax.tree.leaves(converted)):
        return converted
    try:  # a static argument of `equinox.filter_jit` must hash
        hash(eqx.partition(fn, eqx.is_array)[1])
    except TypeError:  # (a dataclass with `eq`, say: compiled for each call, as before)
        return converted
    return fn


class _Fns(NamedTuple):
    """What the primitive's rules need, hashable (by the functions' identity)."""

    forward: Callable  # (*leaves of xs) -> ys leaves: jvp-able
    second: Callable  # the same, differentiable in every mode and order
    n_x: int  # leaves of xs
    live: tuple[bool, ...]  # which of them have a tangent (floating, differentiated: `dx`)
    res_tree: Any  # the reverse pullback's tree (its leaves: the residual operands)
    out_avals: tuple[Aval, ...]  # ys leaves of one call (unbatched)


def _float(x: Any) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


_NONE = object()  # the tangent of a float leaf that has none (not differentiated)


def _is_zero(t: Any) -> bool:
    """A tangent that is zero by construction: none, symbolic, or of an integer (`float0`)."""
    if t is _NONE or isinstance(t, SymbolicZero | ad.Zero):
        return True
    return getattr(t, "dtype", None) == jax.dtypes.float0


def _jvp_live(fn: Callable, args: list, tangents: list) -> tuple[Any, Any]:
    """`jax.jvp(fn, args, tangents)` over the arguments whose tangent is not a symbolic zero
    (the others held constant: no derivative is traced through them, e.g. through Diffrax's
    `nextafter` of the times)."""
    idx = [k for k, t in enumerate(tangents) if not _is_zero(t)]
    if not idx:
        out = fn(*args)
        return out, [jnp.zeros_like(y) for y in out]

    def on_live(*live):
        full = list(args)
        for k, x in zip(idx, live, strict=True):
            full[k] = x
        return fn(*full)

    return jax.jvp(on_live, [args[k] for k in idx], [tangents[k] for k in idx])


def both_modes(reverse: Callable, forward: Callable, second: Callable) -> Callable:
    """`f(*xs) -> (ys, aux)` with the value of `reverse(*xs)` and derivatives in every mode
    (module docstring); `forward(*xs)` and `second(*xs)` return the same `ys`, `aux` has no
    derivative (counts, flags). `xs` leaves that are not floating point get none either."""

    def on_leaves(fn: Callable, tree) -> Callable:
        def g(*leaves):
            return jtu.tree_leaves(fn(*jtu.tree_unflatten(tree, leaves)))

        return g

    @jax.custom_jvp
    def f(*xs):
        return reverse(*xs)

    def f_jvp(primals, tangents):
        # every leaf an operand (integer ones too: closing over them would leak a trace into
        # the primitive's rules), the floating ones with a tangent `live`
        leaves, tree = jtu.tree_flatten(primals)
        dl = jtu.tree_flatten(tangents, is_leaf=_is_zero)[0]
        live = tuple(_float(x) and not _is_zero(d) for x, d in zip(leaves, dl, strict=True))
        ys_tree: list = []

        def value(*leaves):  # `reverse`, its states flattened
            ys, aux = reverse(*jtu.tree_unflatten(tree, leaves))
            ys_leaves, tree_ys = jtu.tree_flatten(ys)
            ys_tree.append(tree_ys)
            return ys_leaves, aux

        second_on = on_leaves(second, tree)
        ys_leaves, aux, res, res_tree = _primal_run(value, second_on, leaves, live)
        fns = _Fns(
            forward=on_leaves(forward, tree),
            second=second_on,
            n_x=len(leaves),
            live=live,
            res_tree=res_tree,
            out_avals=tuple((tuple(y.shape), jnp.result_type(y)) for y in ys_leaves),
        )
        dx = [d for d, on in zip(dl, live, strict=True) if on]
        if dx:
            dys = tangent_p.bind(*leaves, *res, *dx, fns=fns, levels=())
        else:
            dys = [jnp.zeros_like(y) for y in ys_leaves]
        aux_zero = jtu.tree_map(_zero_tangent, aux)
        ys = jtu.tree_unflatten(ys_tree[0], ys_leaves)
        return (ys, aux), (jtu.tree_unflatten(ys_tree[0], dys), aux_zero)

    f.defjvp(f_jvp, symbolic_zeros=True)
    return f


def _primal_run(
    value: Callable, second: Callable, fl: list, live: tuple[bool, ...]
) -> tuple[list, Any, list, Any]:
    """`(ys, aux, residuals, residuals' tree)`: the value of `value(*fl) -> (ys, aux)` and the
    residuals of its pullback (`jax.vjp`) with respect to the `live` leaves only (a backend
    may do less for the others: the Pallas kernel's adjoint serves where the output times are
    not differentiated). Differentiated itself (an outer `jax.jacfwd` of
    `jax.grad`, as `jax.hessian`), the tangent of `ys` is `second`'s; the residuals' tangents
    are zero: the rules that take them (`_jvp`, `_adjoint`) differentiate through `second`
    from `x` instead."""
    box: list = []

    idx = [k for k, on in enumerate(live) if on]

    @jax.custom_jvp
    def run(*fl):
        def on_live(*xs):
            full = list(fl)
            for k, x in zip(idx, xs, strict=True):
                full[k] = x
            return value(*full)

        ys, pullback, aux = jax.vjp(on_live, *[fl[k] for k in idx], has_aux=True)
        res, res_tree = jtu.tree_flatten(pullback)
        box.append(res_tree)
        return ys, aux, res

    def run_jvp(fl, dfl):
        ys, aux, res = run(*fl)
        _, dys = _jvp_live(second, list(fl), list(dfl))
        zero = functools.partial(jtu.tree_map, _zero_tangent)
        return (ys, aux, res), (list(dys), zero(aux), zero(res))

    run.defjvp(run_jvp, symbolic_zeros=True)
    ys, aux, res = run(*fl)
    return ys, aux, res, box[-1]


def _zero_tangent(x: Any) -> Any:
    x = jnp.asarray(x)
    if _float(x):
        return jnp.zeros_like(x)
    return np.zeros(x.shape, jax.dtypes.float0)


tangent_p = Primitive("rigidjax_tangent")
tangent_p.multiple_results = True


Levels = tuple[tuple[int, tuple[int | None, ...]], ...]
"""The batch levels of a `tangent_p` (outermost first): each `(size, axes)`, `axes` per operand
0 (mapped, on its leading axis) or None (shared: never broadcast, so a backend sees it as it
would under `jax.vmap`, e.g. Diffrax's unbatched step counter)."""


def _vmapped(fn: Callable, levels: Levels, in_axes: Callable[[tuple], tuple]) -> Callable:
    """`fn` mapped over `levels` (innermost last), `in_axes(axes)` its arguments' axes."""
    for _, axes in reversed(levels):
        fn = jax.vmap(fn, in_axes=in_axes(axes))
    return fn


def _split_ops(ops, fns: _Fns):
    n_res = fns.res_tree.num_leaves
    return list(ops[: fns.n_x]), list(ops[fns.n_x : fns.n_x + n_res]), list(ops[fns.n_x + n_res :])


def _tangents(fns: _Fns, dx: list) -> list:
    """The tangents of all leaves from those of the live ones (none elsewhere)."""
    it = iter(dx)
    return [next(it) if on else _NONE for on in fns.live]


def _tangent(*ops, fns: _Fns, levels: Levels) -> list:
    """The tangent of `forward` at `x` along `dx` (the residuals unused)."""

    def one(*ops):
        x, _, dx = _split_ops(ops, fns)
        return list(_jvp_live(fns.forward, x, _tangents(fns, dx))[1])

    return _vmapped(one, levels, lambda axes: axes)(*ops)


@functools.lru_cache(maxsize=32)
def _compiled_tangent(fns: _Fns, levels: Levels) -> Callable:
    return jax.jit(functools.partial(_tangent, fns=fns, levels=levels))


def _impl(*ops, fns: _Fns, levels: Levels) -> list:
    return _compiled_tangent(fns, levels)(*ops)


def _abstract(*ops, fns: _Fns, levels: Levels) -> list:
    lead = tuple(size for size, _ in levels)
    return [ShapedArray((*lead, *shape), dtype) for shape, dtype in fns.out_avals]


def _jvp(primals, tangents, *, fns: _Fns, levels: Levels):
    """`d/dε T(x + ε u, dx + ε v)`: the tangent map differentiated once more, through
    `second` (any order, either mode)."""
    x, _, dx = _split_ops(primals, fns)
    u, _, v = _split_ops(tangents, fns)
    n, m = len(x), len(dx)

    def T(*args):
        return _jvp_live(fns.second, list(args[:n]), _tangents(fns, list(args[n:])))[1]

    def one(*args):
        return _jvp_live(T, list(args[: n + m]), list(args[n + m :]))

    if levels:  # (vmap takes arrays: the zeros made)
        u = [ad.instantiate_zeros(t) for t in u]
        v = [ad.instantiate_zeros(t) for t in v]

    def in_axes(axes):
        xa, da = axes[:n], axes[len(axes) - m :]
        return (*xa, *da, *xa, *da)

    out, dout = _vmapped(one, levels, in_axes)(*x, *dx, *u, *v)
    return list(out), list(dout)


def _transpose(cts, *ops, fns: _Fns, levels: Levels):
    """The cotangents of `dx`: the pullback of `reverse` (its residuals among the operands),
    differentiable again through `second` (`_adjoint`); summed over the batch levels where a
    `dx` is shared."""
    x, res, dx = _split_ops(ops, fns)
    avals = _abstract(*x, fns=fns, levels=levels)
    cts = [
        jnp.zeros(a.shape, a.dtype) if type(ct) is ad.Zero else ct
        for ct, a in zip(cts, avals, strict=True)
    ]
    n, r = len(x), len(res)
    adjoint = _adjoint(fns)

    def one(*args):
        return adjoint(args[:n], args[n : n + r], args[n + r :])

    bars = _vmapped(one, levels, lambda axes: (*axes[: n + r], *(0,) * len(cts)))(*x, *res, *cts)
    out = []
    for k, (d, bar) in enumerate(zip(dx, bars, strict=True)):
        shared = [i for i, (_, axes) in enumerate(levels) if axes[n + r + k] is None]
        # (a tangent known to be zero, e.g. of an argument not differentiated: no cotangent)
        out.append(jnp.sum(bar, axis=tuple(shared)) if ad.is_undefined_primal(d) else None)
    return [None] * (n + r) + out


@functools.lru_cache(maxsize=32)
def _adjoint(fns: _Fns) -> Callable:
    """`(x, residuals, ȳ) -> x̄` (of the live leaves) by `reverse`'s pullback; its own
    derivative (`jax.hessian`: forward mode over this reverse mode) that of `second`'s
    pullback."""
    idx = [k for k, on in enumerate(fns.live) if on]

    @jax.custom_jvp
    def adjoint(x, res, ct):
        pullback = jtu.tree_unflatten(fns.res_tree, res)
        return tuple(pullback(list(ct)))

    def adjoint_jvp(primals, tangents):
        x, _, ct = primals
        dx, _, dct = tangents
        n = len(x)

        def by_second(*args):
            bars = jax.vjp(fns.second, *args[:n])[1](list(args[n:]))
            return tuple(bars[k] for k in idx)

        out, dout = _jvp_live(by_second, [*x, *ct], [*dx, *dct])
        return tuple(out), tuple(dout)

    adjoint.defjvp(adjoint_jvp, symbolic_zeros=True)
    return adjoint


def _batch(args, dims, *, fns: _Fns, levels: Levels):
    size = next(a.shape[d] for a, d in zip(args, dims, strict=True) if d is not None)
    moved = [a if d is None else jnp.moveaxis(a, d, 0) for a, d in zip(args, dims, strict=True)]
    axes = tuple(None if d is None else 0 for d in dims)
    out = tangent_p.bind(*moved, fns=fns, levels=((size, axes), *levels))
    return out, [0] * len(out)


tangent_p.def_impl(_impl)
tangent_p.def_abstract_eval(_abstract)
ad.primitive_jvps[tangent_p] = _jvp
ad.primitive_transposes[tangent_p] = _transpose
batching.primitive_batchers[tangent_p] = _batch
mlir.register_lowering(tangent_p, mlir.lower_fun(_tangent, multiple_results=True))
