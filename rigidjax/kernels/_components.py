"""The backend of `_scalar.unroll` that evaluates a field's scalar operations with JAX on one
array per scalar: a `(B,)` batch of a state component on the Diffrax path (XLA fuses the stages
into one loop over the bodies, with no gathers or stacks), or a `(128,)` register vector in a
GPU kernel."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ._objects import Scalar, _is_const


class Components:
    """The backend that evaluates each scalar operation with `jax.lax` on arrays (one array per
    scalar: a `(B,)` batch of a state component, or a scalar); constants stay Python numbers
    and broadcast."""

    def apply(self, name: str, params: dict, args: Sequence[Scalar], dtype) -> Scalar:
        floats = [
            a.dtype for a in args if not _is_const(a) and jnp.issubdtype(a.dtype, jnp.floating)
        ]
        # the float operands in the result's type (a `dot_general` of float32 and float64
        # operands, unrolled, multiplies float32 scalars into a float64 result)
        real = dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(*floats, dtype)
        xs = [
            jnp.asarray(a, _const_dtype(a, real))
            if _is_const(a)
            else a.astype(real)
            if jnp.issubdtype(a.dtype, jnp.floating) and name != "convert_element_type"
            else a
            for a in args
        ]
        shape = jnp.broadcast_shapes(*(jnp.shape(x) for x in xs))
        xs = [jnp.broadcast_to(x, shape) for x in xs]
        if name == "integer_pow":
            return jax.lax.integer_pow(xs[0], params["y"])
        if name == "convert_element_type":
            return jax.lax.convert_element_type(xs[0], params["new_dtype"])
        if name == "round":
            return _round(xs[0], int(params.get("rounding_method", 0)))
        return _LAX[name](*xs) if name in _LAX else getattr(jax.lax, name)(*xs)


def _round(x, method: int):
    """`lax.round(x, method)` (0: halves away from zero, 1: to even) built from `floor`, equal
    for every float (Pallas' Triton lowering has no `round`): `f = ⌊|x|⌋`, `d = |x| − f` exact,
    `f` raised by 1 where `d > ½`, or `d = ½` and (away from zero, or `f` odd); the sign of `x`
    restored."""
    a = jnp.abs(x)
    f = jnp.floor(a)
    d = a - f
    odd = f - 2 * jnp.floor(0.5 * f) == 1
    up = (d > 0.5) | ((d == 0.5) & (odd if method == 1 else True))
    r = jnp.where(up, f + 1, f)
    return jnp.where(x < 0, -r, jnp.where(x > 0, r, 0 * x))  # ±0 (and ±denormals, NaN)


_LAX: dict[str, Callable] = {
    "add_any": jax.lax.add,
    "not": jax.lax.bitwise_not,
    "and": jax.lax.bitwise_and,
    "or": jax.lax.bitwise_or,
}


def _const_dtype(a: Scalar, real):
    """A constant's element type beside arrays whose floats are `real`."""
    if isinstance(a, bool | np.bool_):
        return jnp.bool_
    if isinstance(a, int | np.integer):
        return jnp.int32
    return real
