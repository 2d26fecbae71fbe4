"""Sweep throughput, device scaling and memory: `rigidjax.sweep.run` against raw batched
`simulate`.

Model: the tennis-racket body (1, I2, 2.5) with Ω0 = (δ, 1, δ), a Sobol sample of (I2, δ) in
[1.6, 2.4] × [1e-3, 0.3] (log), torque-free, RK4 at fixed dt = 0.01 over N = 100 steps, outputs
at the end only; the observable is the final body angular velocity Ω(T) (3,), which the raw
batched call computes as well.

Parts (each in a fresh Python process, so compile caches and memory do not carry over):
    ``raw``       one batched `simulate` of B bodies (the whole batch integrated as one state,
                  the library's fastest path), for B = 1e3 … 1e5: body-steps/s; the best B is
                  the baseline;
    ``sweep``     `sweep.run` over the same number of points with its default chunk size and
                  with chunk_size = that best B (in memory, no store): body-steps/s and the
                  ratio to the raw baseline (goal ≥ 0.9);
    ``devices``   the sweep on 1, 2 and 4 virtual CPU devices
                  (`XLA_FLAGS=--xla_force_host_platform_device_count`): body-steps/s (this
                  machine has 2 cores: more devices than cores cannot be faster);
    ``memory``    peak RSS (`ru_maxrss`) of sweeps of 1e5, 1e6 and 1e7 points with a Zarr store
                  (goal: the largest within 2× the smallest; `memory_ratio`). The chunk is
                  integrated and written, then dropped, and the returned Dataset reads the
                  store when used; what grows with the points is the design (sampling 1e7
                  points alone peaks at 730 MiB) and the status vector read for the summary
                  (one byte per point).
Times exclude compilation: the raw call is timed after a warm-up call; a sweep is timed after a
warm-up sweep of the same design (which compiles; `run` keeps the compiled program), and the
store sweeps subtract the compile time `run` reports (`compile_time_s`).

Usage
    python benchmarks/bench_sweep.py [--quick] [--out benchmarks/results/sweep.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import finish, fresh_process, load_average, machine_info, parser  # noqa: E402

N_STEPS, DT = 100, 0.01


def _setup():
    import jax

    jax.config.update("jax_enable_x64", True)
    import diffrax
    import jax.numpy as jnp

    import rigidjax as rj

    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=DT)
    ts = jnp.array([0.0, N_STEPS * DT])
    return jax, jnp, rj, fixed, ts


def _design(n: int):
    import jax

    from rigidjax import sweep

    return sweep.sample(n, key=jax.random.PRNGKey(0), I2=(1.6, 2.4), delta=(1e-3, 0.3, "log"))


def worker_raw(B: int) -> dict:
    jax, jnp, rj, fixed, ts = _setup()
    d = _design(B)
    I2, delta = jnp.asarray(d.points["I2"]), jnp.asarray(d.points["delta"])
    ones = jnp.ones_like(I2)
    body = rj.RigidBody(jnp.stack([ones, I2, 2.5 * ones], -1))
    w0 = jnp.stack([delta, ones, delta], -1)

    def call():
        return jax.block_until_ready(rj.simulate(body, w0, None, ts, **fixed).omega)

    call()
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return {"B": B, "seconds": min(times), "body_steps_per_s": B * N_STEPS / min(times)}


def _model():
    jax, jnp, rj, fixed, ts = _setup()

    def model(p):
        body = rj.RigidBody(jnp.stack([1.0, p["I2"], 2.5]), check=False)
        tr = rj.simulate(body, jnp.stack([p["delta"], 1.0, p["delta"]]), None, ts, **fixed)
        return {"omega_end": tr.omega[-1]}

    return model


def worker_sweep(n: int, chunk: int | None, store: bool) -> dict:
    import jax

    from rigidjax import sweep

    model, d = _model(), _design(n)
    kw = dict(chunk_size=chunk, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        if not store:
            sweep.run(model, d, **kw)  # warm-up: compiles
        t0 = time.perf_counter()
        ds = sweep.run(model, d, store=(Path(tmp) / "s.zarr") if store else None, **kw)
        wall = time.perf_counter() - t0
    compute = wall - ds.attrs["compile_time_s"]
    return {
        "points": n,
        "chunk": ds.attrs["chunk"],
        "num_devices": jax.device_count(),
        "seconds": compute,
        "compile_s": ds.attrs["compile_time_s"],
        "body_steps_per_s": n * N_STEPS / compute,
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "failures": ds.attrs["failures"],
    }


def _run(*args: str, devices: int | None = None) -> dict:
    env = dict(os.environ)
    if devices is not None:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    out, wall, proc = fresh_process(__file__, "--worker", *args, env=env)
    if out is None:
        raise RuntimeError(f"worker {args} failed:\n{proc.stderr[-3000:]}")
    out["process_wall_s"] = wall
    return out


def main(argv=None) -> int:
    p = parser(__doc__, "sweep.json", quick="small sizes: a smoke run", repeats=None)
    p.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        kind, *rest = args.worker
        if kind == "raw":
            res = worker_raw(int(rest[0]))
        else:
            chunk = None if rest[1] == "default" else int(rest[1])
            res = worker_sweep(int(rest[0]), chunk, rest[2] == "store")
        print(json.dumps(res))
        return 0

    t0 = time.perf_counter()
    out: dict = {
        "benchmark": "bench_sweep",
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "quick": args.quick,
        "parameters": {"steps": N_STEPS, "dt": DT, "solver": "RK4, fixed steps, float64"},
        "machine": machine_info(),
        "load_average_start": load_average(),
    }
    batches = [1_000, 10_000] if args.quick else [1_000, 10_000, 100_000]
    out["raw"] = [_run("raw", str(B)) for B in batches]
    best = max(out["raw"], key=lambda r: r["body_steps_per_s"])
    n = 4 * best["B"]
    out["sweep"] = [_run("sweep", str(n), c, "memory") for c in ("default", str(best["B"]))]
    for r in out["sweep"]:
        r["ratio_to_raw"] = r["body_steps_per_s"] / best["body_steps_per_s"]
        print(
            f"sweep chunk {r['chunk']}: {r['body_steps_per_s']:.3g} body-steps/s, "
            f"{r['ratio_to_raw']:.2f}x raw batched simulate (B={best['B']})"
        )
    out["devices"] = [_run("sweep", str(n), str(best["B"]), "memory", devices=k) for k in (1, 2, 4)]
    for r in out["devices"]:
        print(f"{r['num_devices']} devices: {r['body_steps_per_s']:.3g} body-steps/s")
    sizes = [10_000, 100_000] if args.quick else [100_000, 1_000_000, 10_000_000]
    out["memory"] = [_run("sweep", str(m), "default", "store") for m in sizes]
    first, last = out["memory"][0], out["memory"][-1]
    out["memory_ratio"] = last["peak_rss_bytes"] / first["peak_rss_bytes"]
    out["memory_ratio_points"] = last["points"] / first["points"]
    for r in out["memory"]:
        print(f"{r['points']} points to a store: peak RSS {r['peak_rss_bytes'] / 2**20:.0f} MiB")
    finish(out, args.out, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
