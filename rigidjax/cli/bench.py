"""`rigidjax bench`: the headline benchmarks in about a minute, as a table and DIR/bench.json.

Each row times rigidjax against a baseline measured in the same run (best of --repeat, after
a warm-up call that compiles): rotation maps against SciPy's `Rotation`; a batch of free
bodies (fixed-step RK4) against the same scheme vectorised in NumPy; reverse-mode gradients
through the batch against its forward run; a sweep against the same bodies as one batched
`simulate`. The fuller benchmarks live in the repository's benchmarks/ folder."""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ._common import RunError, write_atomic

BODIES, STEPS, DT = 10_000, 200, 0.01
GRAD_BODIES = 1_000  # reverse mode keeps the states of every step: a smaller batch
I = (1.0, 2.0, 3.0)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("rigidjax_bench"), help="output folder")
    p.add_argument("--repeat", type=int, default=3, help="timed calls per row (best is kept)")


def _best(f: Callable[[], object], repeat: int) -> float:
    """Seconds of the fastest of `repeat` calls of `f` (after one warm-up call)."""
    import jax

    jax.block_until_ready(f())
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(f())
        times.append(time.perf_counter() - t)
    return min(times)


def _row(name: str, unit: str, work: float, seconds: float, base_s: float, base: str) -> dict:
    """One table row: `work` units done in `seconds` by rigidjax and `base_s` by the baseline."""
    return dict(
        name=name, unit=unit, rigidjax=work / seconds, baseline=work / base_s, baseline_name=base
    )


def _numpy_rk4(w: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The baseline: RK4 on Euler's equations and q̇ = ½ q ∘ (0, Ω), vectorised over bodies."""
    i1, i2, i3 = I
    c = ((i2 - i3) / i1, (i3 - i1) / i2, (i1 - i2) / i3)

    def f(w, q):
        dw = np.stack([c[0] * w[1] * w[2], c[1] * w[2] * w[0], c[2] * w[0] * w[1]])
        dq = 0.5 * np.stack(
            [
                -q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
                q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                q[0] * w[1] + q[3] * w[0] - q[1] * w[2],
                q[0] * w[2] + q[1] * w[1] - q[2] * w[0],
            ]
        )
        return dw, dq

    for _ in range(STEPS):
        k1 = f(w, q)
        k2 = f(w + 0.5 * DT * k1[0], q + 0.5 * DT * k1[1])
        k3 = f(w + 0.5 * DT * k2[0], q + 0.5 * DT * k2[1])
        k4 = f(w + DT * k3[0], q + DT * k3[1])
        w = w + DT / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        q = q + DT / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        q = q / np.linalg.norm(q, axis=0)
    return w, q


def _rows(repeat: int) -> list[dict]:
    import diffrax
    import jax
    import jax.numpy as jnp
    from scipy.spatial.transform import Rotation

    from .. import sweep
    from .._integrate import SolveOptions
    from ..mechanics.body import RigidBody
    from ..mechanics.dynamics import simulate
    from ..mechanics.invariants import energy
    from ..rotations import so3
    from ..solvers import RK4

    rows = []
    rng = np.random.default_rng(0)

    # rotation maps: rotation vector → matrix → rotation vector
    v = rng.normal(size=(100_000, 3))
    roundtrip = jax.jit(lambda v: so3.log(so3.exp(v)))
    vj = jnp.asarray(v)
    ours = _best(lambda: roundtrip(vj), repeat)
    base = _best(
        lambda: Rotation.from_matrix(Rotation.from_rotvec(v).as_matrix()).as_rotvec(), repeat
    )
    rows.append(
        _row("so3.log(so3.exp(v)), 1e5 rotations", "rotations/s", v.shape[0], ours, base, "SciPy")
    )

    # a batch of free bodies, fixed-step RK4, same scheme as the NumPy baseline
    w0 = jnp.asarray(rng.normal(size=(BODIES, 3)))
    ts = jnp.array([0.0, STEPS * DT])
    fixed = SolveOptions(
        solver=RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=DT, max_steps=STEPS
    )

    def final(inertia, w0):
        tr = simulate(RigidBody(inertia, check=False), w0, None, ts, check=False, options=fixed)
        return tr.omega[:, -1], tr.quat[:, -1]

    forward = jax.jit(final)
    inertia = jnp.asarray(I)
    ours = _best(lambda: forward(inertia, w0), repeat)
    wn = np.asarray(w0).T.copy()
    qn = np.zeros((4, BODIES))
    qn[0] = 1.0
    base = _best(lambda: _numpy_rk4(wn, qn), repeat)
    w_ours, _ = forward(inertia, w0)
    err = float(np.max(np.abs(np.asarray(w_ours) - _numpy_rk4(wn, qn)[0].T)))
    if not err < 1e-8:
        raise RunError(f"bench: rigidjax and the NumPy RK4 disagree by {err:.2e}")
    n = BODIES * STEPS
    rows.append(
        _row(
            f"free bodies, RK4, {BODIES} × {STEPS} steps",
            "body-steps/s",
            n,
            ours,
            base,
            "NumPy, same scheme",
        )
    )

    # reverse-mode gradient through the same batch
    w_grad = w0[:GRAD_BODIES]

    def loss(inertia):
        w, _ = final(inertia, w_grad)
        return jnp.mean(energy(RigidBody(inertia, check=False), w))

    grad = jax.jit(jax.grad(loss))
    small = jax.jit(loss)
    g, f = _best(lambda: grad(inertia), repeat), _best(lambda: small(inertia), repeat)
    m = GRAD_BODIES * STEPS
    rows.append(
        _row(
            f"gradient d(mean energy)/dI, {GRAD_BODIES} × {STEPS} steps",
            "body-steps/s",
            m,
            g,
            f,
            "forward run",
        )
    )

    # a sweep of the same bodies against one batched simulate
    design = sweep.grid(k=np.arange(BODIES, dtype=float))

    def model(p):
        k = p["k"].astype(jnp.int32)
        w, q = final(inertia, w0[k][None])
        return {"omega_end": w[0], "quat_end": q[0]}

    swept = _best(lambda: sweep.run(model, design, progress=False)["omega_end"].values, 1)
    rows.append(
        _row(f"sweep.run over {BODIES} points", "body-steps/s", n, swept, ours, "batched simulate")
    )
    return rows


def run(args: argparse.Namespace) -> int:
    from ._common import UsageError, check_out, set_precision

    if args.repeat < 1:
        raise UsageError(f"--repeat must be at least 1, got {args.repeat}")
    check_out(args.out)
    set_precision(False)
    import jax

    from .. import __version__

    start = time.perf_counter()
    rows = _rows(args.repeat)
    for r in rows:
        r["ratio"] = r["rigidjax"] / r["baseline"]
    result = {
        "rigidjax_version": __version__,
        "jax_version": jax.__version__,
        "device": str(jax.devices()[0].device_kind),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "precision": "float64",
        "wall_time_s": time.perf_counter() - start,
        "rows": rows,
    }
    width = max(len(r["name"]) for r in rows)
    print(f"{'benchmark':<{width}}  {'rigidjax':>10}  {'baseline':>10}  ratio  baseline")
    for r in rows:
        print(
            f"{r['name']:<{width}}  {r['rigidjax']:10.3g}  {r['baseline']:10.3g}  "
            f"{r['ratio']:5.2f}  {r['baseline_name']} ({r['unit']})"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "bench.json"
    try:
        write_atomic(path, lambda f: Path(f).write_text(json.dumps(result, indent=2)))
    except OSError as e:
        raise RunError(f"could not write {path}: {e}") from e
    print(f"{result['wall_time_s']:.3g} s in all; wrote JSON: {path.resolve()}")
    return 0
