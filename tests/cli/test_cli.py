"""The `rigidjax` command end to end in a temporary folder."""

import re

import numpy as np

from rigidjax.cli import main
from rigidjax.cli._data import read


def test_cli_writes_trajectory(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["--t-end", "20", "--num", "201", "--out", str(out), "--no-progress"])
    assert rc == 0
    printed = capsys.readouterr().out
    for ext in ("npz", "csv", "png"):
        path = out / f"trajectory.{ext}"
        assert path.exists() and path.stat().st_size > 0
        assert str(path.resolve()) in printed
    data = np.load(out / "trajectory.npz")
    assert data["omega"].shape == (201, 3) and data["quat"].shape == (201, 4)
    assert data["matrix"].shape == (201, 3, 3)
    # tennis-racket flip: Ω2 starts near +1 and has flipped sign within 20 s
    assert data["omega"][0, 1] > 0.99 and data["omega"][:, 1].min() < -0.9
    assert np.max(np.abs(data["energy"] / data["energy"][0] - 1)) < 1e-8
    csv = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(csv[:, 1:4], data["omega"])
    assert (out / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.glob(".trajectory*"))  # no temporary leftovers
    # `rigidjax identify` and `darboux` read the CSV as it is (they refused its header)
    back = read(out / "trajectory.csv", attitude=True)
    np.testing.assert_allclose(back["t"], data["ts"], rtol=1e-15)
    np.testing.assert_allclose(back["omega"], data["omega"], rtol=1e-15)
    np.testing.assert_allclose(back["quat"], data["quat"], rtol=1e-15, atol=1e-16)


def test_cli_bad_inertia_writes_nothing(tmp_path, capsys):
    out = tmp_path / "bad"
    rc = main(["--inertia", "1", "1", "5", "--out", str(out), "--no-progress"])
    assert rc == 2  # a user error: status 2, like argparse's (was 1 before the CLI checks)
    assert "triangle" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


def test_progress_bar_rounds_simulated_time(tmp_path, capsys):
    """60 s in 50 segments of 1.2 s: the bar's count is a float sum (tqdm showed e.g.
    40.800000000000004/60.0); it shows the rounded times, and 60/60 at the end."""
    rc = main(["--t-end", "60", "--num", "51", "--out", str(tmp_path / "run")])
    assert rc == 0
    err = capsys.readouterr().err
    assert "60/60 s" in err, err
    assert not re.search(r"\d\.\d{7}", err), err


def test_progress_bar_format():
    from tqdm import tqdm

    from rigidjax.cli.simulate import BAR_FORMAT

    line = tqdm.format_meter(40.800000000000004, 60.0, 2.0, unit="s", bar_format=BAR_FORMAT)
    assert "| 40.8/60 s [" in line, line
    assert "40.800000000000004" in tqdm.format_meter(40.800000000000004, 60.0, 2.0, unit="s")
