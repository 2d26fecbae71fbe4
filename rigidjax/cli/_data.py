"""Reading the CSV data files of `rigidjax identify` and `rigidjax darboux`: a header line names
the columns (t, wx, wy, wz and optionally qw, qx, qy, qz; ω and Ω may stand for w), or, without
a header, the columns come in that order. Every error names the file, the line and the fix.
`prepare` is the start the two commands share."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from ._common import UsageError, check_out, check_positive, set_precision

GYRO = ("t", "wx", "wy", "wz")
ATTITUDE = ("qw", "qx", "qy", "qz")


def _column(name: str) -> str:
    """A header name in canonical form: `Omega_X`, `ωx`, `w_x` → `wx`; `time` → `t`."""
    key = name.strip().lower().replace("ω", "w").replace("omega", "w").replace("_", "")
    return "t" if key == "time" else key


def read(path: Path, *, attitude: bool) -> dict[str, np.ndarray]:
    """The columns of `path`: `t (T,)`, `omega (T, 3)` and, if `attitude` and present,
    `quat (T, 4)`. Times must be finite and strictly increasing, values finite."""
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = [r for r in csv.reader(f) if r and not r[0].lstrip().startswith("#")]
    except OSError as e:
        raise UsageError(f"{path}: cannot read the data ({e.strerror or e})") from e
    except UnicodeDecodeError as e:
        raise UsageError(f"{path}: not a text (CSV) file: {e}") from e
    if not rows:
        raise UsageError(f"{path}: no data; give columns {', '.join(GYRO)} (one row per time)")
    first = rows[0]
    try:
        [float(v) for v in first]
        names = list(GYRO + ATTITUDE)[: len(first)]
        body, offset = rows, 1
    except ValueError:
        names = [_column(v) for v in first]
        body, offset = rows[1:], 2
    missing = [c for c in GYRO if c not in names]
    if missing:
        raise UsageError(
            f"{path}: line 1: no column {', '.join(missing)}; the header must name "
            f"{', '.join(GYRO)} (and optionally {', '.join(ATTITUDE)}), got {', '.join(first)}"
        )
    unknown = [v for v, n in zip(first, names, strict=True) if n not in GYRO + ATTITUDE]
    if unknown:
        raise UsageError(
            f"{path}: line 1: unknown column {unknown[0].strip()!r}; the columns are "
            f"{', '.join(GYRO)} and optionally {', '.join(ATTITUDE)}: remove the others"
        )
    has_q = all(c in names for c in ATTITUDE)
    if not has_q and any(c in names for c in ATTITUDE):
        raise UsageError(f"{path}: line 1: give all four of {', '.join(ATTITUDE)} or none")
    if len(body) < 2:
        raise UsageError(f"{path}: needs at least 2 rows of data, got {len(body)}")
    table = np.empty((len(body), len(names)))
    for i, row in enumerate(body):
        if len(row) != len(names):
            raise UsageError(
                f"{path}: line {i + offset}: {len(row)} values, expected {len(names)} "
                f"({', '.join(names)})"
            )
        try:
            table[i] = [float(v) for v in row]
        except ValueError as e:
            raise UsageError(f"{path}: line {i + offset}: {e}; give numbers only") from e
        if not np.all(np.isfinite(table[i])):
            raise UsageError(f"{path}: line {i + offset}: a value is not finite; remove the row")
    col = {n: table[:, k] for k, n in enumerate(names)}
    t = col["t"]
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        k = int(bad[0]) + 1
        raise UsageError(
            f"{path}: line {k + offset}: t = {t[k]:g} does not increase (previous {t[k - 1]:g}); "
            "sort the rows by time and remove repeated times"
        )
    out = {"t": t, "omega": np.column_stack([col[c] for c in GYRO[1:]])}
    if attitude and has_q:
        q = np.column_stack([col[c] for c in ATTITUDE])
        norm = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1) > 1e-3)
        if bad.size:
            k = int(bad[0])
            raise UsageError(
                f"{path}: line {k + offset}: the quaternion has norm {norm[k]:.6g}; give unit "
                "quaternions (scalar first)"
            )
        out["quat"] = q / norm[:, None]
    return out


def prepare(
    args: argparse.Namespace, *positive: str, attitude: bool
) -> tuple[dict[str, np.ndarray], Path]:
    """The start of `identify` and `darboux`: check the options `positive`, read `args.data`
    (`read`), check the output folder (`--out`, by default DATA_out) and set float64; the data
    and the folder."""
    check_positive(args, *positive)
    data = read(args.data, attitude=attitude)
    out: Path = args.out or Path(f"{args.data.stem}_out")
    check_out(out)
    set_precision(False)
    return data, out
