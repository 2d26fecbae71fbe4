"""Machine and version facts recorded in every benchmark JSON, and the JSON writer (shared by the
bench scripts)."""

from __future__ import annotations

import importlib.metadata
import json
import os
import platform
import subprocess
import sys
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
