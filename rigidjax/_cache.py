"""The user's cache folder for rigidjax: JAX's persistent compilation cache of the command line
(`jax/`) and the CPU kernels built on this machine (`kernels/`)."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def user_cache_dir() -> Path:
    """`$XDG_CACHE_HOME/rigidjax` (`%LOCALAPPDATA%` on Windows, `~/Library/Caches` on macOS,
    `~/.cache` otherwise)."""
    if sys.platform == "win32" and os.environ.get("LOCALAPPDATA"):
        base = Path(os.environ["LOCALAPPDATA"])
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "rigidjax"
