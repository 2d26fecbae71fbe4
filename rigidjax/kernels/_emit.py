"""C++ from a field's scalar operations (`_scalar.unroll`): one `const` statement per operation,
exact hexadecimal constants, IEEE semantics (no reassociation: the kernel repeats the JAX
arithmetic in the same order)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._objects import Scalar, _is_const
from ._scalar import Unsupported


class CExpr(str):
    """A C++ variable holding a scalar of element type `dtype`."""

    dtype: np.dtype

    def __new__(cls, text: str, dtype) -> CExpr:
        out = super().__new__(cls, text)
        out.dtype = np.dtype(dtype)
        return out


def _ctype(dtype) -> str:
    d = np.dtype(dtype)
    if d == np.bool_:
        return "bool"
    if np.issubdtype(d, np.integer):
        return "int64_t"
    return "T"


def literal(x: Scalar) -> str:
    """A constant as C++ (floats exact: `T(0x1.8p+1)`)."""
    if isinstance(x, bool | np.bool_):
        return "true" if x else "false"
    if isinstance(x, int | np.integer):
        return f"int64_t({int(x)})"
    x = float(x)
    if np.isnan(x):
        return "std::numeric_limits<T>::quiet_NaN()"
    if np.isinf(x):
        return f"{'-' if x < 0 else ''}std::numeric_limits<T>::infinity()"
    return f"T({x.hex()})"


_UNARY = {
    "neg": "-{0}",
    "abs": "std::abs({0})",
    "sqrt": "std::sqrt({0})",
    "rsqrt": "T(1) / std::sqrt({0})",
    "cbrt": "std::cbrt({0})",
    "sin": "std::sin({0})",
    "cos": "std::cos({0})",
    "tan": "std::tan({0})",
    "asin": "std::asin({0})",
    "acos": "std::acos({0})",
    "atan": "std::atan({0})",
    "sinh": "std::sinh({0})",
    "cosh": "std::cosh({0})",
    "tanh": "std::tanh({0})",
    "asinh": "std::asinh({0})",
    "acosh": "std::acosh({0})",
    "atanh": "std::atanh({0})",
    "exp": "std::exp({0})",
    "exp2": "std::exp2({0})",
    "log": "std::log({0})",
    "log1p": "std::log1p({0})",
    "expm1": "std::expm1({0})",
    "erf": "std::erf({0})",
    "erfc": "std::erfc({0})",
    "floor": "std::floor({0})",
    "ceil": "std::ceil({0})",
    "square": "{0} * {0}",
    "sign": "T((T(0) < {0}) - ({0} < T(0)))",
    "is_finite": "std::isfinite({0})",
    "not": "!{0}",
    "logistic": "T(1) / (T(1) + std::exp(-{0}))",
}
_BINARY = {
    "add": "{0} + {1}",
    "add_any": "{0} + {1}",
    "sub": "{0} - {1}",
    "mul": "{0} * {1}",
    "div": "{0} / {1}",
    "max": "(({0} > {1} || {0} != {0}) ? {0} : {1})",
    "min": "(({0} < {1} || {0} != {0}) ? {0} : {1})",
    "pow": "std::pow({0}, {1})",
    "atan2": "std::atan2({0}, {1})",
    "rem": "std::fmod({0}, {1})",
    "nextafter": "std::nextafter({0}, {1})",
    "lt": "{0} < {1}",
    "le": "{0} <= {1}",
    "gt": "{0} > {1}",
    "ge": "{0} >= {1}",
    "eq": "{0} == {1}",
    "ne": "{0} != {1}",
    "and": "{0} && {1}",
    "or": "{0} || {1}",
}


class CEmitter:
    """The backend of `_scalar.unroll` that writes C++ statements into `lines`."""

    def __init__(self, prefix: str = "v"):
        self.lines: list[str] = []
        self.prefix = prefix
        self.count = 0

    def operand(self, x: Scalar) -> str:
        return literal(x) if _is_const(x) else str(x)

    def assign(self, expr: str, dtype) -> CExpr:
        name = f"{self.prefix}{self.count}"
        self.count += 1
        self.lines.append(f"const {_ctype(dtype)} {name} = {expr};")
        return CExpr(name, dtype)

    def apply(self, name: str, params: dict, args: Sequence[Scalar], dtype) -> Scalar:
        xs = [self.operand(a) for a in args]
        if name in _UNARY:
            expr = _UNARY[name].format(*xs)
        elif name in _BINARY:
            expr = _BINARY[name].format(*xs)
        elif name == "integer_pow":
            return self._integer_pow(xs[0], int(params["y"]), dtype)
        elif name == "select_n":
            # select_n(which, *cases): cases[which]; a bool `which` picks cases[1] when true
            expr = xs[-1]
            for i in reversed(range(len(xs) - 2)):
                expr = f"({xs[0]} == {i} ? {xs[1 + i]} : {expr})"
            if len(xs) == 3:
                expr = f"({xs[0]} ? {xs[2]} : {xs[1]})"
        elif name == "clamp":
            lo, x, hi = xs
            expr = f"std::min(std::max({x}, {lo}), {hi})"
        elif name == "round":
            nearest_even = int(params.get("rounding_method", 0)) == 1
            expr = f"std::{'nearbyint' if nearest_even else 'round'}({xs[0]})"
        elif name == "convert_element_type":
            expr = f"{_ctype(params['new_dtype'])}({xs[0]})"
        else:
            raise Unsupported(name)
        return self.assign(expr, dtype)

    def _integer_pow(self, x: str, y: int, dtype) -> CExpr:
        """x**y by repeated squaring, in the order of XLA's lowering of `lax.integer_pow`."""
        acc: str | None = None
        n = abs(y)
        while n > 0:
            if n & 1:
                acc = x if acc is None else self.assign(f"{acc} * {x}", dtype)
            n >>= 1
            if n > 0:
                x = self.assign(f"{x} * {x}", dtype)
        if acc is None:
            return self.assign("T(1)", dtype)
        return self.assign(f"T(1) / {acc}" if y < 0 else acc, dtype)
