"""`compiled`: the cores of the rotation maps as cached compiled programs, so that an eager call,
and an eager `jax.jacfwd`/`jacrev`/`grad` of it, costs one compilation (issue 26).

Op by op, an eager call of a map dispatches (and on its first call compiles) dozens of small
programs, its derivatives several times more: seconds in a fresh process. Instead:

- concrete arrays where no program is being staged (`_checks.staging`: not inside a `jit`
  that captured them, a `scan` body, ...; eager `vmap`/`jvp` stage nothing): one program,
  `rigidjax._compile.quick_compile_jit` (XLA's classic CPU emitters, which compile these small
  programs about twice as fast; for single elements also
  LLVM's lowest optimisation level, `SMALL_PROGRAM`);
- tracers of an eager `jvp`/`grad`/`jacfwd`/`jacrev` (their primal known, `concrete_value`) of
  single elements (no batch dimensions): a `jax.custom_jvp` whose tangent is `J · dx`, with the
  value and the Jacobian `J` (forward mode through the same core) from one quick-compiled program
  on the primal; the remaining linear map is one small operation in any transformation;
- anything else (under `jit`, `vmap`, batched derivatives): `equinox.filter_jit` of the core,
  nested in the caller's program and differentiated as usual.

Each is compiled once per shape, dtype and static arguments (the arguments that are not arrays:
a sequence string, a check mode) and kept for the process: a long process of eager checks
compiles a bounded number of programs."""

from __future__ import annotations

import functools
import operator
from collections.abc import Callable, Hashable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero

from .._checks import concrete_value, is_concrete, staging
from .._compile import quick_compile_jit


class compiled:  # noqa: N801 - used as a decorator, like eqx.filter_jit
    """`core(*arrays, **static)` (arrays with `ndims[i]` core dimensions and leading batch
    dimensions; static keyword arguments) compiled as described in the module docstring."""

    def __init__(self, *ndims: int) -> None:
        self._ndims = ndims

    def __call__(self, core: Callable) -> Callable:
        return _Compiled(core, self._ndims)


class _Compiled:
    def __init__(self, core: Callable, ndims: tuple[int, ...]) -> None:
        self._core = core
        self._ndims = ndims
        self._quick = quick_compile_jit(core)
        self._small = quick_compile_jit(core, small=True)
        self._plain = eqx.filter_jit(core)
        functools.update_wrapper(self, core)

    def __call__(self, *arrays: Any, **static: Hashable) -> Any:
        single = all(jnp.ndim(a) == n for a, n in zip(arrays, self._ndims, strict=True))
        if all(map(is_concrete, arrays)) and not staging():
            return (self._small if single else self._quick)(*arrays, **static)
        if single and all(concrete_value(a) is not None for a in arrays):
            return self._differentiated(tuple(sorted(static.items())))(*arrays)
        return self._plain(*arrays, **static)

    @functools.cache  # noqa: B019 - one per map and static arguments, kept for the process
    def _differentiated(self, static: tuple[tuple[str, Hashable], ...]) -> Callable:
        """`core(*, **static)` with the tangent `Σ_k J_k · dx_k` (`J_k = ∂ out/∂ x_k`, over the
        arguments with a non-zero tangent)."""
        kwargs = dict(static)

        def value_and_jacobians(*x: Any, argnums: tuple[int, ...]) -> tuple[Any, tuple]:
            # the value as `jacfwd`'s auxiliary output: the core traced once, not twice (7-10
            # ms less to trace and compile, measured here)
            def value_twice(*x: Any) -> tuple[Any, Any]:
                y = self._core(*x, **kwargs)
                return y, y

            if not argnums:
                return self._core(*x, **kwargs), ()
            jacobians, out = jax.jacfwd(value_twice, argnums=argnums, has_aux=True)(*x)
            return out, jacobians

        quick = quick_compile_jit(value_and_jacobians, small=True)
        plain = eqx.filter_jit(value_and_jacobians)

        @jax.custom_jvp
        def f(*x: Any) -> Any:
            return self._plain(*x, **kwargs)

        def f_jvp(primals: tuple, tangents: tuple) -> tuple[Any, Any]:
            # Jacobians only for the arguments with a tangent (`so3.distance(E, P)`: P's)
            live = tuple(k for k, t in enumerate(tangents) if not isinstance(t, SymbolicZero))
            vj = quick if all(map(is_concrete, primals)) and not staging() else plain
            out, jacobians = vj(*primals, argnums=live)
            if not live:
                return out, jnp.zeros_like(out)
            terms = [
                jnp.tensordot(J, tangents[k], axes=jnp.ndim(tangents[k]))
                for J, k in zip(jacobians, live, strict=True)
            ]
            return out, functools.reduce(operator.add, terms)  # no `0 +`: one op less

        f.defjvp(f_jvp, symbolic_zeros=True)
        return f
