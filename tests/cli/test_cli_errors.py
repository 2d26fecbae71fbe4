"""The `rigidjax` command's checks: the output folder before any computation, one-line user
errors with exit status 2 and no traceback, `--version`, compile and run times reported."""

import contextlib
import importlib
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import diffrax
import jax
import numpy as np
import pytest

import rigidjax
from rigidjax import _folders
from rigidjax.cli import main

cli = importlib.import_module("rigidjax.cli.simulate")  # the default command's module
common = importlib.import_module("rigidjax.cli._common")


@pytest.fixture
def no_jax_work(monkeypatch):
    """Fail the test if the command gets as far as building the simulation's inputs."""

    def forbidden(args):
        raise AssertionError("JAX work started before the command line was rejected")

    monkeypatch.setattr(cli, "_inputs", forbidden)


def assert_user_error(rc: int, err: str, *needles: str) -> None:
    """Exit status 2, one `rigidjax: error:` line that contains `needles`, no traceback."""
    assert rc == 2
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("rigidjax: error: ")
    for needle in needles:
        assert needle in lines[0]


# --- the output folder -------------------------------------------------------------------------


def test_out_is_a_file(tmp_path, capsys, no_jax_work):
    f = tmp_path / "results"
    f.write_text("keep me")
    rc = main(["--out", str(f), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, "--out", "not a folder", "--out DIR")
    assert f.read_text() == "keep me"


def test_out_below_a_file(tmp_path, capsys, no_jax_work):
    f = tmp_path / "results"
    f.write_text("")
    rc = main(["--out", str(f / "run"), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, "--out", "not a folder")


def permissions_restrict(folder: Path) -> bool:
    """Whether a read-only `folder` stops this process (not root with CAP_DAC_OVERRIDE)."""
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        probe = folder / ".probe"
        try:
            probe.touch()
        except PermissionError:
            return True  # root without the capability
        probe.unlink()
        return False
    return True


def test_out_unwritable_folder(tmp_path, capsys, no_jax_work):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if not permissions_restrict(locked):
            pytest.skip("running as root: chmod does not restrict writing")
        for out in (locked, locked / "run"):
            rc = main(["--out", str(out), "--no-progress"])
            assert_user_error(rc, capsys.readouterr().err, "--out", "cannot write", "--out DIR")
        assert not (locked / "run").exists()
    finally:
        locked.chmod(0o700)


def test_out_unwritable_probe(tmp_path, capsys, monkeypatch, no_jax_work):
    """The same check where permissions cannot be used (as root): the probe file fails."""

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(_folders.tempfile, "TemporaryFile", refuse)
    rc = main(["--out", str(tmp_path / "a" / "b"), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, "--out", "cannot write", "Permission denied")
    assert not (tmp_path / "a").exists()  # the check creates nothing


def test_out_check_leaves_nothing_behind(tmp_path):
    common.check_out(tmp_path / "new" / "run")
    common.check_out(tmp_path)
    assert list(tmp_path.iterdir()) == []


# --- bad values --------------------------------------------------------------------------------

BAD_OPTIONS = [
    (["--num", "1"], "--num"),
    (["--num", "-5"], "--num"),
    (["--t-end", "0"], "--t-end"),
    (["--t-end", "-2"], "--t-end"),
    (["--t-end", "inf"], "--t-end"),
    (["--t-end", "nan"], "--t-end"),
    (["--rtol", "0"], "--rtol"),
    (["--atol=-1e-9"], "--atol"),
    (["--atol", "nan"], "--atol"),
    # below what the precision can reach: the solve ran into max_steps (or, in darboux, a step
    # size that overflowed to NaN, reported as a non-finite omega(t) with a traceback)
    (["--rtol", "1e-300"], "--rtol: 1e-300 is below what float64 can reach"),
    (["--atol", "1e-16"], "--atol: 1e-16 is below what float64 can reach; give at least 9e-16"),
    (["--float32", "--rtol", "1e-8"], "float32 can reach; give at least 5e-07, or compute in"),
]


@pytest.mark.parametrize(("argv", "option"), BAD_OPTIONS)
def test_bad_option_values(tmp_path, capsys, no_jax_work, argv, option):
    out = tmp_path / "run"
    rc = main([*argv, "--out", str(out), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, option)
    assert not out.exists()


BAD_INPUTS = [
    (["--inertia", "1", "1", "5"], ("--inertia", "triangle")),
    (["--inertia", "0", "1", "1"], ("--inertia", "positive definite")),
    (["--inertia", "1", "nan", "1"], ("--inertia", "non-finite")),
    (["--omega0", "nan", "1", "0"], ("--omega0", "finite")),
    (["--q0", "1", "1", "0", "0"], ("--q0", "unit quaternion")),
    (["--q0", "0", "0", "0", "0"], ("--q0", "unit quaternion")),
]


@pytest.mark.parametrize(("argv", "needles"), BAD_INPUTS)
def test_values_the_library_rejects(tmp_path, capsys, argv, needles):
    """Non-physical values, rejected by the library's own checks before compiling."""
    out = tmp_path / "run"
    rc = main([*argv, "--out", str(out), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, *needles)
    assert not out.exists()


MALFORMED = [
    ["--inertia", "1", "2"],
    ["--omega0", "1", "x", "0"],
    ["--num", "1.5"],
    ["--kinematics", "spinor"],
    ["--no-such-option"],
]


@pytest.mark.parametrize("argv", MALFORMED)
def test_malformed_command_lines(capsys, no_jax_work, argv):
    """argparse's own errors: usage, then one error line; status 2 returned, not raised."""
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert err.startswith("usage: rigidjax")
    assert re.match(r"rigidjax( simulate)?: error: ", err.strip().splitlines()[-1])


@pytest.mark.parametrize(
    ("argv", "hint"), [(["simulat"], "did you mean 'simulate'? "), (["foo", "x.toml"], "")]
)
def test_unknown_command(capsys, no_jax_work, argv, hint):
    """A mistyped command is named, with the commands (it was "unrecognized arguments")."""
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        f"rigidjax: error: unknown command {argv[0]!r}: {hint}the commands are simulate, sweep, "
        "identify, darboux, bench\n"
    )


def test_bugs_keep_their_traceback(tmp_path, monkeypatch):
    """A ValueError after the inputs were checked is a bug, not a user error: not swallowed."""

    def broken(args, inputs):
        raise ValueError("a bug in compiling")

    monkeypatch.setattr(cli, "_compile_and_run", broken)
    with pytest.raises(ValueError, match="a bug in compiling"):
        main(["--num", "3", "--out", str(tmp_path / "run"), "--no-progress"])


def test_failed_solve_message():
    assert cli._failure(diffrax.RESULTS.successful) is None
    assert "max_steps" in cli._failure(diffrax.RESULTS.max_steps_reached)


# --- --version ----------------------------------------------------------------------------------


def test_version(capsys, no_jax_work):
    rc = main(["--version"])
    out = capsys.readouterr().out
    assert rc == 0
    assert out == f"rigidjax {rigidjax.__version__} (jax {jax.__version__})\n"


# --- compile and run times ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> tuple[int, str, Path]:
    """One short successful run (a few output times: the compile dominates)."""
    out = tmp_path_factory.mktemp("cli") / "run"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        rc = main(["--t-end", "2", "--num", "5", "--out", str(out), "--no-progress"])
    return rc, printed.getvalue(), out


def test_times_in_summary(short_run):
    rc, printed, _ = short_run
    assert rc == 0
    m = re.search(r"compile (\S+) s, run (\S+) s", printed)
    assert m is not None, printed
    compile_s, run_s = float(m.group(1)), float(m.group(2))
    assert compile_s > 0 and run_s >= 0


def test_times_in_npz(short_run):
    rc, _, out = short_run
    assert rc == 0
    data = np.load(out / "trajectory.npz")
    compile_s, run_s = float(data["compile_time_s"]), float(data["run_time_s"])
    assert compile_s > 0 and run_s >= 0
    assert int(data["num_steps"]) >= 4
    assert data["omega"].shape == (5, 3)


# --- the console entry (exit status and stderr of a real process) ------------------------------


def command() -> list[str]:
    """The installed `rigidjax` script next to this Python, else `python -m rigidjax.cli`."""
    script = Path(sys.executable).with_name("rigidjax")
    return [str(script)] if script.exists() else [sys.executable, "-m", "rigidjax.cli"]


def run(*argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.run(
        [*command(), *argv], capture_output=True, text=True, env=env, timeout=120, check=False
    )


def test_console_version():
    p = run("--version")
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith(f"rigidjax {rigidjax.__version__} (jax ")


def test_console_user_errors_have_no_traceback(tmp_path):
    f = tmp_path / "file"
    f.write_text("")
    p = run("--out", str(f), "--inertia", "1", "1", "5")  # the folder is checked first
    assert_user_error(p.returncode, p.stderr, "--out")
    p = run("--out", str(tmp_path / "run"), "--inertia", "1", "1", "5")
    assert_user_error(p.returncode, p.stderr, "--inertia", "triangle")
    assert p.stdout == ""
