"""What every bench script writes around its numbers: the command line (`parser`), the progress
log (`Log`), the machine record (`machine_info`, `load_average`), the verdicts (`target`), the
printed table (`table`), the figure (`figure`) and the JSON file (`write_json`, closed by
`finish`)."""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import re
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

PACKAGES = ("jax", "jaxlib", "diffrax", "equinox", "optimistix", "numpy", "scipy", "rigidjax")
RESULTS = Path(__file__).resolve().parent / "results"


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


def timestamp() -> str:
    """Now, UTC, to the second (ISO 8601)."""
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def write_json(path: Path, obj) -> None:
    """Write `obj` as indented JSON to `path` atomically (a killed run leaves the old file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(obj, indent=2) + "\n")
    tmp.replace(path)


def load_report(out: dict) -> str:
    """The closing line of a run: load averages at start and end, and the total wall time."""
    return (
        f"load average start {out['load_average_start']}, end {out['load_average_end']}; "
        f"total {out['total_wall_s']:.0f} s"
    )


def finish(out: dict, path: Path, t0: float) -> None:
    """Close a run: the load average at the end and the wall time since `t0` into `out`,
    written atomically to `path`, and the closing line printed."""
    out["load_average_end"] = load_average()
    out["total_wall_s"] = time.perf_counter() - t0
    write_json(Path(path), out)
    print(load_report(out))
    print(f"wrote {path}")


class Log:
    """`log(msg)` prints `msg` at once, after the seconds since the log began (`stamp=True`);
    `log.t0` is when it began (`perf_counter`), `log.load_start` the load average then."""

    def __init__(self, stamp: bool = True):
        self.t0 = time.perf_counter()
        self.load_start = load_average()
        self.stamp = stamp

    def __call__(self, msg: str) -> None:
        prefix = f"[{self.elapsed():7.1f} s] " if self.stamp else ""
        print(prefix + msg, flush=True)

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


def execute(run, args, show=None, stamp: bool = False) -> dict:
    """The body of a script's `main`: `out = run(args, log)` with a fresh `Log`, `show(out)`
    (its table), then `finish` into `args.out`; returns `out`."""
    log = Log(stamp=stamp)
    out = run(args, log)
    if show is not None:
        show(out)
    finish(out, args.out, log.t0)
    return out


def parser(
    doc: str | None,
    out: str | None,
    *,
    quick: str | None = None,
    repeats: int | None = 3,
    seed: bool = False,
) -> argparse.ArgumentParser:
    """The command line every script shares: `--quick` (with its help text, if `quick`),
    `--repeats`, `--seed`, and `--out` (default `results/<out>`: a quick check writes elsewhere
    by giving `--out`)."""
    p = argparse.ArgumentParser(description=(doc or "").split("\n\n")[0])
    if quick is not None:
        p.add_argument("--quick", action="store_true", help=quick)
    if repeats is not None:
        p.add_argument("--repeats", type=int, default=repeats, help="timed rounds (best of)")
    if seed:
        p.add_argument("--seed", type=int, default=0)
    if out is not None:
        p.add_argument("--out", type=Path, default=RESULTS / out, help="JSON output path")
    return p


def target(value, goal: float, at_least: bool = True, **extra) -> dict:
    """A verdict: `{"target", "value", **extra, "passed"}`; `passed` is None without a value."""
    passed = None if value is None else bool(value >= goal if at_least else value <= goal)
    return dict(target=goal, value=value, **extra, passed=passed)


def print_targets(targets: dict) -> None:
    for name, t in targets.items():
        verdict = {True: "PASS", False: "FAIL", None: "—"}[t["passed"]]
        print(f"target {name}: {t['value']} (target {t['target']}) -> {verdict}")


_SPEC = re.compile(r"([<>^]?)(\d+)")


def _cell(value: Any, spec: str) -> str:
    if value is None:
        return format("—", "".join(_SPEC.match(spec).groups()))  # type: ignore[union-attr]
    if isinstance(value, str):
        return format(value, _SPEC.match(spec).group(0))  # type: ignore[union-attr]
    return format(value, spec)


def table(columns: Sequence[tuple[str, str]], rows: Iterable[Sequence[Any]]) -> str:
    """A text table: `columns` are `(header, format spec)` pairs (the spec with its alignment
    and width, e.g. `"<22"`, `">10.3g"`); a cell that is None prints as "—", a string as it is.
    The header, a rule, then one line per row."""
    head = "".join(_cell(h, spec) for h, spec in columns)
    lines = [head, "-" * len(head)]
    for row in rows:
        lines.append("".join(_cell(v, spec) for v, (_, spec) in zip(row, columns, strict=True)))
    return "\n".join(lines)


@contextmanager
def figure(path: Path, *subplots: int, dpi: int = 110, **kw) -> Iterator[tuple[Any, Any]]:
    """`(fig, axes)` of `plt.subplots(*subplots, **kw)` on the Agg backend, laid out and saved
    to `path` at `dpi` when the block ends, then closed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(*subplots, **kw)
    try:
        yield fig, axes
        fig.tight_layout()
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
