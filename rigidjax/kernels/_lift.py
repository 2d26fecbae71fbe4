"""Which concrete float constants of a field are lifted into the runtime constants `c` (with the
traced ones, `model.hoist`), so that the C++ depends on their positions and not on their values:
an eager call with a new gain (`lambda t, w, q: -k * w`, a torque module with new array
leaves) reuses the kernel built for the last one instead of building one per value (1–4 s, and
a file in the kernel cache each).

Kept folded into the C++: 0 and the powers of two (±1 among them), whose folding changes the code
(a row of a matrix selected instead of multiplied by 0 and 1, a division by 2 made a product),
and the non-finite values; a literal only where it is an operand of arithmetic or a comparison,
or an argument of a jitted function without `pow` (`jnp.clip(w, -k, k)`, `jnp.where`), written
outside rigidjax: an exponent stays folded, which the scalar program lowers for half-integers as
`x ** n * sqrt(x)`, and so do the literals of the library's own models (Taylor coefficients,
thresholds), which no call changes and which would cost each body a copy per step.
The lifted values are the same numbers at run time, so results do not change."""

from __future__ import annotations

import math
import os
from pathlib import Path

import jax
import jaxlib
import numpy as np
from jax.extend import core as jex_core

from .._checks import LIBRARY_CHECK

_ARITHMETIC = frozenset(
    {"mul", "div", "add", "add_any", "sub", "max", "min", "select_n", "clamp"}
    | {"lt", "le", "gt", "ge", "eq", "ne"}
)


def folded(x: float) -> bool:
    """Whether the constant `x` stays in the C++: 0, ±2^k, ±inf and NaN."""
    if not math.isfinite(x) or x == 0:
        return True
    return abs(math.frexp(x)[0]) == 0.5


def liftable(value, dtype) -> np.ndarray | None:
    """The mask of the elements of a concrete constant `value` lifted into `c` (a float array
    of the solve's `dtype`, not all folded), or None where it stays whole in the C++."""
    x = np.asarray(value)
    if x.dtype != np.dtype(dtype):
        return None
    mask = np.array([not folded(float(v)) for v in x.reshape(-1)], dtype=bool).reshape(x.shape)
    return mask if mask.any() else None


# package folders with their separator: `.../jax/` is not `.../jaxtyping/`
_JAX = tuple(os.path.join(Path(str(m.__file__)).parent, "") for m in (jax, jaxlib))
_LIBRARY = os.path.join(Path(__file__).parents[1], "")


def _in_library(eqn) -> bool:
    """Whether `eqn` was written in rigidjax (its innermost frame outside JAX); False where no
    traceback was recorded."""
    traceback = eqn.source_info.traceback
    for frame in traceback.frames if traceback is not None else ():
        if not frame.file_name.startswith(_JAX):
            return frame.file_name.startswith(_LIBRARY)
    return False


def _has_pow(jaxpr) -> bool:
    return any(e.primitive.name == "pow" for e in jaxpr.eqns) or any(
        _has_pow(inner) for inner in jex_core.subjaxprs(jaxpr)
    )


def _takes_literals(eqn) -> bool:
    """Whether `eqn`'s float literals are lifted: arithmetic, or a jitted function (not one of
    the library's checks) that raises nothing to a power, written outside rigidjax."""
    name = eqn.primitive.name
    if _in_library(eqn):
        return False
    if name == "jit":
        inner = eqn.params["jaxpr"]
        return eqn.params.get("name") != LIBRARY_CHECK and not _has_pow(inner.jaxpr)
    return name in _ARITHMETIC


def literals_as_consts(closed: jex_core.ClosedJaxpr, dtype) -> jex_core.ClosedJaxpr:
    """`closed` with its float literals of `dtype` that are operands at its top level of
    arithmetic or comparisons, or of jitted functions (`_takes_literals`; not `folded`) made
    constants (new constant variables, their values appended to its consts), one per
    occurrence."""
    jaxpr = closed.jaxpr
    new_vars: list = []
    values: list[np.ndarray] = []
    eqns = []
    for eqn in jaxpr.eqns:
        if _takes_literals(eqn):
            invars = []
            for v in eqn.invars:
                literal = isinstance(v, jex_core.Literal)
                value = np.asarray(v.val, getattr(v.aval, "dtype", None)) if literal else None
                if value is not None and liftable(value, dtype) is not None:
                    var = jex_core.Var(v.aval)
                    new_vars.append(var)
                    values.append(value)
                    invars.append(var)
                else:
                    invars.append(v)
            eqn = eqn.replace(invars=invars)
        eqns.append(eqn)
    if not values:
        return closed
    lifted = jaxpr.replace(constvars=[*jaxpr.constvars, *new_vars], eqns=eqns)
    return jex_core.ClosedJaxpr(lifted, [*closed.consts, *values])
