"""Issue 26, item 1: eager value-and-derivative checks of the rotation maps in one long process
died with `Fatal Python error: Segmentation fault`.

Cause (reproduced on the code before the fix): every eager check compiled new XLA executables
that the process kept: the run-time checks (`equinox.error_if`, a `lax.cond` around host
callbacks made anew at each call) evaluated op by op under `jacfwd`/`jacrev`/`grad`. Each check
of the sequence below added about 7600 memory mappings (and 420 MB); at Linux's
`vm.max_map_count` (65530), after 8 checks, LLVM could not map the next executable
("LLVM compilation error: Cannot allocate memory") and the process died. Now the checks run in
NumPy on the known primal and each map is one compiled program per shape (and per derivative),
so the number of compilations is bounded: the test asserts that, after the first checks, no
check compiles anything, and that the process's memory mappings do not grow (Linux)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SCRIPT = textwrap.dedent(
    """
    import faulthandler, json, os
    faulthandler.enable()
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    import rigidjax as rj

    compiles = [0]

    def count(event, seconds, **kwargs):
        compiles[0] += event == "/jax/core/compile/backend_compile_duration"

    jax.monitoring.register_event_duration_secs_listener(count)

    def maps():
        if not os.path.exists("/proc/self/maps"):
            return None
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)

    E = np.eye(3)

    def rotation(n, t):
        n = np.asarray(n, float) / np.linalg.norm(n)
        K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
        return E + np.sin(t) * K + (1 - np.cos(t)) * K @ K

    rng = np.random.default_rng(0)
    axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 1, 1]]
    axes += [rng.normal(size=3) for _ in range(4)]
    cases = [rotation(n, t) for t in (1e-9, 1e-5, np.pi - 1e-5, np.pi - 1e-9) for n in axes]
    cases += [2 * np.outer(n, n) / (n @ n) - E for n in map(np.asarray, axes)]  # half-turns

    maps_ = [rj.so3.log, rj.quat.from_matrix, rj.mrp.from_matrix,
             lambda P: rj.so3.distance(jnp.eye(3), P)]
    maps_ += [lambda P, s=s: rj.euler.from_matrix(P, s) for s in rj.euler.SEQUENCES]
    for i, P in enumerate(cases):
        P = jnp.asarray(P)
        for f in maps_:
            for out in (f(P), jax.jacfwd(f)(P), jax.jacrev(f)(P),
                        jax.grad(lambda P: jnp.sum(f(P)))(P)):
                assert np.all(np.isfinite(np.asarray(out)))
        print(json.dumps({"check": i, "compiles": compiles[0], "maps": maps()}), flush=True)
    """
)


@pytest.mark.slow
def test_eager_derivative_checks_compile_a_bounded_number_of_programs(tmp_path):
    """45 checks (θ near 0 and π about 9 axes, and half-turns), each the value, jacfwd, jacrev
    and grad of so3.log, quat/mrp.from_matrix, so3.distance(E, ·) and euler.from_matrix in all
    24 sequences, in one process with faulthandler: it ends normally, and from the third check
    on nothing is compiled (before the fix: thousands of executables per check)."""
    script = tmp_path / "long_process.py"
    script.write_text(SCRIPT)
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=1200
    )
    assert proc.returncode == 0, proc.stderr[-5000:]
    rows = [json.loads(line) for line in proc.stdout.splitlines()]
    assert len(rows) == 45
    after = rows[2:]
    assert after[-1]["compiles"] == after[0]["compiles"], rows
    if after[0]["maps"] is not None:
        assert after[-1]["maps"] <= after[0]["maps"] + 100, rows
