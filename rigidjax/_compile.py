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

from ._checks import staging

QUICK_COMPILE = {"xla_cpu_use_fusion_emitters": False}
SMALL_PROGRAM = {**QUICK_COMPILE, "xla_backend_optimization_level": 0}


class quick_compile_jit:  # noqa: N801 - used as a decorator, like eqx.filter_jit
    """`eqx.filter_jit(fn)` compiled with `QUICK_COMPILE` (`SMALL_PROGRAM` if `small`), built at
    the first call (the options need a backend, which importing rigidjax must not start). An XLA
    that does not know the options rejects them at that first compile ("No such compile
    option"): then `fn` is compiled with its defaults, for good. (No probe compile to find out
    first: it cost 5-10 ms of a rotation map's 50 ms first call, measured here.) Where a program
    is being staged (`_checks.staging`: a `jit` with its arguments or constants captured from
    outside, a `scan` body, a custom rule's trace) it is the plain `eqx.filter_jit(fn)`, nested
    in the caller's program: XLA takes options only at the top."""

    def __init__(self, fn: Callable, small: bool = False):
        self._fn = fn
        self._options = dict(SMALL_PROGRAM if small else QUICK_COMPILE)
        self._jitted: Callable | None = None
        self._plain = eqx.filter_jit(fn)
        functools.update_wrapper(self, fn)

    def __call__(self, *args, **kwargs):
        if staging():  # the plain program, nested in the one being staged
            return self._plain(*args, **kwargs)
        if self._jitted is None:
            self._jitted = self._build(self._options)
        try:
            return self._jitted(*args, **kwargs)
        except jax.errors.JaxRuntimeError as e:
            if not self._options or "No such compile option" not in str(e):
                raise
            self._options = {}
            self._jitted = self._build({})
            return self._jitted(*args, **kwargs)

    def _build(self, options: dict[str, Any]) -> Callable:
        # filter_jit hands keyword arguments other than `donate` to jax.jit (its `jitkwargs`,
        # not in its typed signature)
        jit: Callable[..., Callable] = eqx.filter_jit
        return jit(self._fn, compiler_options=options)
