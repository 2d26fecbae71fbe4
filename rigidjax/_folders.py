"""Whether a folder can be made and written, asked before any work is done (a sweep's store,
the command line's output folder): probed with a temporary file in the folder or its closest
existing ancestor, so that nothing is left behind and permissions are what the system says
(also as root, where `os.access` says yes to everything)."""

from __future__ import annotations

import tempfile
from pathlib import Path

__all__ = ["write_problem"]


def _nearest_existing(path: Path) -> Path:
    """`path` or its closest ancestor that exists (a dangling link counts as existing)."""
    for p in (path, *path.absolute().parents):
        if p.exists() or p.is_symlink():
            return p
    return Path(path.absolute().anchor)  # pragma: no cover - the root always exists


def write_problem(path: Path) -> str | None:
    """Why a folder at `path` cannot be made and written into (a phrase), or None if it can."""
    if path.exists() and not path.is_dir():
        return f"{path} is a file, not a folder"
    existing = _nearest_existing(path)
    if not existing.is_dir():
        return f"{existing} exists and is not a folder"
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as e:
        return f"cannot write in {existing} ({e.strerror or e})"
    return None
