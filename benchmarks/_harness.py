"""The benchmark harness shared by every bench script: ahead-of-time compilation with its timing,
timed calls (wall and CPU time, results blocked until ready), repeats and their summary, the
machine and version facts recorded in every JSON, and the atomic JSON writer."""

from __future__ import annotations

import importlib.metadata
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

PACKAGES = ("jax", "jaxlib", "diffrax", "equinox", "optimistix", "numpy", "scipy", "rigidjax")


def load_average() -> list[float] | None:
    """1/5/15-minute system load: other processes on the cores skew every timing."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (OSError, AttributeError):  # pragma: no cover - not on every platform
        return None


def _git(*cmd: str) -> subprocess.CompletedProcess | None:
    # read-only queries; GIT_OPTIONAL_LOCKS=0: never refresh (write) the index
    try:
        return subprocess.run(
            ["git", *cmd],
            capture_output=True,
            text=True,
            cwd=Path(__file__).resolve().parent,
            env={**os.environ, "GIT_OPTIONAL_LOCKS": "0"},
            check=False,
        )
    except OSError:
        return None


def _version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def machine_info() -> dict:
    """Platform, cores, JAX backend and devices, package versions, git commit and whether
    `rigidjax/` has uncommitted changes, and the load average now."""
    import jax

    rev = _git("rev-parse", "HEAD")
    diff = _git("diff", "--quiet", "HEAD", "--", "rigidjax")
    return dict(
        platform=platform.platform(),
        processor=platform.processor() or platform.machine(),
        python=sys.version.split()[0],
        cpu_count=os.cpu_count(),
        jax_backend=jax.default_backend(),
        jax_devices=[str(d) for d in jax.devices()],
        versions={name: _version(name) for name in PACKAGES},
        git_commit=rev.stdout.strip() if rev is not None else "",
        rigidjax_has_uncommitted_changes=(
            None if diff is None or diff.returncode > 1 else diff.returncode == 1
        ),
        loadavg_at_record=load_average(),
    )


def write_json(path: Path, obj) -> None:
    """Write `obj` as indented JSON to `path` atomically (a killed run leaves the old file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(obj, indent=2) + "\n")
    tmp.replace(path)


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


def timed(fn: Callable, *args) -> tuple[object, float, float]:
    """Run `fn(*args)` once to completion; returns `(result, wall seconds, CPU seconds)`."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = block(fn(*args))
    return out, time.perf_counter() - t0, time.process_time() - c0


def repeat(
    fn: Callable,
    *args,
    repeats: int,
    warmup: bool = False,
    min_total: float = 0.0,
    max_calls: int = 200,
) -> list[float]:
    """Wall times of repeated calls `fn(*args)` (after one untimed call if `warmup`): at least
    `repeats`, and more until `min_total` seconds are spent (at most `max_calls`)."""
    if warmup:
        block(fn(*args))
    times: list[float] = []
    while len(times) < repeats or (sum(times) < min_total and len(times) < max_calls):
        times.append(timed(fn, *args)[1])
    return times


def summary(times: list[float]) -> dict:
    """`{"seconds": best, "seconds_median", "all_seconds"}` of a list of wall times (the best is
    the least disturbed by other processes; the median shows the spread)."""
    return {
        "seconds": min(times),
        "seconds_median": statistics.median(times),
        "all_seconds": list(times),
    }
