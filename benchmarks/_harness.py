"""The benchmark harness shared by every bench script (the machine record, the command line,
the tables and the JSON writer are in `_record`, the C and CUDA references in `_c_reference`;
this module re-exports `_record`).

Timing: `measure` compiles a callable ahead of time (`aot_compile`, trace + lower and XLA compile
timed separately), warms it up with one timed first call, then times repeated calls; every call
ends in `jax.block_until_ready` and records wall and process-CPU seconds (`timed`). It returns a
`Timing`: `best`, `median`, `times`, `cpu_times`, the compile and first-call times and the latest
output. `interleaved` times several `Timing`s in rounds (each round calls each once, so a change
in machine load hits them alike); `fresh_process` runs a worker in a new interpreter, for
first-call times, and `worker` reads its answer or its error."""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from _record import (  # noqa: F401  (re-exported: the scripts import one module)
    RESULTS,
    Log,
    execute,
    figure,
    finish,
    load_average,
    load_report,
    machine_info,
    parser,
    print_targets,
    table,
    target,
    timestamp,
    write_json,
)

# --------------------------------------------------------------------------- timing


def block(x):
    """`x` with every array in it computed (`jax.block_until_ready`): timings end here."""
    import jax

    return jax.block_until_ready(x)


def aot_compile(fn: Callable, *args) -> tuple[Callable, dict[str, float]]:
    """`jax.jit(fn)` lowered and compiled ahead of time for `args`; returns the compiled callable
    and `{"trace_lower_s", "compile_s", "total_s"}` (nothing is run)."""
    import jax

    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    return compiled, {"trace_lower_s": t1 - t0, "compile_s": t2 - t1, "total_s": t2 - t0}


def timed(fn: Callable, *args, **kwargs) -> tuple[Any, float, float]:
    """Run `fn(*args, **kwargs)` once to completion (`block_until_ready`); returns
    `(result, wall seconds, process CPU seconds)`."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = block(fn(*args, **kwargs))
    return out, time.perf_counter() - t0, time.process_time() - c0


class Timing:
    """One callable under measurement, with its fixed arguments: optionally compiled ahead of
    time (`aot=True`: `trace_lower_s`, `compile_s`), warmed up (`warm_up`: `first_run_s`), then
    timed (`run`: wall `times` and CPU `cpu_times`). `output` is the result of the latest call;
    `fn` the (compiled) callable."""

    def __init__(self, fn: Callable, *args, aot: bool = True):
        self.args = args
        self.trace_lower_s: float | None = None
        self.compile_s: float | None = None
        if aot:
            fn, c = aot_compile(fn, *args)
            self.trace_lower_s, self.compile_s = c["trace_lower_s"], c["compile_s"]
        self.fn = fn
        self.first_run_s: float | None = None
        self.output: Any = None
        self.times: list[float] = []
        self.cpu_times: list[float] = []

    def warm_up(self) -> Any:
        """One call, timed as `first_run_s` but not counted among `times`; returns its output."""
        self.output, self.first_run_s, _ = timed(self.fn, *self.args)
        return self.output

    def run(self, repeats: int = 1, min_total: float = 0.0, max_calls: int = 200) -> Timing:
        """Timed calls: at least `repeats`, and more until `min_total` seconds of timed calls are
        spent in all (at most `max_calls`)."""
        n = 0
        while n < repeats or (sum(self.times) < min_total and len(self.times) < max_calls):
            self.output, wall, cpu = timed(self.fn, *self.args)
            self.times.append(wall)
            self.cpu_times.append(cpu)
            n += 1
        return self

    @property
    def trace_lower_compile_s(self) -> float | None:
        """Trace + lower + XLA compile (None without `aot`)."""
        if self.trace_lower_s is None or self.compile_s is None:
            return None
        return self.trace_lower_s + self.compile_s

    @property
    def first_call_s(self) -> float | None:
        """Trace + lower + compile + first run: what a first call costs."""
        if self.trace_lower_compile_s is None or self.first_run_s is None:
            return None
        return self.trace_lower_compile_s + self.first_run_s

    def first_call_record(self) -> dict:
        """What the first call cost: `trace_lower_s`, `compile_s`, `trace_lower_compile_s`,
        `first_run_s` and `first_call_s` (their sum)."""
        keys = ("trace_lower_s", "compile_s", "trace_lower_compile_s", "first_run_s")
        return {k: getattr(self, k) for k in (*keys, "first_call_s")}

    @property
    def repeats(self) -> int:
        return len(self.times)

    @property
    def best(self) -> float:
        """The minimum wall time: the run least disturbed by other processes."""
        return min(self.times)

    @property
    def median(self) -> float:
        return statistics.median(self.times)

    @property
    def cpu_best(self) -> float:
        return min(self.cpu_times)

    def summary(self, cpu: bool = False) -> dict:
        """`{"seconds": best, "seconds_median", "all_seconds"}`, with `cpu`: also
        `"cpu_seconds"` (best) and `"all_cpu_seconds"`."""
        out = {"seconds": self.best, "seconds_median": self.median, "all_seconds": list(self.times)}
        if cpu:
            out.update(cpu_seconds=self.cpu_best, all_cpu_seconds=list(self.cpu_times))
        return out


def measure(
    fn: Callable,
    *args,
    repeats: int,
    aot: bool = True,
    warmup: bool = True,
    min_total: float = 0.0,
) -> Timing:
    """Compile `fn` ahead of time for `args` (unless `aot=False`: a NumPy / SciPy callable or one
    compiled already), call it once as warm-up (unless `warmup=False`), then time `repeats` calls
    (more until `min_total` seconds, see `Timing.run`)."""
    t = Timing(fn, *args, aot=aot)
    if warmup:
        t.warm_up()
    return t.run(repeats, min_total=min_total)


def interleaved(
    timings: Iterable[Timing], repeats: int, after_round: Callable[[int], None] | None = None
) -> None:
    """`repeats` rounds, each calling every timing once in order (`Timing.run(1)`), so a change
    in machine load hits all of them alike; `after_round(r)` runs after round r (0-based)."""
    timings = list(timings)
    for r in range(repeats):
        for t in timings:
            t.run(1)
        if after_round is not None:
            after_round(r)


def fresh_process(
    script: str | Path, *args: str, env: dict | None = None
) -> tuple[dict | None, float, subprocess.CompletedProcess]:
    """Run `python script *args` in a fresh interpreter (first-call costs: nothing compiled or
    imported yet); returns the JSON object on the last line of its stdout (None if it failed),
    the process's wall seconds and the completed process (for `stderr`, `returncode`)."""
    cmd = [sys.executable, str(Path(script).resolve()), *args]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        return None, wall, proc
    return json.loads(proc.stdout.strip().splitlines()[-1]), wall, proc


def worker(script: str | Path, *args: str, env: dict | None = None, cold: bool = False) -> dict:
    """`fresh_process`'s answer with its `process_wall_s`, or `{"error": the end of its stderr,
    "returncode"}` where it failed; `cold`: with JAX's persistent compilation cache off."""
    if cold:
        env = {k: v for k, v in (env or os.environ).items() if "COMPILATION_CACHE" not in k}
        env["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    res, wall, proc = fresh_process(script, *args, env=env)
    if res is None:
        return dict(error=proc.stderr[-4000:], returncode=proc.returncode)
    res["process_wall_s"] = wall
    return res


def maxrss_mib() -> float:
    """This process's peak resident memory so far (`ru_maxrss`), MiB."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # Linux: KiB, macOS: bytes
    return round(r / (1024**2 if sys.platform == "darwin" else 1024), 1)


MEMORY_FIELDS = (
    "temp_size_in_bytes",
    "argument_size_in_bytes",
    "output_size_in_bytes",
    "alias_size_in_bytes",
    "generated_code_size_in_bytes",
)


def memory_analysis(compiled) -> dict | None:
    """XLA's buffer sizes of a compiled program (`compiled.memory_analysis()`), bytes."""
    try:
        m = compiled.memory_analysis()
    except Exception as e:  # pragma: no cover
        return dict(error=repr(e))
    if m is None:  # pragma: no cover
        return None
    return {k: int(getattr(m, k)) for k in MEMORY_FIELDS if hasattr(m, k)}
