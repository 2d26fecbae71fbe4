"""`rigidjax sweep` with `[sensors]`: the estimator in the loop from a config. Errors name the key
(no compilation); the shipped example runs with its histograms and Zarr store (slow)."""

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from rigidjax.cli import main

EXAMPLE = Path(__file__).parents[2] / "examples" / "slew_estimated.toml"


@pytest.fixture(autouse=True)
def cache_dir(tmp_path_factory, monkeypatch):
    """The command's persistent compilation cache in a folder of the test session (as
    tests/cli/conftest.py)."""
    path = tmp_path_factory.getbasetemp() / "jax-cache"
    monkeypatch.setenv("RIGIDJAX_CACHE_DIR", str(path))
    return path


def sweep(config: Path, out: Path) -> tuple[int, str]:
    errors = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(errors):
        rc = main(["sweep", str(config), "--out", str(out), "--no-progress"])
    return rc, errors.getvalue()


@pytest.mark.parametrize(
    ("old", "new", "needles"),
    [
        ("gyro_arw = 5e-6", "", ("[sensors] gyro_arw", "missing")),
        ("gyro_rrw = 5e-8", "gyro_rrw = -5e-8", ("[sensors] gyro_rrw", "≥ 0")),
        # the filter's prior on the bias: zero would make P0 singular
        ("gyro_bias = 5e-5", "gyro_bias = 0.0", ("[sensors] gyro_bias", "positive")),
        (
            "star_tracker = [2.5e-5, 2.5e-5, 1.5e-4]",
            "star_tracker = [1e-5, 1e-5]",
            ("star_tracker",),
        ),
        ("[design]", '[run]\nprecision = "float32"\n\n[design]', ("float64",)),
        ('"knowledge_error_end", ', '"knowledge_error_max", ', ("knowledge_error_max",)),
    ],
)
def test_config_errors(tmp_path, old, new, needles):
    text = EXAMPLE.read_text(encoding="utf-8")
    assert old in text
    config = tmp_path / "bad.toml"
    config.write_text(text.replace(old, new, 1), encoding="utf-8")
    rc, err = sweep(config, tmp_path / "out")
    assert rc == 2 and "Traceback" not in err
    for needle in needles:
        assert needle in err, err


def test_sensors_need_a_closed_loop(tmp_path):
    text = EXAMPLE.read_text(encoding="utf-8")
    start, end = text.index("[wheels]"), text.index("[sensors]")
    config = tmp_path / "open.toml"
    body = text[:start] + text[end:]
    body = body.replace("tilt1 = [-0.01745, 0.01745]\ntilt2 = [-0.01745, 0.01745]\n", "")
    config.write_text(
        body.replace("tilt3 = [-0.01745, 0.01745]\ntilt4 = [-0.01745, 0.01745]\n", "")
    )
    rc, err = sweep(config, tmp_path / "out")
    assert rc == 2 and "[sensors]" in err and "[control]" in err, err


@pytest.mark.slow  # ~40 s: 1e4 closed loops with the filter and sensors in the CPU kernel
def test_example_runs_with_its_plot(tmp_path):
    import xarray as xr

    out = tmp_path / "out"
    rc, err = sweep(EXAMPLE, out)
    assert rc == 0, err
    ds = xr.open_zarr(out / "sweep.zarr")
    assert ds["status"].size == 10_000 and (ds["status"].values == 0).all()
    k = ds["knowledge_error_end"].values
    assert np.all(np.isfinite(k)) and np.median(k) < 1e-4  # arcseconds: the star tracker's σ
    assert np.all(ds["control_error_end"].values < 1e-2)
    assert (out / "sweep.png").stat().st_size > 10_000
