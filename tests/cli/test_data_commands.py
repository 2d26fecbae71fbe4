"""`rigidjax darboux GYRO.csv` and `rigidjax identify DATA.csv` on data made by SciPy, and the
data-file errors (file, line and fix; no traceback)."""

import contextlib
import io
import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rigidjax.cli import main

I = np.array([1.0, 2.0, 2.5])


def free_body(t, y):
    """Euler's equations and q̇ = ½ q ∘ (0, Ω) (scalar first), written out for SciPy."""
    w, (qw, qx, qy, qz) = y[:3], y[3:]
    dw = [
        (I[1] - I[2]) / I[0] * w[1] * w[2],
        (I[2] - I[0]) / I[1] * w[2] * w[0],
        (I[0] - I[1]) / I[2] * w[0] * w[1],
    ]
    dq = [
        -qx * w[0] - qy * w[1] - qz * w[2],
        qw * w[0] + qy * w[2] - qz * w[1],
        qw * w[1] + qz * w[0] - qx * w[2],
        qw * w[2] + qx * w[1] - qy * w[0],
    ]
    return np.concatenate([dw, 0.5 * np.asarray(dq)])


@pytest.fixture(scope="module")
def truth():
    t = np.linspace(0.0, 8.0, 81)
    y0 = [0.4, 1.1, -0.7, 1.0, 0.0, 0.0, 0.0]
    sol = solve_ivp(free_body, (0, 8), y0, t_eval=t, method="DOP853", rtol=1e-13, atol=1e-13)
    return t, sol.y[:3].T, sol.y[3:].T


def command(*argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([*argv, "--no-progress"])
    return rc, out.getvalue(), err.getvalue()


def write_csv(path, header, *columns):
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="")
    return path


def test_darboux_reproduces_the_attitude(tmp_path, truth):
    """Dense gyro samples of the exact motion: the attitude follows SciPy's to the error of
    interpolating the rates between samples."""
    t, w, q = truth
    fine = np.linspace(0.0, 8.0, 1601)
    sol = solve_ivp(
        free_body, (0, 8), [0.4, 1.1, -0.7, 1, 0, 0, 0], t_eval=fine, rtol=1e-13, atol=1e-13
    )
    gyro = write_csv(tmp_path / "gyro.csv", "time,omega_x,omega_y,omega_z", fine, sol.y[:3].T)
    rc, out, err = command("darboux", str(gyro), "--out", str(tmp_path / "att"))
    assert rc == 0, err
    table = np.loadtxt(tmp_path / "att" / "attitude.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 1:5], sol.y[3:].T, atol=2e-5)
    data = np.load(tmp_path / "att" / "attitude.npz")
    assert data["matrix"].shape == (1601, 3, 3)
    for name in ("attitude.csv", "attitude.npz", "attitude.png"):
        assert str((tmp_path / "att" / name).resolve()) in out


@pytest.mark.slow
def test_identify_finds_the_inertia(tmp_path, truth):
    t, w, q = truth
    rng = np.random.default_rng(1)
    noisy = w + 1e-3 * rng.normal(size=w.shape)
    data = write_csv(tmp_path / "gyro.csv", "t,wx,wy,wz", t, noisy)
    rc, out, err = command("identify", str(data), "--sigma-omega", "1e-3", "--out", str(tmp_path))
    assert rc == 0, err
    result = json.loads((tmp_path / "identify.json").read_text())
    moments, std = np.array(result["principal_moments"]), np.array(result["inertia_std"])
    np.testing.assert_allclose(moments, I / I.sum(), atol=5 * np.max(np.diag(std)) + 1e-6)
    assert result["converged"] and result["samples"] == 81 and not result["attitude_data"]
    assert (tmp_path / "identify.png").exists() and "principal moments" in out


BAD_DATA = [
    ("t,wx,wy,wz\n0,1,0,0\n1,1,0,0\n1,1,0,0\n", ("line 4", "does not increase")),
    ("t,wx,wy\n0,1,0\n1,1,0\n", ("line 1", "no column wz")),
    ("t,wx,wy,wz\n0,1,0,0\n1,1,x,0\n", ("line 3", "numbers only")),
    ("t,wx,wy,wz\n0,1,0,0\n1,1,0\n", ("line 3", "3 values, expected 4")),
    ("t,wx,wy,wz\n0,1,0,0\n1,nan,0,0\n", ("line 3", "not finite")),
    ("", ("no data",)),
    ("t,wx,wy,wz,qw,qx,qy,qz\n0,1,0,0,1,0,0,0\n1,1,0,0,2,0,0,0\n", ("line 3", "norm 2")),
    ("t,wx,wy,wz,qw\n0,1,0,0,1\n1,1,0,0,1\n", ("all four",)),
    ("0,1,0,0,1\n1,1,0,0,1\n", ("line 1", "all four")),  # no header: the fifth is qw
    ("t,wx,wy,wz,foo\n0,1,0,0,9\n1,1,0,0,9\n", ("line 1", "unknown column 'foo'")),
]


@pytest.mark.parametrize("name", ["identify", "darboux"])
@pytest.mark.parametrize(("text", "needles"), BAD_DATA)
def test_data_errors(tmp_path, text, needles, name):
    """Both commands read their files alike (darboux ignored extra columns); darboux does not
    use the attitude columns (their norm)."""
    if name == "darboux" and "norm 2" in needles:
        pytest.skip("darboux does not read the attitude")
    path = tmp_path / "data.csv"
    path.write_text(text)
    rc, out, err = command(name, str(path), "--out", str(tmp_path / "o"))
    assert rc == 2 and "Traceback" not in err, err
    line = err.strip()
    assert line.startswith(f"rigidjax: error: {path}") and "\n" not in line
    for needle in needles:
        assert needle in line, line
    assert not (tmp_path / "o").exists()


def test_headerless_columns(tmp_path, truth):
    """Without a header the columns are t, wx, wy, wz in that order."""
    from rigidjax.cli._data import read

    t, w, _ = truth
    path = tmp_path / "plain.csv"
    np.savetxt(path, np.column_stack([t, w]), delimiter=",")
    data = read(path, attitude=True)
    np.testing.assert_array_equal(data["t"], t)
    np.testing.assert_allclose(data["omega"], w)
    assert "quat" not in data


def test_darboux_refuses_unattainable_tolerances(tmp_path, truth):
    """It ended in a traceback ("omega(t) returned a non-finite value": the first step size
    overflowed to NaN); now one line before any work."""
    t, w, _ = truth
    path = write_csv(tmp_path / "gyro.csv", "t,wx,wy,wz", t, w)
    argv = ("darboux", str(path), "--rtol", "1e-300", "--atol", "1e-300", "--out")
    rc, _, err = command(*argv, str(tmp_path / "o"))
    assert rc == 2 and "Traceback" not in err, err
    assert (
        err.strip()
        == "rigidjax: error: --rtol: 1e-300 is below what float64 can reach; give at least 9e-16"
    )
    assert not (tmp_path / "o").exists()
