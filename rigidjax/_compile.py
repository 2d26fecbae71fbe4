"""`quick_compile_jit`: `eqx.filter_jit` for the large programs that rigidjax compiles once per
call and runs briefly (the fits), with XLA options that halve their compile time.

XLA:CPU's fusion emitters (the default of jaxlib 0.10, measured here) build one LLVM module
per fusion; a fit's program has hundreds of fusions (XLA keeps every division, square root and
arctangent of the forward-mode Jacobian in a fusion of its own), so LLVM dominates the first
call. Its classic
loop emitters (`xla_cpu_use_fusion_emitters=False`) compile the attitude fit of
`benchmarks/bench_identify.py` in 1.9 s instead of 4.4 s, and run it as fast. For
`design_excitation` (second-order derivatives, run time dominating) measured here: first call
8.7–9.3 s instead of 9.5–10.2 s, its default 60 ascent steps 8–16% slower. The option is a CPU
one (other backends ignore it) and is left out where this XLA does not know it.

`SMALL_PROGRAM` adds LLVM's lowest optimisation level, for programs on a few numbers that run
once or a few times (an eager call of a rotation map on one matrix, or its Jacobian): it halves
their compile time again (0.15 → 0.08 s for the forward-mode Jacobian of `so3.log`, measured
here), and leaves the values as they are (IEEE arithmetic at every level: no fast-math).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax

QUICK_COMPILE = {"xla_cpu_use_fusion_emitters": False}
SMALL_PROGRAM = {**QUICK_COMPILE, "xla_backend_optimization_level": 0}


@functools.cache
def quick_compile_options(small: bool = False) -> dict[str, Any]:
    """`QUICK_COMPILE` (`SMALL_PROGRAM` if `small`) if this XLA accepts it (one tiny compile to
    find out), else `{}`."""
    options = SMALL_PROGRAM if small else QUICK_COMPILE
    try:
        jax.jit(lambda x: x, compiler_options=options).lower(0.0).compile()
    except Exception:  # noqa: BLE001 - an XLA without the option: its default emitters
        return {}
    return dict(options)


class quick_compile_jit:  # noqa: N801 - used as a decorator, like eqx.filter_jit
    """`eqx.filter_jit(fn)` compiled with `quick_compile_options(small)`, built at the first call
    (the options need a backend, which importing rigidjax must not start)."""

    def __init__(self, fn: Callable, small: bool = False):
        self._fn = fn
        self._small = small
        self._jitted: Callable | None = None
        functools.update_wrapper(self, fn)

    def __call__(self, *args, **kwargs):
        if self._jitted is None:
            # filter_jit hands keyword arguments other than `donate` to jax.jit (its
            # `jitkwargs`, not in its typed signature)
            jit: Callable[..., Callable] = eqx.filter_jit
            self._jitted = jit(self._fn, compiler_options=quick_compile_options(self._small))
        return self._jitted(*args, **kwargs)
