"""Small shared helpers: argument checks and Taylor-guarded coefficient evaluation."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike


def as_float(x: ArrayLike, name: str = "x") -> Array:
    """`x` as a floating JAX array (integers are promoted to the default float dtype)."""
    try:
        x = jnp.asarray(x)
    except TypeError as e:  # pragma: no cover - message clarity only
        raise TypeError(f"{name} must be array-like, got {type(x).__name__}") from e
    if jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"{name} must be real, got dtype {x.dtype}")
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def check_shape(x: Array, trailing: Sequence[int], name: str) -> None:
    """Raise a ValueError at trace time if `x` does not end in the dimensions `trailing`."""
    trailing = tuple(trailing)
    if x.ndim < len(trailing) or tuple(x.shape[x.ndim - len(trailing) :]) != trailing:
        want = "(..., " + ", ".join(map(str, trailing)) + ")"
        raise ValueError(f"{name} must have shape {want}, got {tuple(x.shape)}")


def vector(x: ArrayLike, n: int, name: str) -> Array:
    """Float array with trailing dimension `n`, checked."""
    x = as_float(x, name)
    check_shape(x, (n,), name)
    return x


def matrix(x: ArrayLike, name: str) -> Array:
    """Float array with trailing shape (3, 3), checked."""
    x = as_float(x, name)
    check_shape(x, (3, 3), name)
    return x


def small_threshold(dtype) -> float:
    """Below this value of θ² the truncated Taylor series is used instead of the closed form.

    Four-term series are accurate to ~x⁴/9! there; the closed forms lose ~eps/x to cancellation
    just above it, so the threshold depends on the precision.
    """
    return 1e-2 if jnp.finfo(dtype).eps < 1e-10 else 1e-1


def guarded(x2: Array, exact: Callable[[Array], Array], series: Callable[[Array], Array]) -> Array:
    """Evaluate f(x²) by `series` near 0 and `exact` elsewhere, with finite values AND gradients.

    The double-`where` trick: the exact branch is fed a harmless value where it is not selected,
    so its (discarded) derivative cannot be NaN (jax#1052).
    """
    small = x2 < small_threshold(x2.dtype)
    x2_safe = jnp.where(small, jnp.ones_like(x2), x2)
    return jnp.where(small, series(x2), exact(x2_safe))


def poly(x: Array, coeffs: Sequence[float]) -> Array:
    """Horner evaluation of Σ coeffs[k] x^k."""
    out = jnp.full_like(x, coeffs[-1])
    for c in reversed(coeffs[:-1]):
        out = out * x + c
    return out


def validate(
    x: Array,
    bad: Callable,
    message: str,
    detail: Callable[[np.ndarray], str] | None = None,
) -> Array:
    """Check `x` with `bad(xp, x) -> bool array` and return it, raising a clear error if any is
    true: a ValueError at once (with `detail(x)` appended) when `x` is concrete, else an
    `equinox.error_if` that raises at run time under jit/vmap. The concrete check runs in NumPy,
    so it works on constants inside a trace as well."""
    if isinstance(x, jax.core.Tracer):
        return eqx.error_if(x, jnp.any(bad(jnp, x)), message)
    xn = np.asarray(x)
    if np.any(bad(np, xn)):
        raise ValueError(message + (detail(xn) if detail is not None else ""))
    return x
