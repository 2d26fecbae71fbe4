"""The command as separate processes: the persistent compilation cache across runs, `rigidjax
bench`, and a sweep shared by two processes (`--coordinator`, `--num-processes`,
`--process-id`)."""

import json
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from .test_sweep_command import CONFIG

pytestmark = pytest.mark.slow


def command() -> list[str]:
    script = Path(sys.executable).with_name("rigidjax")
    return [str(script)] if script.exists() else [sys.executable, "-m", "rigidjax.cli"]


def run(*argv: str, cache: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "RIGIDJAX_CACHE_DIR": str(cache)}
    env.pop("XLA_FLAGS", None)
    return subprocess.run(
        [*command(), *argv], capture_output=True, text=True, env=env, timeout=timeout, check=False
    )


def compile_seconds(stdout: str) -> float:
    m = re.search(r"compile (\S+) s", stdout)
    assert m is not None, stdout
    return float(m.group(1))


def test_second_run_loads_the_compiled_program(tmp_path):
    """The README's main command (shortened): the second run spends < 20% of the first run's
    compile time; with --no-cache nothing is stored."""
    cache = tmp_path / "cache"
    argv = ("--t-end", "5", "--num", "51", "--no-progress", "--out", str(tmp_path / "run"))
    first = run(*argv, cache=cache)
    assert first.returncode == 0, first.stderr
    assert any(cache.iterdir())
    second = run(*argv, cache=cache)
    assert second.returncode == 0, second.stderr
    c1, c2 = compile_seconds(first.stdout), compile_seconds(second.stdout)
    assert c2 < 0.2 * c1, (c1, c2)
    unused = tmp_path / "unused"
    off = run(*argv, "--no-cache", cache=unused)
    assert off.returncode == 0, off.stderr
    assert not unused.exists() or not any(unused.iterdir())


def test_bench_writes_table_and_json(tmp_path):
    p = run("bench", "--repeat", "1", "--out", str(tmp_path), "--no-progress", cache=tmp_path / "c")
    assert p.returncode == 0, p.stderr
    result = json.loads((tmp_path / "bench.json").read_text())
    assert len(result["rows"]) == 4
    for row in result["rows"]:
        assert row["rigidjax"] > 0 and row["baseline"] > 0
        assert row["ratio"] == pytest.approx(row["rigidjax"] / row["baseline"])
        assert row["name"] in p.stdout


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_share_a_sweep(tmp_path):
    config = tmp_path / "racket.toml"
    config.write_text(CONFIG + "\n[run]\nchunk_size = 2\n")
    single = run("sweep", str(config), "--out", str(tmp_path / "one"), cache=tmp_path / "c")
    assert single.returncode == 0, single.stderr
    port = free_port()
    shared = tmp_path / "two"
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "RIGIDJAX_CACHE_DIR": str(tmp_path / "c2")}
    env.pop("XLA_FLAGS", None)
    procs = [
        subprocess.Popen(
            [*command(), "sweep", str(config), "--out", str(shared), "--no-progress"]
            + ["--coordinator", f"localhost:{port}", "--num-processes", "2"]
            + ["--process-id", str(i)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for i in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err
    assert "2 process(es)" in outs[0][0] and "swept" not in outs[1][0]  # process 0 reports
    a = xr.open_zarr(tmp_path / "one" / "sweep.zarr").load()
    b = xr.open_zarr(shared / "sweep.zarr").load()
    assert b.attrs["num_processes"] == 2
    for name in ("max_nutation", "energy_drift", "omega_end", "status"):
        np.testing.assert_allclose(a[name].values, b[name].values, rtol=1e-12, atol=1e-15)
