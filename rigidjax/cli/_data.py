"""Reading the CSV data files of `rigidjax identify` and `rigidjax darboux`: a header line names
the columns (t, wx, wy, wz and optionally qw, qx, qy, qz; ω and Ω may stand for w, 1, 2, 3 for
x, y, z, and a unit in brackets may follow: `omega_1 [rad/s]`), or, without a header, the
columns come in that order. The trajectory.csv that `rigidjax simulate` writes reads as it is:
its derived columns (energy, momentum_norm) are skipped. Values are comma-separated, UTF-8 (a
BOM is dropped); blank lines, rows of only commas, trailing commas and `#` comments are
skipped. Every error names the file, the line (the file's own numbering) and the fix.
`prepare` is the start the two commands share."""

from __future__ import annotations

import argparse
import csv
import re
from pathlib import Path

import numpy as np

from ._common import UsageError, check_out, check_positive, set_precision

GYRO = ("t", "wx", "wy", "wz")
ATTITUDE = ("qw", "qx", "qy", "qz")
DERIVED = ("energy", "momentumnorm")  # the columns of simulate's trajectory.csv that are skipped


def _column(name: str) -> str:
    """A header name in canonical form: `Omega_X`, `ωx`, `w_x`, `omega1` → `wx`; `q_w` → `qw`;
    `time` → `t`; a unit after it dropped (`t [s]`, `wx (rad/s)`)."""
    key = re.sub(r"\s*[\[(][^\[\]()]*[\])]\s*$", "", name.strip())
    key = key.lower().replace("ω", "w").replace("omega", "w").replace("_", "")
    if key in ("w1", "w2", "w3"):
        key = "w" + "xyz"[int(key[1]) - 1]
    return "t" if key == "time" else key


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    """The rows of `path`, each with the file's line number (1-based: where the row ends), less
    their trailing empty fields (as spreadsheets export: `t,wx,wy,wz,`), and less rows left
    empty (blank, whitespace-only, only commas) and comments (`#`). A BOM (as Excel writes) is
    dropped."""
    rows, line = [], 0
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            for r in reader:
                line = reader.line_num
                while r and not r[-1].strip():
                    r.pop()
                if r and not r[0].lstrip().startswith("#"):
                    rows.append((line, r))
    except OSError as e:
        raise UsageError(f"{path}: cannot read the data ({e.strerror or e})") from e
    except UnicodeDecodeError as e:
        raise UsageError(f"{path}: not a text (CSV) file: {e}") from e
    except csv.Error as e:
        raise UsageError(f"{path}: line {line + 1}: {e}; give comma-separated values") from e
    return rows


def _header(path: Path, line: int, first: list[str]) -> list[str]:
    """The canonical names of the header `first` (on `line`), checked: all of `GYRO`, each
    once (`wx`, `omega_x` and `ωx` are one column), no others but `DERIVED`, all of
    `ATTITUDE` or none."""
    where = f"{path}: line {line}"
    names = [_column(v) for v in first]
    seen: dict[str, int] = {}
    for k, name in enumerate(names):
        if name in GYRO + ATTITUDE:
            if name in seen:
                j = seen[name]
                same = f" (both are {name})" if first[j].strip() != first[k].strip() else ""
                raise UsageError(
                    f"{where}: column {k + 1} {first[k].strip()!r} repeats column {j + 1} "
                    f"{first[j].strip()!r}{same}; remove one of them"
                )
            seen[name] = k
    missing = [c for c in GYRO if c not in names]
    if missing:
        text = ",".join(first)
        sep = "';'" if ";" in text else "tabs" if "\t" in text else None
        hint = f"; the file must be comma-separated (this one uses {sep})" if sep else ""
        raise UsageError(
            f"{where}: no column {', '.join(missing)}; the header must name "
            f"{', '.join(GYRO)} (and optionally {', '.join(ATTITUDE)}), got {', '.join(first)}"
            + hint
        )
    unknown = [v for v, n in zip(first, names, strict=True) if n not in GYRO + ATTITUDE + DERIVED]
    if unknown:
        raise UsageError(
            f"{where}: unknown column {unknown[0].strip()!r}; the columns are "
            f"{', '.join(GYRO)} and optionally {', '.join(ATTITUDE)}: remove the others"
        )
    return names


def read(path: Path, *, attitude: bool) -> dict[str, np.ndarray]:
    """The columns of `path`: `t (T,)`, `omega (T, 3)` and, if `attitude` and present,
    `quat (T, 4)`. Times must be finite and strictly increasing, values finite. Messages give
    the file's own line numbers (comments and blank lines counted)."""
    rows = _rows(path)
    if not rows:
        raise UsageError(f"{path}: no data; give columns {', '.join(GYRO)} (one row per time)")
    line1, first = rows[0]
    try:
        [float(v) for v in first]
    except ValueError:
        names = _header(path, line1, first)
        rows = rows[1:]
    else:  # no header: the columns in the order t, wx, wy, wz[, qw, qx, qy, qz]
        if len(first) > len(GYRO + ATTITUDE):
            raise UsageError(
                f"{path}: line {line1}: {len(first)} values, expected 4 or 8 columns "
                f"({', '.join(GYRO)}[, {', '.join(ATTITUDE)}]); remove the others"
            )
        names = list(GYRO + ATTITUDE)[: len(first)]
    has_q = all(c in names for c in ATTITUDE)
    if not has_q and any(c in names for c in ATTITUDE):
        raise UsageError(f"{path}: line {line1}: give all four of {', '.join(ATTITUDE)} or none")
    if len(rows) < 2:
        raise UsageError(f"{path}: needs at least 2 rows of data, got {len(rows)}")
    lines = [n for n, _ in rows]
    table = np.empty((len(rows), len(names)))
    for i, (line, row) in enumerate(rows):
        if len(row) != len(names):
            raise UsageError(
                f"{path}: line {line}: {len(row)} values, expected {len(names)} "
                f"({', '.join(names)})"
            )
        try:
            table[i] = [float(v) for v in row]
        except ValueError as e:
            raise UsageError(f"{path}: line {line}: {e}; give numbers only") from e
        if not np.all(np.isfinite(table[i])):
            raise UsageError(f"{path}: line {line}: a value is not finite; remove the row")
    col = {n: table[:, k] for k, n in enumerate(names)}
    t = col["t"]
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        k = int(bad[0]) + 1
        raise UsageError(
            f"{path}: line {lines[k]}: t = {t[k]:g} does not increase (previous {t[k - 1]:g}); "
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
                f"{path}: line {lines[k]}: the quaternion has norm {norm[k]:.6g}; give unit "
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
