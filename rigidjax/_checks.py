"""Argument checks shared by every public function: one validation helper (`validate`) that raises a
ValueError on concrete input and an `equinox.error_if` under tracing, with the same message."""

from __future__ import annotations

import numbers
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, TypeVar, overload

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax._src import core as _jax_core  # the trace stack, not in the public `jax.core`
from jax._src.interpreters import partial_eval as _pe
from jaxtyping import Array, DTypeLike, Float

from ._custom_types import Mat33, RealLike


def as_float(x: RealLike, name: str = "x") -> Float[Array, "..."]:
    """`x` as a floating JAX array (integers are promoted to the default float dtype)."""
    if x is None:
        raise TypeError(f"{name} must be an array (or a number), got None")
    try:
        x = jnp.asarray(x)
    except TypeError as e:  # pragma: no cover - message clarity only
        raise TypeError(f"{name} must be array-like, got {type(x).__name__}") from e
    if jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"{name} must be real, got dtype {x.dtype}")
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def floats(*args: tuple[RealLike, str]) -> list[Float[Array, "..."]]:
    """`(x, name)` pairs as float arrays of one common (promoted) dtype, shapes untouched."""
    xs = [as_float(x, name) for x, name in args]
    dtype = jnp.result_type(*xs)
    return [x.astype(dtype) for x in xs]


def check_shape(x: Array, trailing: Sequence[int], name: str) -> None:
    """Raise a ValueError at trace time if `x` does not end in the dimensions `trailing`."""
    trailing = tuple(trailing)
    if x.ndim < len(trailing) or tuple(x.shape[x.ndim - len(trailing) :]) != trailing:
        want = "(..., " + ", ".join(map(str, trailing)) + ")"
        raise ValueError(f"{name} must have shape {want}, got {tuple(x.shape)}")


def vector(x: RealLike, n: int, name: str) -> Float[Array, "*batch _"]:
    """Float array with trailing dimension `n`, checked."""
    x = as_float(x, name)
    check_shape(x, (n,), name)
    return x


def matrix(x: RealLike, name: str) -> Mat33:
    """Float array with trailing shape (3, 3), checked."""
    x = as_float(x, name)
    check_shape(x, (3, 3), name)
    return x


def staging() -> bool:
    """True where a program is being traced to be compiled (inside `jax.jit`, a `scan` body, a
    custom rule's trace...), False in eager code, also under eager `jax.vmap`, `jax.jvp` or
    `jax.grad`, whose operations on concrete arrays run at once. Only where nothing is staged
    may a program be compiled with its own XLA options (a `jit` with `compiler_options` cannot
    be nested), whatever the arguments (arrays captured from outside a `jit` are concrete
    inside it). Read from JAX's trace stack; where a JAX lacks it, True (the plain program: the
    same values)."""
    trace = getattr(getattr(_jax_core, "trace_ctx", None), "trace", None)
    if trace is None:
        return True
    while trace is not None and not isinstance(trace, _jax_core.EvalTrace):
        if isinstance(trace, _pe.DynamicJaxprTrace | _pe.JaxprTrace):
            return True
        trace = getattr(trace, "parent_trace", None)
    return trace is None


def is_concrete(x: object) -> bool:
    """True unless `x` is a tracer (inside jit/vmap/grad): its values can be checked now."""
    return not isinstance(x, jax.core.Tracer)


def concrete_value(x: object) -> np.ndarray | None:
    """The value of `x` as a NumPy array if it is known now, else None: `x` itself if it is not
    a tracer, or the primal of a tracer of `jax.jvp`/`grad`/`jacfwd`/`jacrev` applied to an
    eager call (JAX's `Tracer.to_concrete_value`, which lets Python control flow run under
    `grad`); None inside `jit` and `vmap`, whose values are known only at run time."""
    if isinstance(x, jax.core.Tracer):
        to_value = getattr(x, "to_concrete_value", None)  # absent from other JAX versions
        x = to_value() if to_value is not None else None
        if x is None or isinstance(x, jax.core.Tracer):
            return None
    return np.asarray(x)


def inertia_rtol(dtype: Any) -> float:
    """Relative tolerance of the inertia checks (symmetry, positive definiteness, the triangle
    inequality), `max(1e-9, 1000 eps)` of `dtype`: `RigidBody` and the closed forms alike."""
    return max(1e-9, 1e3 * float(jnp.finfo(dtype).eps))


class Check(NamedTuple):
    """One check: `bad(xp, x)` (xp is NumPy or jax.numpy) is true where `x` fails; the error is
    `message + detail(x) + hint` (the detail, with the offending value, on concrete `x` only)."""

    bad: Callable[[Any, Any], Any]
    message: str
    detail: Callable[[np.ndarray], str] | None = None
    hint: str = ""


_T = TypeVar("_T")


@overload
def validate_all(x: Array, checks: Sequence[Check], on: None = None) -> Array: ...
@overload
def validate_all(x: Array, checks: Sequence[Check], on: _T) -> _T: ...
def validate_all(x: Array, checks: Sequence[Check], on: Any = None) -> Any:
    """Several checks of `x` at the cost of one: the ValueError of the first check that fails
    when the value of `x` is known now (`concrete_value`: concrete `x`, also a constant inside a
    trace or the primal under an eager `grad`/`jacfwd`/`jacrev`; the check runs in NumPy), or
    one `equinox.branched_error_if` carrying the message of the first failing check (`x` known
    only at run time, under jit/vmap). Returns `on` (default `x`; any PyTree) with the run-time
    check attached. The predicates see `x` through `stop_gradient`: they add nothing to
    derivatives.

    The NumPy path also keeps eager derivatives free of `error_if`: each of its run-time checks
    evaluated op by op compiles a new executable with its own host callbacks, which a long
    process accumulates (issue 26: a segmentation fault after some thousands of them)."""
    out = x if on is None else on
    xn = concrete_value(x)
    if xn is not None:
        with np.errstate(all="ignore"):
            for c in checks:
                if np.any(c.bad(np, xn)):
                    raise ValueError(c.message + (c.detail(xn) if c.detail else "") + c.hint)
        return out
    xs = jax.lax.stop_gradient(x)
    fails = jnp.stack([jnp.any(c.bad(jnp, xs)) for c in checks])
    msgs = [c.message + c.hint for c in checks]
    return attach_check(out, jnp.any(fails), jnp.argmax(fails), msgs)


def _library_check(x: Any, pred: Array, index: Array, msgs: tuple[str, ...]) -> Any:
    """`equinox.branched_error_if` under a name of the library's own, which the kernels' scalar
    programs (`kernels/_scalar.py`) recognise: they drop the library's checks of a model's field
    (its state is a unit quaternion by construction) and leave a user's to the Diffrax path."""
    return eqx.branched_error_if(x, pred, index, msgs)


LIBRARY_CHECK = _library_check.__name__
"""The name of the library's run-time checks in a jaxpr (a `jit` equation's `name`)."""
_marked = jax.jit(_library_check, static_argnames="msgs")


def attach_check(out: Any, pred: Array, index: Array, msgs: Sequence[str]) -> Any:
    """`out` (a PyTree) with `equinox.branched_error_if(pred, index, msgs)` attached through a
    scalar: the check's branch passes the scalar, not `out`, which it would copy whole (under
    `jax.vmap`, once per check: a third of a 1e5-body sweep step), and every floating array of
    `out` then depends on the scalar (a zero added to one element, in place), so that the check
    runs whenever `out` is used."""
    leaves, tree = jax.tree_util.tree_flatten(out)
    # strongly typed floating arrays carry it (adding a typed zero would strip a weak type)
    floating = [
        hasattr(a, "dtype")
        and jnp.issubdtype(a.dtype, jnp.inexact)
        and a.size > 0
        and not getattr(getattr(a, "aval", a), "weak_type", False)
        for a in leaves
    ]
    if not any(floating):
        return _marked(out, pred, index, msgs=tuple(msgs))  # nothing to carry a scalar
    flag = _marked(jnp.zeros((), jnp.int32), pred, index, msgs=tuple(msgs))

    def depend(a: Any, f: bool) -> Any:
        if not f:
            return a
        zero = jnp.zeros((), a.dtype) * flag.astype(a.dtype)
        if not a.ndim:
            return a + zero
        at = (0,) * a.ndim  # (an update in place, not a scatter: the kernels unroll it)
        return jax.lax.dynamic_update_slice(a, a[(slice(0, 1),) * a.ndim] + zero, at)

    return jax.tree_util.tree_unflatten(
        tree, [depend(a, f) for a, f in zip(leaves, floating, strict=True)]
    )


def first(mask: Any) -> tuple[int, ...]:
    """Index of the first true entry of a batch mask (`()` for a single element)."""
    mask = np.asarray(mask)
    return tuple(int(i) for i in np.unravel_index(int(np.argmax(mask)), mask.shape))


def at(name: str, k: tuple[int, ...]) -> str:
    return name + (f"[{', '.join(map(str, k))}]" if k else "")


def fmt(v: Any) -> str:
    """An array on one line, 6 significant digits."""
    return " ".join(np.array2string(np.asarray(v), precision=6, separator=", ").split())


def validate(
    x: Array,
    bad: Callable[[Any, Any], Any],
    message: str,
    detail: Callable[[np.ndarray], str] | None = None,
    *,
    hint: str = "",
    on: Array | None = None,
) -> Array:
    """Check `x` with `bad(xp, x) -> bool array` (`xp` is NumPy or `jax.numpy`) and raise a clear
    error if any entry is true: a ValueError `message + detail(x) + hint` at once when `x` is
    concrete, else an `equinox` run-time error with `message + hint` under jit/vmap (one
    `Check` of `validate_all`).

    Returns `on` (default `x`), to which the run-time check is attached: use the returned value
    (an unused check is removed with the dead code). For a check made only on concrete values
    (e.g. where traced callers expect NaN), guard the call with `is_concrete(x)`."""
    return validate_all(x, [Check(bad, message, detail, hint)], x if on is None else on)


def _got(v: np.ndarray) -> str:
    return f", got {v}"


def check_frame(frame: object, name: str = "frame") -> None:
    """A frame argument: `"space"` (Zhilin's "left") or `"body"` ("right"); anything else (a
    typo such as "inertial" or "Space") is a ValueError, never silently one of them."""
    if frame not in ("space", "body"):
        raise ValueError(
            f"{name} must be 'space' or 'body' (Zhilin's 'left' and 'right'), got {frame!r}"
        )


def check_finite(x: Array, name: str) -> Array:
    """`x`, checked to be finite everywhere (see `validate`); the error shows the first
    non-finite entry."""

    def detail(v: np.ndarray) -> str:
        if v.ndim == 0:
            return f", got {v}"
        k = first(~np.isfinite(v))
        return f": {at(name, k)} = {fmt(v[k])}"

    return validate(x, lambda xp, v: ~xp.isfinite(v), f"{name} must be finite", detail)


def zero_vector(xp: Any, x: Any) -> Any:
    """`validate` predicate: true where the vector `x (..., n)` (last axis) is zero or NaN."""
    return ~(xp.sum(x * x, axis=-1) > 0)


def check_positive(x: Array, name: str) -> Array:
    """`x`, checked to be positive and finite everywhere (see `validate`)."""
    return validate(
        x, lambda xp, v: ~((v > 0) & xp.isfinite(v)), f"{name} must be positive and finite", _got
    )


def check_nonnegative(x: Array, name: str, what: str, hint: str = "") -> Array:
    """`x`, checked to be non-negative and finite everywhere (see `validate`); `what`, its kind
    (a unit, "a length"), goes into the message."""
    return validate(
        x,
        lambda xp, v: ~((v >= 0) & xp.isfinite(v)),
        f"{name} must be non-negative and finite ({what})",
        lambda v: f", got {v}" if v.ndim == 0 else f", got min {np.min(v)}",
        hint=hint,
    )


def norm_tolerance(dtype: DTypeLike) -> float:
    """Tolerance of the checks of unit quaternions and vectors and of rotation matrices: 1e-6 in
    float64, 1e-4 in lower precision."""
    return 1e-6 if dtype == jnp.float64 else 1e-4


def check_unit_norm(x: Array, name: str, hint: str = "") -> Array:
    """`x (..., n)`, checked to have unit norm within `norm_tolerance` (see `validate`): a unit
    quaternion (w, x, y, z) when n = 4, else a unit vector. The error names `name`, the
    offending norm (concrete `x`) and the fix `hint`; by default "normalise it with
    rigidjax.quat.normalize" for quaternions."""
    tol = norm_tolerance(x.dtype)
    quaternion = x.shape[-1] == 4
    if not hint:
        hint = "; normalise it with rigidjax.quat.normalize" if quaternion else "; normalise it"

    def bad(xp: Any, v: Any) -> Any:
        return ~(xp.abs(xp.sqrt(xp.sum(v * v, axis=-1)) - 1) <= tol)

    def detail(v: np.ndarray) -> str:
        n = np.linalg.norm(v, axis=-1)
        if n.ndim == 0:
            return f": |{name}| = {n:.9g}"
        k = np.unravel_index(np.argmax(np.abs(n - 1)), n.shape)  # the worst (NaN first)
        return f": |{name}[{', '.join(map(str, k))}]| = {n[k]:.9g}"

    what = "quaternion (w, x, y, z)" if quaternion else "vector"
    return validate(x, bad, f"{name} must be a unit {what}", detail, hint=hint)


def initial_vector(x: RealLike, n: int, name: str, dtype: DTypeLike) -> Float[Array, " n"]:
    """One finite `(n,)` vector of `dtype`, for integrators that take a single state (a batch
    gets an error pointing to `jax.vmap`)."""
    x = vector(x, n, name).astype(dtype)
    if x.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) (jax.vmap for batches), got {x.shape}")
    return check_finite(x, name)


def check_times_shape(ts: Array, name: str = "ts") -> Float[Array, " T"]:
    """`ts`, if it is a 1-D array of at least two times (a ValueError otherwise)."""
    if ts.ndim != 1 or ts.shape[0] < 2:
        raise ValueError(
            f"{name} must be a 1-D array of at least 2 times, got shape {tuple(ts.shape)}"
        )
    return ts


def check_times(ts: Array, name: str = "ts") -> Float[Array, " T"]:
    """`ts` as a 1-D, finite, strictly increasing array of at least two times (clear error
    otherwise)."""
    check_times_shape(ts, name)

    def detail(t: np.ndarray) -> str:
        if not np.all(np.isfinite(t)):
            k = int(np.flatnonzero(~np.isfinite(t))[0])
            return f": {name}[{k}] = {t[k]}"
        k = int(np.flatnonzero(~(np.diff(t) > 0))[0])
        return f": {name}[{k + 1}] = {t[k + 1]} follows {name}[{k}] = {t[k]}"

    return validate(
        ts,
        lambda xp, t: ~xp.isfinite(t[1:]) | ~(xp.diff(t) > 0),
        f"{name} must be strictly increasing and finite",
        detail,
    )


def integer(x: object, name: str, low: int = 1) -> int:
    """`x` as a Python int: an integer (Python or NumPy, not a bool) of at least `low`, else a
    ValueError naming `name`."""
    if not (isinstance(x, numbers.Integral) and not isinstance(x, bool) and int(x) >= low):
        kind = {0: "a non-negative integer", 1: "a positive integer"}.get(low, f"≥ {low}")
        raise ValueError(f"{name} must be {kind}, got {x!r}")
    return int(x)


def broadcast_level(
    shape: tuple[int, ...], target: tuple[int, ...], name: str, what: str, *, extend: bool = False
) -> tuple[int, ...]:
    """`shape` (a noise level's, say) broadcast against `target`, which it may enlarge only with
    `extend`; where it does not, a ValueError naming `name`, the target (`what`) and the shape."""
    try:
        out = tuple(np.broadcast_shapes(shape, target))
    except ValueError:
        out = None
    if out is None or (not extend and out != tuple(target)):
        raise ValueError(
            f"{name} must be a scalar or an array broadcasting {what}, e.g. (3,) per body axis; "
            f"got shape {tuple(shape)}"
        )
    return out


def broadcast_batch(**shapes: tuple[int, ...]) -> tuple[int, ...]:
    """The common batch shape of the arguments' batch shapes `name=shape` (NumPy broadcasting);
    a ValueError naming the arguments and their batch shapes if they do not broadcast."""
    try:
        return tuple(np.broadcast_shapes(*shapes.values()))
    except ValueError:
        given = ", ".join(f"{name} {s}" for name, s in shapes.items())
        raise ValueError(
            f"the batch shapes (leading dimensions) do not broadcast: {given}; give them equal "
            "leading dimensions, or 1 (or none) where one value serves the whole batch"
        ) from None
