"""`rigidjax sweep` of a closed loop (`[wheels]` and `[control]`): the store's observables equal
the library's (a `Gyrostat`, `control.quaternion_pd`, `simulate` and `rigidjax.observables`; the
settling time located by `events.settling_event` within the sample grid's bracket) at every
point; config errors name the key; the shipped Monte Carlo example runs with its plot."""

import contextlib
import io
from pathlib import Path

import diffrax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

import rigidjax as rj
from rigidjax import observables as obs
from rigidjax.cli import main
from rigidjax.events import settling_event

CONFIG = """
[body]
inertia = ["Ixx", 12.0, 8.0]

[initial]
omega0 = [0.0, "wy", 0.0]

[wheels]
axes = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]]
inertia = 0.05
torque_max = 0.1
tilt = [0.0, "tilt", 0.0, 0.0]

[control]
kp = 0.6
kd = 3.0
period = 0.5
target = [0.0, 0.0, 90.0]
tolerance = 1.0

[times]
t_end = 60.0
num = 121

[solver]
method = "rk4"
dt = 0.25

[design]
kind = "sample"
n = 4
seed = 3

[design.ranges]
Ixx = [9.5, 10.5]
wy = [-0.002, 0.002]
tilt = [-0.02, 0.02]
"""
EXAMPLE = Path(__file__).parents[2] / "examples" / "slew_montecarlo.toml"


def sweep(config: Path, out: Path) -> tuple[int, str]:
    errors = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(errors):
        rc = main(["sweep", str(config), "--out", str(out), "--no-progress"])
    return rc, errors.getvalue()


def library(Ixx: float, wy: float, tilt: float):
    """The same point through the library: nominal axes for the law, the second wheel's axis
    turned by `tilt` about `a × e_x` (its perpendicular: e_x is least along e_y)."""
    A = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], np.ones(3) / np.sqrt(3)]).T
    tilted = A.copy()
    tilted[:, 1] = np.cos(tilt) * A[:, 1] + np.sin(tilt) * np.cross(A[:, 1], [1.0, 0, 0])
    g = rj.Gyrostat([Ixx, 12.0, 8.0], wheel_axes=tilted, wheel_inertia=[0.05] * 4,
                    wheel_torque_max=0.1)  # fmt: skip
    target = rj.quat.from_rotvec(jnp.array([0.0, 0.0, np.pi / 2]))
    law = rj.control.quaternion_pd(0.6, 3.0, target, wheel_axes=A)
    ts = jnp.linspace(0.0, 60.0, 121)

    def run(event=None):
        return rj.simulate(
            g, [0.0, wy, 0.0], None, ts, controller=law, control_period=0.5, solver=rj.RK4(),
            stepsize_controller=diffrax.ConstantStepSize(), dt0=0.25, event=event,
        )  # fmt: skip

    tr = run()
    tol = np.radians(1.0)
    # the settling time on the sample grid brackets the last entry into the tolerance, which
    # the event after the last sample outside locates
    grid = float(obs.settling_time(tr, target, tol))
    after = grid - 0.5
    settled = run(settling_event(target, tol, after)).event_t
    assert after < float(settled) <= grid
    return dict(
        settling_time=settled,
        peak_wheel_speed=obs.peak_wheel_speed(tr),
        saturation_count=obs.saturation_count(tr, 0.1),
        pointing_error_end=obs.pointing_error(tr, target)[-1],
    )


@pytest.mark.slow  # ~30 s: the sweep and the library compile the closed loop and its event
def test_store_equals_the_library(tmp_path):
    config = tmp_path / "slew.toml"
    config.write_text(CONFIG)
    rc, err = sweep(config, tmp_path / "out")
    assert rc == 0, err
    ds = xr.open_zarr(tmp_path / "out" / "sweep.zarr")
    assert (ds["status"].values == 0).all()
    for i in range(4):
        point = {k: float(ds[k].values[i]) for k in ("Ixx", "wy", "tilt")}
        want = library(**point)
        for name, value in want.items():
            np.testing.assert_allclose(ds[name].values[i], value, rtol=1e-12, atol=1e-14)
    assert (ds["saturation_count"].values > 0).all()  # the 90° slew saturates at first
    assert np.isfinite(ds["settling_time"].values).all()


@pytest.mark.parametrize(
    ("old", "new", "needles"),
    [
        (CONFIG[CONFIG.index("[control]") : CONFIG.index("[times]")], "", ("[wheels]/[control]",)),
        ("kp = 0.6\n", "", ("[control] kp", "missing")),
        ('tilt = [0.0, "tilt", 0.0, 0.0]', 'tilt = [0.0, "tilt"]', ("[wheels] tilt", "shape")),
        ("[design]", '[observables]\nnames = ["max_nutation"]\n\n[design]', ("max_nutation",)),
        ("target = [0.0, 0.0, 90.0]", "target = [0.0, 90.0]", ("[control] target",)),
        ("[0.0, 0.0, 1.0], [1.0, 1.0, 1.0]", "[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]", ("span",)),
    ],
)
def test_config_errors(tmp_path, old, new, needles):
    assert old in CONFIG
    config = tmp_path / "bad.toml"
    config.write_text(CONFIG.replace(old, new, 1))
    rc, err = sweep(config, tmp_path / "out")
    assert rc == 2 and "Traceback" not in err
    for needle in needles:
        assert needle in err, err


@pytest.mark.slow
def test_monte_carlo_example_runs_with_its_plot(tmp_path):
    """examples/slew_montecarlo.toml as shipped: 1e4 draws, every one settled (at located
    times, not on the 0.5 s sample grid), some saturated, the Zarr store and the histograms
    written."""
    out = tmp_path / "out"
    rc, err = sweep(EXAMPLE, out)
    assert rc == 0, err
    ds = xr.open_zarr(out / "sweep.zarr")
    assert ds["status"].size == 10_000 and (ds["status"].values == 0).all()
    settling = ds["settling_time"].values
    assert np.isfinite(settling).all()
    on_grid = np.isclose(settling * 2, np.round(settling * 2), rtol=0, atol=1e-9)
    assert on_grid.mean() < 0.01
    assert (ds["saturation_count"].values > 0).any()
    assert (out / "sweep.png").stat().st_size > 10_000
