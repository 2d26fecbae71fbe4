"""sweep.run: the Dataset contract, storage and resume (also after SIGKILL), local devices,
failures recorded per point, and bad input refused before any computation."""

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

import rigidjax as rj
from rigidjax import _folders, sweep
from tests.helpers import rigid_body_dop853
from tests.sweep._model import TS, design, model

ROOT = Path(__file__).resolve().parents[2]
CHUNK = 4  # at most 4 points per chunk: blocks of the 5 × 3 grid are rows of 3, 5 chunks


@pytest.fixture(scope="module")
def in_memory():
    return sweep.run(model, design(), chunk_size=np.int64(CHUNK), progress=False)


def test_dataset_contract(in_memory):
    ds, d = in_memory, design()
    assert ds["min_w2"].dims == ("I2", "offset")
    assert ds["omega_end"].dims == ("I2", "offset", "omega_end_dim_0")
    np.testing.assert_array_equal(ds["I2"], d.coords["I2"][1])
    assert ds["status"].dtype == np.int8 and np.all(ds["status"] == 0)
    assert ds["status"].attrs["flag_meanings"].split()[0] == "ok"
    for key in ("rigidjax_version", "jax_version", "num_devices", "num_processes", "wall_time_s"):
        assert key in ds.attrs
    assert ds.attrs["num_devices"] == jax.device_count() and ds.attrs["num_processes"] == 1


def test_values_equal_a_loop_of_simulate(in_memory):
    """Each point's observables are those of simulate at that point (the padded last chunk
    included), and simulate agrees with SciPy."""
    for I2, off in [(1.6, 0.01), (2.4, 0.1), (2.2, 0.05)]:
        out = model({"I2": jnp.asarray(I2), "offset": jnp.asarray(off)})
        got = in_memory.sel(I2=I2, offset=off)
        np.testing.assert_allclose(got["min_w2"], out["min_w2"], rtol=1e-12)
        np.testing.assert_allclose(got["omega_end"], out["omega_end"], rtol=1e-12)
        w_ref, _ = rigid_body_dop853([1.0, I2, 2.5], [off, 1.0, off], [1, 0, 0, 0], TS)
        np.testing.assert_allclose(got["omega_end"], w_ref[-1], atol=1e-3)  # RK4 at h = 0.25


def test_store_equals_in_memory_and_opens_without_rigidjax(in_memory, tmp_path):
    store = tmp_path / "s.zarr"
    ds = sweep.run(model, design(), store=store, chunk_size=CHUNK, progress=False)
    # the values stay in the store until used (a sweep larger than memory stays bounded by
    # the chunk); they compare equal to the in-memory run's
    assert not any(ds[name].variable._in_memory for name in ("omega_end", "min_w2", "status"))
    xr.testing.assert_identical(ds.drop_attrs(), in_memory.drop_attrs())
    opened = xr.open_zarr(store)  # no rigidjax involved
    xr.testing.assert_identical(opened.load(), ds)
    # the same call again finds every chunk done and computes nothing
    again = sweep.run(model, design(), store=store, chunk_size=CHUNK, progress=False)
    xr.testing.assert_equal(again, ds)
    # without chunk_size the stored chunking is adopted (the default depends on free memory,
    # which changes between calls and between the processes of one sweep)
    adopted = sweep.run(model, design(), store=store, progress=False)
    xr.testing.assert_equal(adopted, ds)
    with pytest.raises(ValueError, match="was written for another design"):
        sweep.run(model, sweep.grid(I2=[1.7, 1.9], offset=[0.01]), store=store, progress=False)
    with pytest.raises(ValueError, match="another chunk_size"):
        sweep.run(model, design(), store=store, chunk_size=2, progress=False)


_KILLED_RUN = """
import os, signal, sys
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
from rigidjax import sweep
from tests.sweep._model import design, model
calls = [0]
def count(_):
    calls[0] += 1
    if calls[0] == 3:  # (replaced by the test) while computing a chunk
        os.kill(os.getpid(), signal.SIGKILL)
def killing_model(p):
    out = model(p)
    jax.debug.callback(count, p["I2"])
    return out
# the same observables as `model`, so the store is the one `model` would write
sweep.run(killing_model, design(), store=sys.argv[1], chunk_size=4, progress=False)
"""


def test_resume_after_sigkill(in_memory, tmp_path):
    store = tmp_path / "killed.zarr"
    # vmap of a debug callback runs it once per point: the kill comes at the first point of
    # the third chunk (chunks are rows of 3 points)
    script = _KILLED_RUN.replace("calls[0] == 3", "calls[0] == 2 * 3 + 1")
    proc = subprocess.run([sys.executable, "-c", script, str(store)], cwd=ROOT, check=False)
    assert proc.returncode == -signal.SIGKILL
    import zarr

    done = np.asarray(zarr.open_group(str(store), mode="r")["_sweep/done"][:])
    assert done.tolist() == [1, 1, 0, 0, 0]  # nothing half-written counts as done
    ds = sweep.run(model, design(), store=store, chunk_size=CHUNK, progress=False)
    xr.testing.assert_identical(ds.drop_attrs(), in_memory.drop_attrs())


_DEVICES_RUN = """
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
from rigidjax import sweep
from tests.sweep._model import design, model
ds = sweep.run(model, design(), chunk_size=4, progress=False)
print(json.dumps({"num_devices": ds.attrs["num_devices"], "local": jax.local_device_count(),
                  "min_w2": ds["min_w2"].values.tolist()}))
"""


def test_four_local_devices_give_the_single_device_result(in_memory):
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(_DEVICES_RUN)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["num_devices"] == 4 and out["local"] == 4
    np.testing.assert_allclose(out["min_w2"], in_memory["min_w2"].values, rtol=1e-13)


def test_failures_are_recorded_per_point_and_counted():
    def fragile(p):
        out = model(p)
        # non-finite where I2 > 2.3; an error (an invalid body, checked) where I2 < 1.65
        out["min_w2"] = jnp.where(p["I2"] > 2.3, jnp.nan, out["min_w2"])
        checked = rj.RigidBody(jnp.stack([1.0, p["I2"], 2.65]))  # not physical for I2 < 1.65
        out["omega_end"] = out["omega_end"] + 0 * rj.energy(checked, out["omega_end"])
        return out

    ds = sweep.run(fragile, design(), chunk_size=CHUNK, progress=False)
    status = ds["status"].values
    assert np.all(status[0] == 3) and np.all(status[-1] == 1) and np.all(status[1:-1] == 0)
    assert ds.attrs["failures"] == {
        "nonfinite_observable": 3,
        "integration_failed": 0,
        "model_error": 3,
    }
    assert any("triangle inequality" in e for e in ds.attrs["errors"])
    assert np.all(np.isnan(ds["omega_end"].values[0]))  # no value for a point that raised
    assert np.all(np.isfinite(ds["omega_end"].values[1:]))


def test_failed_integration_gets_status_2():
    d = sweep.grid(I2=[1.8, 2.0], offset=[0.05])

    def short(p):
        body = rj.RigidBody(jnp.stack([1.0, p["I2"], 2.5]), check=False)
        tr = rj.simulate(
            body, jnp.stack([p["offset"], 1.0, p["offset"]]), None, TS, throw=False, max_steps=2
        )
        return {"w": tr.omega[-1], "result": tr.result}

    ds = sweep.run(short, d, progress=False)
    assert np.all(ds["status"] == 2) and ds.attrs["failures"]["integration_failed"] == 2


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(chunk_size=0), "chunk_size must be a positive integer"),
        (dict(chunk_size=-3), "chunk_size must be a positive integer"),
    ],
)
def test_bad_arguments_before_any_computation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sweep.run(model, design(), progress=False, **kwargs)


def test_a_factor_that_overflows_float32_is_refused_before_any_computation():
    """Without x64 the points are float32: 1e39 (finite in the design's float64) would reach
    the model as inf."""

    def never(point):
        raise AssertionError("the model was called")

    with jax.enable_x64(False):
        with pytest.raises(ValueError, match="'I2' overflows float32.*point 1 has 1e"):
            sweep.run(never, sweep.grid(I2=np.array([2.0, 1e39])), progress=False)


def test_bad_models_and_stores(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="is a file"):
        sweep.run(model, design(), store=tmp_path / "file", progress=False)
    with pytest.raises(ValueError, match="cannot be written"):
        sweep.run(model, design(), store=tmp_path / "file" / "s.zarr", progress=False)
    with pytest.raises(ValueError, match="pure JAX function of the point"):
        sweep.run(lambda p: {"x": jnp.zeros(3 if p["I2"] > 2 else 2)}, design(), progress=False)
    with pytest.raises(ValueError, match="must return a non-empty dict"):
        sweep.run(lambda p: p["I2"], design(), progress=False)
    with pytest.raises(ValueError, match="clashes with a factor"):
        sweep.run(lambda p: {"I2": p["I2"]}, design(), progress=False)
    sampled = sweep.sample(4, key=jax.random.key(0), I2=(1.1, 2.9))
    with pytest.raises(ValueError, match="'point' clashes with a factor, a dimension"):
        sweep.run(lambda p: {"point": p["I2"]}, sampled, progress=False)
    # a folder with files of the user's and no store: refused, never emptied
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(ValueError, match="a folder with files and no Zarr store"):
        sweep.run(model, design(), store=tmp_path / "mine", progress=False)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"
    # (with the jaxtyping hook on, its TypeCheckError names the parameter and the type)
    with pytest.raises(TypeError, match=r"(?s)design.*Design"):
        sweep.run(model, {"I2": [1.0]}, progress=False)


def test_unwritable_store_as_root(tmp_path, monkeypatch):
    """Writability is probed, not read from permissions (`os.access` says yes to root, and a
    store under /proc failed in zarr with a FileNotFoundError)."""

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(_folders.tempfile, "TemporaryFile", refuse)
    with pytest.raises(ValueError, match="cannot be written: .*Permission denied"):
        sweep.run(model, design(), store=tmp_path / "a" / "s.zarr", progress=False)
    assert not (tmp_path / "a").exists()


_PROCESS_RUN = """
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_cpu_collectives_implementation", "gloo")
port, pid, store = sys.argv[1], int(sys.argv[2]), sys.argv[3]
jax.distributed.initialize(f"localhost:{port}", num_processes=2, process_id=pid)
from rigidjax import sweep
from tests.sweep._model import design, model
ds = sweep.run(model, design(), store=store, chunk_size=4, progress=False)
n = ds.attrs["num_processes"]
print(json.dumps({"num_processes": n, "min_w2": ds["min_w2"].values.tolist()}))
"""


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_share_the_chunks_and_both_return_everything(in_memory, tmp_path):
    """jax.distributed on localhost (CPU collectives over gloo): both processes return the
    complete Dataset, equal to the single-process one, from one store."""
    store, port = tmp_path / "mp.zarr", str(_free_port())
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _PROCESS_RUN, port, str(pid), str(store)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for pid in (0, 1)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-2000:]
        got = json.loads(out.strip().splitlines()[-1])
        assert got["num_processes"] == 2
        np.testing.assert_allclose(got["min_w2"], in_memory["min_w2"].values, rtol=1e-13)
    xr.testing.assert_identical(xr.open_zarr(store).load().drop_attrs(), in_memory.drop_attrs())
