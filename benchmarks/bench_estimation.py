"""The multiplicative EKF: `rigidjax.estimation.mekf` against a NumPy loop of the same filter.

Problem: R runs × N steps (default 1e4 × 1000) of a gyro and a star tracker at 10 Hz on bodies
turning at constant rates (`rigidjax.sensors`), one measurement row in ten missing (NaN); the
filter returns the attitude, bias and covariance at every step and the log-likelihood.

Baseline (measured in the same run): `benchmarks/reference/mekf_numpy.py`, a Python loop over
the steps vectorised over the runs with NumPy's batched matrix products and solves. `mekf` is
compiled ahead of time (its compile time recorded) and timed on the same data; both results
are compared (largest attitude difference, relative log-likelihood difference). The ratio is
the NumPy time over `mekf`'s.

Usage
    python benchmarks/bench_estimation.py [--quick] [--out benchmarks/results/estimation.json]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent / "reference"))

from _harness import Timing, finish, load_average, machine_info, parser  # noqa: E402

ARW, RRW, SIGMA, DT = 1e-5, 1e-7, 2e-5, 0.1


def data(runs: int, steps: int):
    import jax
    import jax.numpy as jnp

    from rigidjax import sensors
    from rigidjax.rotations import quat

    @jax.jit
    def make(key):
        ts = jnp.arange(steps + 1) * DT
        k1, k2, k3, k4 = jax.random.split(key, 4)
        w = 0.02 * jax.random.normal(k1, (runs, 3))
        q_start = quat.random(k2, (runs,))
        q = quat.mul(q_start[:, None], quat.from_rotvec(ts[:, None] * w[:, None]))
        omega = jnp.broadcast_to(w[:, None], (runs, steps + 1, 3))
        rate, _ = sensors.gyro(k3, ts, omega, arw=ARW, rrw=RRW, bias0=jnp.full(3, 1e-4))
        qm = sensors.star_tracker(k4, q, SIGMA)
        qm = jnp.where((jnp.arange(steps + 1) % 10 == 5)[:, None], jnp.nan, qm)
        return ts, rate, qm, qm[:, 0]

    return make(jax.random.key(0))


def main(argv=None) -> int:
    quick = "1000 runs × 200 steps: a smoke run"
    args = parser(__doc__, "estimation.json", quick=quick, repeats=None).parse_args(argv)
    t0 = time.perf_counter()
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    from mekf_numpy import mekf_numpy, qlog, qmul

    from rigidjax.estimation import mekf

    runs, steps = (1000, 200) if args.quick else (10_000, 1000)
    out: dict = {
        "benchmark": "bench_estimation",
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "quick": args.quick,
        "parameters": {
            "runs": runs,
            "steps": steps,
            "dt": DT,
            "arw": ARW,
            "rrw": RRW,
            "sigma": SIGMA,
            "missing": "one measurement row in ten (NaN)",
            "dtype": "float64",
            "outputs": "quat, bias, cov (6x6) at every step, log-likelihood",
        },
        "machine": machine_info(),
        "load_average_start": load_average(),
    }
    ts, rate, qm, q0 = jax.block_until_ready(data(runs, steps))
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-8] * 3))

    def run(ts, rate, qm, q0, P0):
        r = mekf(ts, rate, qm, arw=ARW, rrw=RRW, sigma=SIGMA, q0=q0, P0=P0)
        return r.quat, r.bias, r.cov, r.log_likelihood

    jx = Timing(run, ts, rate, qm, q0, P0)
    jx.warm_up()
    jx.run(repeats=3)
    nt, nr, nq, n0 = (np.asarray(a) for a in (ts, rate, qm, q0))
    npy = Timing(
        lambda: mekf_numpy(nt, nr, nq, arw=ARW, rrw=RRW, sigma=SIGMA, q0=n0, P0=np.asarray(P0)),
        aot=False,
    )
    npy.run(repeats=1)
    q_np, b_np, P_np, ll_np = npy.output
    q_jx, b_jx, P_jx, ll_jx = jx.output
    conj = np.asarray(q_jx) * np.array([1.0, -1, -1, -1])
    dq = np.linalg.norm(qlog(qmul(conj, q_np)), axis=-1)
    out["mekf"] = jx.summary(cpu=True) | {
        "trace_lower_s": jx.trace_lower_s,
        "compile_s": jx.compile_s,
        "first_run_s": jx.first_run_s,
        "run_steps_per_s": runs * steps / jx.best,
    }
    out["numpy"] = npy.summary(cpu=True) | {"run_steps_per_s": runs * steps / npy.best}
    out["ratio_numpy_over_mekf"] = npy.best / jx.best
    out["agreement"] = {
        "max_attitude_difference_rad": float(dq.max()),
        "max_bias_difference": float(np.max(np.abs(np.asarray(b_jx) - b_np))),
        "max_cov_difference_relative": float(
            np.max(np.abs(np.asarray(P_jx) - P_np)) / np.max(np.abs(P_np))
        ),
        "max_log_likelihood_difference_relative": float(
            np.max(np.abs(np.asarray(ll_jx) - ll_np) / np.abs(ll_np))
        ),
    }
    print(
        f"mekf {runs} runs x {steps} steps: {jx.best:.3g} s (compile {jx.compile_s:.3g} s); "
        f"NumPy loop {npy.best:.3g} s: {out['ratio_numpy_over_mekf']:.3g}x"
    )
    print(f"agreement: {out['agreement']}")
    finish(out, Path(args.out), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
