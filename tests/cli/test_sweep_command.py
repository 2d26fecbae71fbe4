"""`rigidjax sweep CONFIG.toml`: the store, the plot and the summary; values against SciPy;
resuming; config errors that name the file, the key and the fix, with no traceback."""

import contextlib
import io
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from scipy.integrate import solve_ivp

import rigidjax as rj
from rigidjax.cli import main

CONFIG = """
[body]
inertia = [1.0, "I2", 2.5]

[initial]
omega0 = ["offset", 1.0, 0.0]

[times]
t_end = 4.0
num = 5

[solver]
method = "tsit5"
rtol = 1e-10
atol = 1e-10

[design]
kind = "grid"

[design.factors.I2]
values = [1.6, 2.0]

[design.factors.offset]
start = 0.01
stop = 0.1
num = 3
scale = "log"

[observables]
names = ["max_nutation", "energy_drift", "omega_end"]
"""


def sweep(config: Path, out: Path, *extra: str) -> tuple[int, str, str]:
    printed, errors = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(errors):
        rc = main(["sweep", str(config), "--out", str(out), "--no-progress", *extra])
    return rc, printed.getvalue(), errors.getvalue()


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    config = folder / "racket.toml"
    config.write_text(CONFIG)
    out = folder / "out"
    rc, printed, err = sweep(config, out)
    return rc, printed, err, config, out


def euler_rhs(I):
    def f(t, w):
        return [
            (I[1] - I[2]) / I[0] * w[1] * w[2],
            (I[2] - I[0]) / I[1] * w[2] * w[0],
            (I[0] - I[1]) / I[2] * w[0] * w[1],
        ]

    return f


def test_writes_store_plot_and_config(swept):
    rc, printed, err, config, out = swept
    assert rc == 0, err
    for name in ("sweep.zarr", "sweep.png", "sweep.toml"):
        assert (out / name).exists()
        assert str((out / name).resolve()) in printed or name == "sweep.toml"
    assert (out / "sweep.toml").read_text() == config.read_text()
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert re.search(r"swept 6 points .* failed: none", printed)


def test_values_against_scipy(swept):
    out = swept[-1]
    ds = xr.open_zarr(out / "sweep.zarr").load()
    assert ds["omega_end"].dims == ("I2", "offset", "omega_end_dim_0")
    np.testing.assert_allclose(ds["offset"].values, np.geomspace(0.01, 0.1, 3))
    assert (ds["status"].values == 0).all()
    for I2 in ds["I2"].values:
        for offset in ds["offset"].values:
            I = (1.0, I2, 2.5)
            ref = solve_ivp(
                euler_rhs(I), (0, 4), [offset, 1.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12
            )
            got = ds["omega_end"].sel(I2=I2, offset=offset).values
            np.testing.assert_allclose(got, ref.y[:, -1], rtol=0, atol=1e-7)
    assert float(ds["energy_drift"].max()) < 1e-8


def test_resumes_without_recomputing(swept):
    rc, _, _, config, out = swept
    before = xr.open_zarr(out / "sweep.zarr").load()
    rc, printed, err = sweep(config, out)
    assert rc == 0, err
    assert "compile 0 s" in printed  # every chunk was done: nothing compiled or computed
    after = xr.open_zarr(out / "sweep.zarr").load()
    xr.testing.assert_equal(before.drop_attrs(), after.drop_attrs())


def test_refuses_another_config_in_the_same_folder(swept, tmp_path, capsys):
    out = swept[-1]
    other = tmp_path / "other.toml"
    other.write_text(CONFIG.replace("t_end = 4.0", "t_end = 5.0"))
    rc = main(["sweep", str(other), "--out", str(out), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, "another config", "--out")


def test_runtime_checks_restored_after_the_command(swept):
    """The command compiles its programs with Equinox's checks as NaN; afterwards they raise."""
    assert swept[0] == 0
    from equinox import _errors

    assert _errors.EQX_ON_ERROR == "raise"
    body = rj.RigidBody(jnp.array([1.0, 2.0, 2.5]))
    ts = jnp.linspace(0.0, 1.0, 3)
    f = jax.jit(lambda q0: rj.simulate(body, jnp.array([0.1, 1.0, 0.0]), q0, ts).omega)
    with pytest.raises(Exception, match="q0 must be a unit quaternion"):  # noqa: B017
        f(jnp.array([2.0, 0.0, 0.0, 0.0]))


# --- config errors ------------------------------------------------------------------------------


def assert_user_error(rc: int, err: str, *needles: str) -> None:
    assert rc == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("rigidjax: error: ")
    for needle in needles:
        assert needle in lines[0], lines[0]


BAD_CONFIGS = [
    (("t_end = 4.0", "t_end = "), ("not valid TOML", "line 9")),
    (('inertia = [1.0, "I2", 2.5]', ""), ("[body] inertia", "missing")),
    (('inertia = [1.0, "I2", 2.5]', 'inertai = [1.0, "I2", 2.5]'), ("unknown key 'inertai'",)),
    (('omega0 = ["offset", 1.0, 0.0]', 'omega0 = ["offst", 1.0, 0.0]'), ("'offst'", "not defined")),
    (("num = 5", "num = 5\n[design.factors.extra]\nvalues = [1.0]"), ("'extra'", "not used")),
    (('method = "tsit5"', 'method = "rk4"'), ("[solver] dt", "rk4")),
    (('method = "tsit5"', 'method = "rk45"'), ("[solver] method", "dopri8")),
    (('"omega_end"]', '"omega_ends"]'), ("[observables] names", "omega_ends")),
    (("start = 0.01", "start = 0.0"), ("[design.factors.offset]", "log scale")),
    (("values = [1.6, 2.0]", "values = [1.6, 4.0]"), ("I2 = 4", "triangle")),
    (("omega0 = [", "q0 = [1.0, 1.0, 0.0, 0.0]\nomega0 = ["), ("q0", "unit quaternion")),
    (("rtol = 1e-10", "rtol = -1e-10"), ("[solver] rtol", "positive")),
    (("rtol = 1e-10", "rtol = 1e-300"), ("[solver] rtol: 1e-300 is below what float64",)),
    (('[1.0, "I2", 2.5]', '[1.0, "I2"]'), ("[body] inertia", "shape")),
]


@pytest.mark.parametrize(("change", "needles"), BAD_CONFIGS)
def test_config_errors(tmp_path, capsys, change, needles):
    old, new = change
    assert old in CONFIG
    config = tmp_path / "bad.toml"
    config.write_text(CONFIG.replace(old, new, 1))
    rc = main(["sweep", str(config), "--out", str(tmp_path / "out"), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, str(config), *needles)
    assert not (tmp_path / "out").exists()


def test_refuses_a_store_folder_of_other_files_and_writes_nothing(tmp_path, capsys):
    """`--out` whose `sweep.zarr` is a folder of the user's files: refused before any work, the
    files kept, and no `sweep.toml` left beside them."""
    config = tmp_path / "c.toml"
    config.write_text(CONFIG)
    out = tmp_path / "o"
    (out / "sweep.zarr").mkdir(parents=True)
    (out / "sweep.zarr" / "mine.txt").write_text("keep")
    rc = main(["sweep", str(config), "--out", str(out), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, "--out", "a folder with files and no Zarr")
    assert sorted(p.name for p in out.iterdir()) == ["sweep.zarr"]
    assert (out / "sweep.zarr" / "mine.txt").read_text() == "keep"


def test_missing_config_file(tmp_path, capsys):
    rc = main(["sweep", str(tmp_path / "none.toml"), "--no-progress"])
    assert_user_error(rc, capsys.readouterr().err, "none.toml", "cannot read")


def test_distributed_flags_go_together(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text(CONFIG)
    rc = main(["sweep", str(config), "--out", str(tmp_path / "o"), "--coordinator", "h:1"])
    assert_user_error(rc, capsys.readouterr().err, "--num-processes", "--process-id")


def test_examples_parse():
    """Every shipped example is a valid config whose design points are physical."""
    from rigidjax.cli import _config
    from rigidjax.cli.sweep import check_points

    examples = sorted((Path(__file__).parents[2] / "examples").glob("*.toml"))
    assert any(p.name == "tennis_racket.toml" for p in examples)
    for path in examples:
        c = _config.load(path)
        check_points(c, _config.make_design(c))


def test_first_flip_time_is_located(tmp_path):
    """`first_flip_time` in a sweep is the solver's located flip (`events.flip_event`), the
    closed form to the tolerance, not an interpolation between the 5 samples."""
    config = tmp_path / "flip.toml"
    text = CONFIG.replace("t_end = 4.0", "t_end = 20.0").replace(
        '"max_nutation", "energy_drift", "omega_end"', '"first_flip_time", "omega_end"'
    )
    config.write_text(text.replace("values = [1.6, 2.0]", "values = [1.6, 2.0, 2.2]"))
    rc, _, err = sweep(config, tmp_path / "out")
    assert rc == 0, err
    ds = xr.open_zarr(tmp_path / "out" / "sweep.zarr")
    for I2 in (1.6, 2.0, 2.2):
        for offset in ds["offset"].values:
            w0 = jnp.array([offset, 1.0, 0.0])
            want = rj.analytic.time_of_first_flip(jnp.array([1.0, I2, 2.5]), w0)
            got = ds["first_flip_time"].sel(I2=I2, offset=offset).values
            assert np.isfinite(got) and got < 20.0
            np.testing.assert_allclose(got, want, rtol=1e-7)
    plain = rj.simulate(rj.RigidBody(jnp.array([1.0, 2.0, 2.5])), w0, None, jnp.linspace(0, 20, 5))
    np.testing.assert_allclose(ds["omega_end"].sel(I2=2.0).values[-1], plain.omega[-1], atol=1e-8)
