"""Data files and configs as users' tools write them: BOMs, comments and blank lines before the
error, whitespace-only lines, repeated or extra columns, other separators, other encodings and a
broken copy of the config in `--out`. Valid ones are read; the others give one line naming the
file, the line or key and the fix (exit status 2, no traceback), before any work."""

from pathlib import Path

import numpy as np
import pytest

from rigidjax.cli import main
from rigidjax.cli._config import load
from rigidjax.cli._data import read
from tests.cli.test_cli_errors import assert_user_error

ROWS = "0,0.3,1,0.2\n0.1,0.28,1.01,0.19\n0.2,0.26,1.01,0.18\n"
CONFIG = """\
[body]
inertia = [1.0, "I2", 2.5]

[initial]
omega0 = [0.01, 1.0, 0.0]

[times]
t_end = 1.0
num = 3

[design.factors.I2]
values = [1.6, 2.0]
"""


def data_error(tmp_path: Path, capsys, command: str, text: str, *needles: str) -> str:
    """Run `command` on a file of `text`: a one-line user error naming the file and `needles`,
    no output folder. The line."""
    path = tmp_path / "data.csv"
    path.write_bytes(text.encode())
    rc = main([command, str(path), "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err
    assert_user_error(rc, err, f"rigidjax: error: {path}: ", *needles)
    assert not (tmp_path / "o").exists()
    return err.strip()


def read_text(tmp_path: Path, text: str, encoding: str = "utf-8") -> dict[str, np.ndarray]:
    path = tmp_path / "data.csv"
    path.write_bytes(text.encode(encoding))
    return read(path, attitude=True)


# --- columns -----------------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["identify", "darboux"])
@pytest.mark.parametrize("extra", [1, 3])
def test_headerless_file_with_too_many_columns(tmp_path, capsys, command, extra):
    """Nine or more columns without a header: refused on its line (was a traceback from
    `zip(strict=True)`)."""
    n = 8 + extra
    text = "".join(f"{t}{',1' * (n - 1)}\n" for t in range(3))
    data_error(tmp_path, capsys, command, text, "line 1: ", f"{n} values", "expected 4 or 8")


@pytest.mark.parametrize("command", ["identify", "darboux"])
@pytest.mark.parametrize(
    ("header", "needles"),
    [
        ("t,wx,wy,wz,wx", ("column 5 'wx' repeats column 2 'wx'",)),
        ("time,omega_x,wy,wz,WX", ("column 5 'WX' repeats column 2 'omega_x'", "both are wx")),
        ("t,ωx,wy,wz,Omega_X", ("'Omega_X' repeats column 2 'ωx'", "both are wx")),
        ("Time,wx,wy,wz,t", ("column 5 't' repeats column 1 'Time'", "both are t")),
        ("t,wx,wy,wz,qw,qx,qy,qz,QZ", ("column 9 'QZ' repeats column 8 'qz'",)),
    ],
)
def test_repeated_column(tmp_path, capsys, command, header, needles):
    """Two columns of one quantity (aliases and case included) are refused, not the last one
    used."""
    n = header.count(",") + 1
    rows = "".join(f"{t}{',1' * (n - 1)}\n" for t in range(3))
    data_error(tmp_path, capsys, command, f"{header}\n{rows}", "line 1: ", *needles)


# --- line numbers ------------------------------------------------------------------------------

LEAD = "# exported by the logger\n#\n# units: s, rad/s\n"  # lines 1-3


@pytest.mark.parametrize(
    ("bad", "needles"),
    [
        ("0.3,1,x,0", ("numbers only",)),
        ("0.3,1,0", ("3 values, expected 4",)),
        ("0.3,1,nan,0", ("not finite",)),
        ("0.15,1,0,0", ("does not increase",)),
    ],
)
def test_line_numbers_count_comments_and_blank_lines(tmp_path, capsys, bad, needles):
    """Header on line 4 after comments, blank lines and a comment between the rows: the bad
    row is on line 12 of the file (was given as line 5)."""
    text = f"{LEAD}t,wx,wy,wz\n\n0,1,0,0\n\n0.1,1,0,0\n# note\n\n0.2,1,0,0\n{bad}\n0.4,1,0,0\n"
    assert text.splitlines()[11] == bad
    data_error(tmp_path, capsys, "darboux", text, "line 12: ", *needles)


def test_quaternion_line_number_after_comments(tmp_path, capsys):
    q = ",1,0,0,0"
    text = f"{LEAD}t,wx,wy,wz,qw,qx,qy,qz\n0,1,0,0{q}\n\n# x\n1,1,0,0,2,0,0,0\n"
    data_error(tmp_path, capsys, "identify", text, "line 8: ", "norm 2")


def test_header_line_number_after_comments(tmp_path, capsys):
    data_error(tmp_path, capsys, "darboux", f"{LEAD}\nt,wx,wy\n0,1,0\n1,1,0\n", "line 5: ", "wz")


# --- blank lines, BOMs, encodings --------------------------------------------------------------


def test_whitespace_only_lines_are_blank(tmp_path):
    """A line of spaces or tabs (trailing or between rows) is skipped like an empty one."""
    data = read_text(tmp_path, "t,wx,wy,wz\n0,0.3,1,0.2\n \t \n0.1,0.28,1.01,0.19\n   \n")
    np.testing.assert_array_equal(data["t"], [0, 0.1])


@pytest.mark.parametrize(
    "text",
    [
        "t,wx,wy,wz,\n0,0.3,1,0.2,\n0.1,0.28,1.01,0.19,\n",  # trailing commas (spreadsheets)
        "t,wx,wy,wz\n0,0.3,1,0.2\n,,,\n0.1,0.28,1.01,0.19\n , ,\n",  # rows of only commas
        "t [s],omega_1 [rad/s],omega_2 (rad/s),omega_3 [rad/s]\n0,0.3,1,0.2\n0.1,0.28,1.01,0.19\n",
        "0,0.3,1,0.2,\n0.1,0.28,1.01,0.19,,\n",  # no header
    ],
)
def test_what_spreadsheets_export(tmp_path, text):
    """Trailing commas, rows of only commas and units in the header were refused."""
    data = read_text(tmp_path, text)
    np.testing.assert_array_equal(data["t"], [0, 0.1])
    np.testing.assert_allclose(data["omega"], [[0.3, 1, 0.2], [0.28, 1.01, 0.19]])


def test_a_missing_value_before_a_trailing_comma_is_still_an_error(tmp_path, capsys):
    data_error(
        tmp_path, capsys, "darboux", "t,wx,wy,wz,\n0,1,0,0,\n1,1,0,,\n", "line 3: ", "3 values"
    )


@pytest.mark.parametrize("header", ["t,wx,wy,wz\n", ""])
def test_utf8_bom_is_dropped(tmp_path, header):
    """Excel's UTF-8 BOM before a header or before the first number."""
    data = read_text(tmp_path, f"{header}{ROWS}", "utf-8-sig")
    np.testing.assert_array_equal(data["t"], [0, 0.1, 0.2])
    np.testing.assert_allclose(data["omega"][0], [0.3, 1, 0.2])


def test_config_with_bom_loads(tmp_path):
    path = tmp_path / "c.toml"
    path.write_bytes(CONFIG.encode("utf-8-sig"))
    assert load(path).num == 3


@pytest.mark.parametrize(
    "raw",
    [
        CONFIG.replace("[body]", "# Moment d'inertie (kg m²)\n[body]").encode("latin-1"),
        b"\xff\xfe\x00",
    ],
)
def test_config_not_utf8(tmp_path, capsys, raw):
    path = tmp_path / "c.toml"
    path.write_bytes(raw)
    rc = main(["sweep", str(path), "--out", str(tmp_path / "o"), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, str(path), "not UTF-8", "save the config")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("copy", [b"this = = broken\n", b"[body]\ninertia = [1.0, \xe9]\n"])
def test_broken_config_copy_in_out(tmp_path, capsys, copy):
    """`--out` holding a store and a broken `sweep.toml`: refused, naming that copy and the fix;
    the folder left as it was."""
    config = tmp_path / "c.toml"
    config.write_text(CONFIG)
    out = tmp_path / "o"
    (out / "sweep.zarr").mkdir(parents=True)
    (out / "sweep.toml").write_bytes(copy)
    rc = main(["sweep", str(config), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert_user_error(rc, err, f"--out {out}", str(out / "sweep.toml"), "choose another --out")
    assert (out / "sweep.toml").read_bytes() == copy
    assert sorted(p.name for p in out.iterdir()) == ["sweep.toml", "sweep.zarr"]


# --- separators --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "uses"),
    [
        ("t;wx;wy;wz\n0;0.3;1;0.2\n0.1;0.28;1.01;0.19\n", "';'"),
        ("t;wx;wy;wz\n0;0,3;1;0,2\n0,1;0,28;1,01;0,19\n", "';'"),  # decimal commas
        ("0;0.3;1;0.2\n0.1;0.28;1.01;0.19\n", "';'"),
        ("t\twx\twy\twz\n0\t0.3\t1\t0.2\n0.1\t0.28\t1.01\t0.19\n", "tabs"),
    ],
)
def test_other_separators_are_refused_with_a_hint(tmp_path, capsys, text, uses):
    data_error(tmp_path, capsys, "darboux", text, "line 1: ", "comma-separated", f"uses {uses}")


def test_no_separator_hint_for_a_comma_file(tmp_path, capsys):
    line = data_error(tmp_path, capsys, "darboux", "t,wx,wy\n0,1,0\n1,1,0\n", "no column wz")
    assert "comma-separated" not in line
