"""A jaxpr taken apart into scalar operations: the one definition of a model's vector field that
every backend evaluates.

A model's field is written in JAX for one body on small arrays (`Ω (3,)`, `q (4,)`, a 3×3
matrix). `unroll` walks its jaxpr with every array held as a NumPy object array of scalars, so
that the structural operations (slices, reshapes, broadcasts, transposes, concatenations, small
matrix products, reductions) cost nothing and only the scalar arithmetic remains. A `Backend`
carries that arithmetic out:

- `CEmitter` writes it as C++ statements (`rigidjax.kernels.model`: the CPU kernel);
- `_components.Components` evaluates it with JAX on one array per scalar, e.g. a `(B,)` array
  per state component of a batch (the Diffrax path: XLA fuses the stages into one loop over
  bodies with no gathers or stacks; the GPU kernel: one `(128,)` register vector per
  component).

The library's run-time checks in the field (`_checks.LIBRARY_CHECK`, e.g. `quat.to_matrix`'s)
are dropped: their host callbacks cost ~10× an attitude torque's arithmetic, and the state is a
unit quaternion by construction (a non-finite state still fails the solve; validate parameters
where they are built). A primitive with no scalar form (`while`, `scan`, a host callback, a
data-dependent index, ...), a user's `equinox.error_if` and an effect (`jax.debug.print`) raise
`Unsupported` naming it: the caller falls back to the field as it is, where they run.
`lax.cond` and `lax.switch` become a selection between their branches."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from jax.extend import core as jex_core

from .._checks import LIBRARY_CHECK, is_concrete
from ._objects import Scalar, _filled, _is_const, objects


class Unsupported(ValueError):
    """The field uses `primitive`, which has no scalar form here."""

    def __init__(self, primitive: str):
        super().__init__(primitive)
        self.primitive = primitive


@runtime_checkable
class Backend(Protocol):
    def apply(self, name: str, params: dict, args: Sequence[Scalar], dtype: np.dtype) -> Scalar:
        """The elementwise primitive `name` on scalars `args`, of element type `dtype`."""
        ...


# Elementwise primitives evaluated on constants while unrolling (in float64 NumPy, then cast).
_FOLD: dict[str, Callable[..., Any]] = {
    "add": np.add,
    "add_any": np.add,
    "sub": np.subtract,
    "mul": np.multiply,
    "div": np.divide,
    "neg": np.negative,
    "max": np.maximum,
    "min": np.minimum,
    "abs": np.abs,
    "sqrt": np.sqrt,
    "sin": np.sin,
    "cos": np.cos,
    "exp": np.exp,
    "log": np.log,
    "square": np.square,
    "lt": np.less,
    "le": np.less_equal,
    "gt": np.greater,
    "ge": np.greater_equal,
    "eq": np.equal,
    "ne": np.not_equal,
    "not": np.logical_not,
    "and": np.logical_and,
    "or": np.logical_or,
}
ELEMENTWISE = frozenset(
    {
        *_FOLD,
        "rsqrt",
        "cbrt",
        "tan",
        "asin",
        "acos",
        "atan",
        "atan2",
        "sinh",
        "cosh",
        "tanh",
        "asinh",
        "acosh",
        "atanh",
        "log1p",
        "expm1",
        "exp2",
        "pow",
        "integer_pow",
        "sign",
        "floor",
        "ceil",
        "round",
        "select_n",
        "clamp",
        "is_finite",
        "convert_element_type",
        "erf",
        "erfc",
        "logistic",
        "rem",
        "nextafter",
    }
)
_IDENTITY = frozenset({"copy", "copy_p", "stop_gradient", "optimization_barrier", "pvary"})
_CALLS = ("jaxpr", "call_jaxpr", "fun_jaxpr")


def _simplify(name: str, args: Sequence[Scalar]) -> tuple[bool, Scalar]:
    """Identities with a constant 0 or 1 operand (the cotangent programs are full of them)."""
    if name in ("add", "add_any"):
        a, b = args
        if _is_const(a) and a == 0:
            return True, b
        if _is_const(b) and b == 0:
            return True, a
    if name == "sub" and _is_const(args[1]) and args[1] == 0:
        return True, args[0]
    if name == "mul":
        a, b = args
        for x, y in ((a, b), (b, a)):
            if _is_const(x) and x == 0:
                return True, 0.0
            if _is_const(x) and x == 1:
                return True, y
    if name == "div" and _is_const(args[1]) and args[1] == 1:
        return True, args[0]
    if name == "neg" and _is_const(args[0]) and args[0] == 0:
        return True, 0.0
    return False, None


class _Unroller:
    def __init__(self, backend: Backend):
        self.backend = backend

    def elementwise(self, name: str, params: dict, args: list[np.ndarray], dtype) -> np.ndarray:
        shape = np.broadcast_shapes(*(a.shape for a in args))
        args = [np.broadcast_to(a, shape) for a in args]
        out = np.empty(shape, dtype=object)
        for idx in np.ndindex(shape):
            xs = [a[idx] for a in args]
            out[idx] = self.scalar(name, params, xs, dtype)
        return out

    def scalar(self, name: str, params: dict, xs: list[Scalar], dtype) -> Scalar:
        if name == "convert_element_type" and np.dtype(params["new_dtype"]) == np.dtype(
            _kind_dtype(xs[0])
        ):
            return xs[0]
        done, value = _simplify(name, xs)
        if done:
            return value
        if all(_is_const(x) for x in xs):
            if name in _FOLD:
                return _cast(_FOLD[name](*(np.float64(x) for x in xs)), dtype)
            if name == "select_n":
                return xs[1 + int(xs[0])]
            if name == "convert_element_type":
                return _cast(xs[0], dtype)
            if name == "integer_pow":
                return _cast(np.float64(xs[0]) ** params["y"], dtype)
        if name == "select_n" and _is_const(xs[0]):
            return xs[1 + int(xs[0])]
        if name == "pow" and _is_const(xs[1]) and float(2 * xs[1]).is_integer():
            return self.half_power(xs[0], float(xs[1]), dtype)
        return self.backend.apply(name, params, xs, dtype)

    def half_power(self, x: Scalar, e: float, dtype) -> Scalar:
        """`x ** e` for a constant `e` of whole or half units as `x ** n * sqrt(x)`: `r2 ** 1.5`
        of a gravity field without `pow`, which does not vectorise (to an ulp of `pow`)."""
        n = math.floor(e)
        out = self.scalar("integer_pow", {"y": n}, [x], dtype) if n else None
        if e != n:
            root = self.backend.apply("sqrt", {}, [x], dtype)
            out = root if out is None else self.mul(out, root, dtype)
        return 1.0 if out is None else out

    def add(self, a, b, dtype):
        return self.scalar("add", {}, [a, b], dtype)

    def mul(self, a, b, dtype):
        return self.scalar("mul", {}, [a, b], dtype)

    def run(self, jaxpr, consts: Sequence[np.ndarray], args: Sequence[np.ndarray]):
        env: dict = {}

        def read(v):
            return read_literal(v) if isinstance(v, jex_core.Literal) else env[v]

        for v, x in zip(jaxpr.constvars, consts, strict=True):
            env[v] = x
        for v, x in zip(jaxpr.invars, args, strict=True):
            env[v] = x
        for eqn in _live(jaxpr):
            used = eqn.invars[: len(eqn.invars) - _checked(eqn)]
            ins = [read(v) for v in used]
            outs = self.eqn(eqn, ins)
            for v, x in zip(eqn.outvars, outs, strict=True):
                env[v] = objects(x).reshape(v.aval.shape)
        return [read(v) for v in jaxpr.outvars]

    def eqn(self, eqn, ins: list[np.ndarray]) -> list[np.ndarray]:
        name, p = eqn.primitive.name, eqn.params
        dtype = eqn.outvars[0].aval.dtype if eqn.outvars else None
        if name in ELEMENTWISE:
            return [self.elementwise(name, p, ins, dtype)]
        if name in _IDENTITY:
            return ins
        if _checked(eqn):
            leaves = iter(ins)  # x's leaves (its predicate and index were dropped)
            inner = p["jaxpr"].jaxpr
            return [
                read_literal(v) if isinstance(v, jex_core.Literal) else next(leaves)
                for v in inner.outvars
            ]
        if p.get("name") == "branched_error_if_impl":  # a user's check: the field runs it
            raise Unsupported("equinox.error_if")
        if name == "cond":
            return self.cond(eqn, ins)
        for key in _CALLS:
            if key in p and name not in ("while", "scan"):
                closed = p[key]
                closed_form = hasattr(closed, "consts")
                inner, consts = (closed.jaxpr, closed.consts) if closed_form else (closed, [])
                consts = [np.asarray(c, dtype=object) for c in map(_const_array, consts)]
                return self.run(inner, consts, ins)
        if name in ("unstack", "split"):
            x = ins[0]
            axis = p["axis"]
            if name == "unstack":
                return [objects(np.take(x, i, axis=axis)) for i in range(x.shape[axis])]
            bounds = np.cumsum([0, *p["sizes"]])
            return [
                np.take(x, range(a, b), axis=axis)
                for a, b in zip(bounds[:-1], bounds[1:], strict=False)
            ]
        structural = _STRUCTURAL.get(name)
        if structural is None:
            raise Unsupported(name)
        return [structural(self, p, ins, eqn)]

    def cond(self, eqn, ins: list[np.ndarray]) -> list[np.ndarray]:
        """`lax.cond`/`lax.switch`: the branch of a constant index, else every branch (they are
        pure: `_live` refuses effects) and each output selected by the index (`select_n`, a C
        conditional: an untaken branch's NaN or inf does not reach the result)."""
        which, branches = ins[0], eqn.params["branches"]
        if _is_const(which.reshape(()).item()):
            branches = [branches[int(which.reshape(()).item())]]
        outs = [
            self.run(b.jaxpr, [objects(_const_array(c)) for c in b.consts], ins[1:])
            for b in branches
        ]
        if len(outs) == 1:
            return outs[0]
        cases = zip(eqn.outvars, *outs, strict=True)
        return [self.elementwise("select_n", {}, [which, *xs], v.aval.dtype) for v, *xs in cases]


def _checked(eqn) -> int:
    """How many trailing operands of one of the library's checks `(x..., pred[, index]) -> x...`
    only feed the check (its predicate, and its message index unless constant); 0 for any other
    equation (a differentiated check's tangent part is an identity call, unrolled as any)."""
    if not (eqn.primitive.name == "jit" and eqn.params.get("name") == LIBRARY_CHECK):
        return 0
    kinds = [np.dtype(v.aval.dtype) for v in eqn.invars[-2:]]
    if len(kinds) == 2 and kinds[0] == np.bool_ and np.issubdtype(kinds[1], np.integer):
        return 2
    return 1 if kinds and kinds[-1] == np.bool_ else 0


def _live(jaxpr) -> list:
    """The equations that the outputs need; a runtime check needs only the values it passes
    through (its predicate and message index, and what computes them, are dropped). An effect
    (`jax.debug.print`, ...) is `Unsupported`: dropping it would change what the field does."""
    live = {v for v in jaxpr.outvars if not isinstance(v, jex_core.Literal)}
    keep = []
    for eqn in reversed(jaxpr.eqns):
        if eqn.effects:
            raise Unsupported(eqn.primitive.name)
        if not any(v in live for v in eqn.outvars):
            continue
        keep.append(eqn)
        ins = eqn.invars[: len(eqn.invars) - _checked(eqn)]
        live.update(v for v in ins if not isinstance(v, jex_core.Literal))
    return keep[::-1]


def read_literal(v) -> np.ndarray:
    return np.asarray(_cast(np.asarray(v.val).item(), v.aval.dtype), dtype=object)


def _const_array(c) -> np.ndarray:
    """A constant of an inner jaxpr as NumPy numbers (a tracer cannot be: Unsupported)."""
    if not is_concrete(c):
        raise Unsupported("a traced constant inside a nested call")
    a = np.asarray(c)
    return np.vectorize(lambda x: _cast(x, a.dtype), otypes=[object])(a) if a.size else a


def _kind_dtype(x: Scalar):
    if isinstance(x, bool | np.bool_):
        return np.dtype(bool)
    if isinstance(x, int | np.integer):
        return np.dtype(np.int64)
    return getattr(x, "dtype", None)


def _cast(x, dtype) -> Scalar:
    d = np.dtype(dtype)
    if np.issubdtype(d, np.complexfloating):
        raise Unsupported(f"complex numbers ({d.name})")
    return bool(x) if d == np.bool_ else int(x) if np.issubdtype(d, np.integer) else float(x)


def _broadcast_in_dim(u: _Unroller, p, ins, eqn):
    x, shape = ins[0], p["shape"]
    new = [1] * len(shape)
    for src, dst in enumerate(p["broadcast_dimensions"]):
        new[dst] = x.shape[src]
    return np.broadcast_to(x.reshape(new), shape)


def _slice(u, p, ins, eqn):
    strides = p["strides"] or (1,) * len(p["start_indices"])
    idx = tuple(
        slice(a, b, s)
        for a, b, s in zip(p["start_indices"], p["limit_indices"], strides, strict=True)
    )
    return ins[0][idx]


def _pad(u, p, ins, eqn):
    """`lax.pad`: low, high (negative: cropping) and interior padding per axis."""
    x, value = ins
    value = value.reshape(()).item()
    config = p["padding_config"]
    shape = tuple(
        int(lo + hi + n + max(n - 1, 0) * interior)
        for n, (lo, hi, interior) in zip(x.shape, config, strict=True)
    )
    out = _filled(shape, value)
    for idx in np.ndindex(x.shape):
        at = tuple(
            lo + i * (interior + 1) for i, (lo, _, interior) in zip(idx, config, strict=True)
        )
        if all(0 <= a < n for a, n in zip(at, shape, strict=True)):
            out[at] = x[idx]
    return out


def _static_index(x: np.ndarray, what: str) -> int:
    v = x.reshape(()).item()
    if not _is_const(v):
        raise Unsupported(f"{what} with an index computed at run time")
    return int(v)


def _starts(ins, sizes, shape, what):
    starts = [_static_index(i, what) for i in ins]
    return [min(max(s, 0), n - k) for s, n, k in zip(starts, shape, sizes, strict=True)]


def _dynamic_slice(u, p, ins, eqn):
    x, sizes = ins[0], p["slice_sizes"]
    starts = _starts(ins[1 : 1 + x.ndim], sizes, x.shape, "dynamic_slice")
    return x[tuple(slice(s, s + k) for s, k in zip(starts, sizes, strict=True))]


def _dynamic_update_slice(u, p, ins, eqn):
    x, upd = ins[0].copy(), ins[1]
    starts = _starts(ins[2:], upd.shape, x.shape, "dynamic_update_slice")
    x[tuple(slice(s, s + k) for s, k in zip(starts, upd.shape, strict=True))] = upd
    return x


def _iota(u, p, ins, eqn):
    shape, dim = p["shape"], p["dimension"]
    idx = np.indices(shape)[dim]
    return np.vectorize(lambda i: _cast(i, p["dtype"]), otypes=[object])(idx)


def _empty(u, p, ins, eqn):
    """Uninitialised (zeros here): a `cond`'s residuals of the branch not taken, read only by
    its twin in the cotangent program, whose outputs the index discards (`_Unroller.cond`)."""
    aval = eqn.outvars[0].aval
    return _filled(aval.shape, _cast(0, aval.dtype))


def _reduce(op: str):
    def reduce(u: _Unroller, p, ins, eqn):
        (x,) = ins
        dtype = eqn.outvars[0].aval.dtype
        axes = tuple(p["axes"])
        keep = [a for a in range(x.ndim) if a not in axes]
        x = np.transpose(x, (*keep, *axes)).reshape(*(x.shape[a] for a in keep), -1)
        out = np.empty(x.shape[:-1], dtype=object)
        for idx in np.ndindex(out.shape):
            terms = list(x[idx])
            acc = terms[0]
            for t in terms[1:]:
                acc = u.scalar(op, {}, [acc, t], dtype)
            out[idx] = acc
        return out

    return reduce


def _dot_general(u: _Unroller, p, ins, eqn):
    (lc, rc), (lb, rb) = p["dimension_numbers"]
    lhs, rhs = ins
    dtype = eqn.outvars[0].aval.dtype
    lf = [a for a in range(lhs.ndim) if a not in (*lc, *lb)]
    rf = [a for a in range(rhs.ndim) if a not in (*rc, *rb)]
    L = np.transpose(lhs, (*lb, *lf, *lc))
    R = np.transpose(rhs, (*rb, *rf, *rc))
    nb = math.prod(lhs.shape[a] for a in lb)
    nk = math.prod(lhs.shape[a] for a in lc)
    L = L.reshape(nb, -1, nk)
    R = R.reshape(nb, -1, nk)
    out = np.empty((nb, L.shape[1], R.shape[1]), dtype=object)
    for b in range(nb):
        for i in range(L.shape[1]):
            for j in range(R.shape[1]):
                acc: Scalar = 0.0
                for k in range(nk):
                    acc = u.add(acc, u.mul(L[b, i, k], R[b, j, k], dtype), dtype)
                out[b, i, j] = acc
    shape = (
        *(lhs.shape[a] for a in lb),
        *(lhs.shape[a] for a in lf),
        *(rhs.shape[a] for a in rf),
    )
    return out.reshape(shape)


_STRUCTURAL: dict[str, Callable] = {
    "broadcast_in_dim": _broadcast_in_dim,
    "reshape": lambda u, p, ins, e: ins[0].reshape(p["new_sizes"]),
    "squeeze": lambda u, p, ins, e: np.squeeze(ins[0], axis=tuple(p["dimensions"])),
    "expand_dims": lambda u, p, ins, e: np.expand_dims(ins[0], tuple(p["dimensions"])),
    "transpose": lambda u, p, ins, e: np.transpose(ins[0], p["permutation"]),
    "rev": lambda u, p, ins, e: np.flip(ins[0], tuple(p["dimensions"])),
    "slice": _slice,
    "concatenate": lambda u, p, ins, e: np.concatenate(ins, axis=p["dimension"]),
    "stack": lambda u, p, ins, e: np.stack(ins, axis=p["axis"]),
    "pad": _pad,
    "dynamic_slice": _dynamic_slice,
    "dynamic_update_slice": _dynamic_update_slice,
    "iota": _iota,
    "empty": _empty,
    "empty2": _empty,
    "reduce_sum": _reduce("add"),
    "reduce_max": _reduce("max"),
    "reduce_min": _reduce("min"),
    "reduce_and": _reduce("and"),
    "reduce_or": _reduce("or"),
    "reduce_prod": _reduce("mul"),
    "dot_general": _dot_general,
}


def unroll(
    closed: jex_core.ClosedJaxpr,
    backend: Backend,
    consts: Sequence[np.ndarray],
    args: Sequence[np.ndarray],
) -> list[np.ndarray]:
    """The outputs of `closed` (as object arrays of the backend's scalars) on `args` (object
    arrays of scalars, one per input, in the input's shape), the jaxpr's constants given as
    `consts` in the same form."""
    return _Unroller(backend).run(closed.jaxpr, consts, args)
