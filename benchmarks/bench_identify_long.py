"""Inertia identification from long records: growing prefixes against the whole record at once.

A torque-free body with a full inertia tensor ``I = R diag(1, 2, 2.6) Rᵀ`` (the one in
``tests/fit/data.py``), Ω0 = (0.4, 1.1, −0.7): gyro data every 0.1 s over ``--spans`` seconds
(~1.1 rad of turning a second) from SciPy DOP853 (rtol = atol = 1e-13), noise σ = 0.01 rad/s.
``identify_inertia(ts, ω, sigma_omega=σ)`` with its defaults, which fit a record that turns the
body through more than 30 rad in growing prefixes (``rigidjax.fit.identify.TURN``), against the
baseline of the same call fitting the whole record at once (``TURN = inf``, set before the
first call in a fresh process: the fit is compiled with it). Each fit in its own process:
first call (trace + compile + fit) and one more call on new noise. Recorded: wall and CPU
times, convergence, LM steps, the largest |error|/std of the principal moments.

Usage
    python benchmarks/bench_identify_long.py [--quick] [--seed 0] [--spans 100,300,1000]
        [--out benchmarks/results/identify_long.json]
"""

from __future__ import annotations

import argparse
import json

from _harness import Log, execute, machine_info, parser, table, timed, timestamp, worker

MOMENTS = (1.0, 2.0, 2.6)
ROTVEC = (0.3, -0.5, 0.2)
W0 = (0.4, 1.1, -0.7)
DT, SIGMA = 0.1, 0.01


def fit_worker(span: float, prefixes: bool, seed: int) -> dict:
    """Two fits of `span` seconds of noisy gyro data (the second on new noise)."""
    import jax

    jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it
    import numpy as np
    from scipy.integrate import solve_ivp
    from scipy.spatial.transform import Rotation

    import rigidjax.fit.identify as identify

    if not prefixes:
        identify.TURN = float("inf")
    R = Rotation.from_rotvec(ROTVEC).as_matrix()
    I = R @ np.diag(MOMENTS) @ R.T
    I_inv = np.linalg.inv(I)
    ts = np.arange(round(span / DT) + 1) * DT
    sol = solve_ivp(
        lambda t, w: I_inv @ -np.cross(w, I @ w), (0, span), W0, "DOP853", ts, rtol=1e-13,
        atol=1e-13,
    )  # fmt: skip
    omega = sol.y.T
    turned = float(np.sum(np.linalg.norm(omega, axis=1)) * DT)
    truth = np.array(MOMENTS) / sum(MOMENTS)
    rng = np.random.default_rng(seed)
    calls = []
    for _ in range(2):
        obs = omega + SIGMA * rng.normal(size=omega.shape)
        est, wall, cpu = timed(identify.identify_inertia, ts, obs, sigma_omega=SIGMA)
        moments, std = np.asarray(est.principal_moments), np.asarray(est.principal_moments_std)
        calls.append(
            dict(
                seconds=round(wall, 3),
                cpu_seconds=round(cpu, 3),
                converged=bool(est.converged),
                lm_steps=int(est.num_steps),
                max_moment_error=float(np.max(np.abs(moments - truth))),
                max_moment_std=float(np.max(std)),
                max_error_over_std=float(np.max(np.abs(moments - truth) / std)),
            )
        )
    return dict(span_s=span, samples=ts.size, turned_rad=round(turned, 1), calls=calls)


def run(args, log: Log) -> dict:
    spans = [300.0] if args.quick else args.spans
    log(f"bench_identify_long: spans {spans} s, load {log.load_start}")
    results = {}
    for span in spans:
        for name, prefixes in (("prefixes", True), ("whole", False)):
            r = worker(__file__, "--_span", str(span), "--_prefixes", str(int(prefixes)),
                       "--seed", str(args.seed), cold=True)  # fmt: skip
            results[f"{name}_{span:g}"] = r
            log(
                f"  {span:g} s, {name}: "
                + (
                    f"ERROR\n{r['error']}"
                    if "error" in r
                    else ", ".join(
                        f"{c['seconds']:.1f} s, {c['lm_steps']} steps, converged "
                        f"{c['converged']}, |error|/std {c['max_error_over_std']:.2g}"
                        for c in r["calls"]
                    )
                )
            )
    return dict(
        benchmark="bench_identify_long",
        timestamp=timestamp(),
        quick=args.quick,
        parameters=dict(
            moments=MOMENTS,
            rotvec=ROTVEC,
            omega0=W0,
            sample_interval_s=DT,
            noise_sigma=SIGMA,
            spans_s=spans,
            seed=args.seed,
            baseline="the whole record at once (TURN = inf), the same call otherwise",
        ),  # fmt: skip
        machine=machine_info(),
        load_average_start=log.load_start,
        results=results,
        summary=summarise(results),
    )


def summarise(results: dict) -> dict:
    """Per fit: the calls that converged (of 2), the repeat call's seconds and LM steps."""
    out = {}
    for key, r in results.items():
        calls = r.get("calls", [])
        if calls:
            out[f"{key}_s_converged_calls"] = sum(c["converged"] for c in calls)
            out[f"{key}_s_repeat_seconds"] = calls[-1]["seconds"]
            out[f"{key}_s_repeat_lm_steps"] = calls[-1]["lm_steps"]
    return out


def print_table(out: dict) -> None:
    rows = [
        [key, r["turned_rad"], "first" if k == 0 else "repeat", c["seconds"], c["lm_steps"],
         str(c["converged"]), c["max_error_over_std"]]
        for key, r in out["results"].items()
        for k, c in enumerate(r.get("calls", []))
    ]  # fmt: skip
    columns = [("fit", "<16"), ("turned rad", ">11.0f"), ("call", ">8"), ("s", ">8.1f"),
               ("LM steps", ">9"), ("converged", ">10"), ("err/std", ">9.2g")]  # fmt: skip
    print(table(columns, rows))


def main(argv=None) -> None:
    p = parser(__doc__, "identify_long.json", quick="300 s only", repeats=None, seed=True)
    p.add_argument(
        "--spans", type=lambda x: [float(v) for v in x.split(",")], default=[100.0, 300.0, 1000.0]
    )
    p.add_argument("--_span", type=float, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_prefixes", type=int, default=1, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args._span is not None:
        print(json.dumps(fit_worker(args._span, bool(args._prefixes), args.seed)))
    else:
        execute(run, args, print_table)


if __name__ == "__main__":
    main()
