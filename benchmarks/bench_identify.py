"""Inertia identification and gradient cost through `simulate`: time, compile, memory.

Part 1: identification (``identify_inertia``), every mode (``MODES``)
    A torque-free body with a full inertia tensor ``I = R diag(1, 2, 2.6) Rᵀ`` (the one in
    ``tests/fit/data.py``); Ω and the attitude at T equally spaced times on [0, 8] from SciPy
    DOP853 (rtol = atol = 1e-13), plus noise σ = 1e-3. Each mode and T in a fresh process (no
    persistent compilation cache): the first call (trace + compile + fit), then ``--repeats``
    calls with new data of the same shape (another Ω0 and noise draw; the program is reused).
    Recorded: wall and CPU times, convergence, LM steps, the trace-relative error, the largest
    |error|/std, the bias error, the peak RSS.

Part 1b: experiment design (``design_excitation``) against PRBS
    Body diag(1, 2, 2.6), Ω0 = (0.1, 0.05, −0.05), 20 s, 8 segments, |u_i| ≤ 0.1, 10 gyro
    samples per segment: the design time, log det of the design's information against 20 PRBS
    draws, their Cramér–Rao std, and known-torque fits of SciPy data (5 draws each).

Part 2: gradient / forward cost through ``simulate``
    ``L(I, Ω0) = c·Ω(T) + (q(T)·q_c)²`` with RK4 at T/N, T = 10, N = 10³ and 10⁴; ``jax.grad``
    w.r.t. the 3×3 tensor and Ω0; forward and gradient compiled ahead of time, warmed up, timed
    in ``--grad-repeats`` interleaved rounds. Adjoints: ``default`` (max_steps = 100 000),
    ``tight`` (max_steps = N), ``store_all`` (checkpoints = N), and a hand-written RK4 in
    ``lax.scan`` (``lean_scan``, ``lean_scan_remat``); not with ``--quick``. Memory: XLA's
    ``memory_analysis()`` of the compiled programs, and the process's peak RSS. The gradient is
    checked against central finite differences.

Usage
    python benchmarks/bench_identify.py [--quick] [--repeats 3] [--seed 0]
        [--parts identify,design,grad] [--out benchmarks/results/identify.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from _gradient_cost import GRAD_T, SIM_CONFIGS, grad_worker
from _harness import (
    Log,
    execute,
    machine_info,
    parser,
    table,
    timed,
    timestamp,
    worker,
)
from _harness import maxrss_mib as _maxrss_mib

ROTVEC = (0.3, -0.5, 0.2)
MOMENTS = (1.0, 2.0, 2.6)
W0 = (0.4, 1.1, -0.7)
SPAN = 8.0
NOISE = 1e-3


def _setup_jax():
    import jax

    jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it
    return jax


def true_inertia():
    import numpy as np
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(ROTVEC).as_matrix()
    return R @ np.diag(MOMENTS) @ R.T


# --------------------------------------------------------------------------- part 1


def motion(T: int, w0, q0=(1.0, 0.0, 0.0, 0.0), I=None, torque=None, span=SPAN):
    """Clean body angular velocity (T, 3) and attitude (T, 4) at T equally spaced times on
    [0, span], SciPy DOP853 (rtol = atol = 1e-13; independent of rigidjax)."""
    import numpy as np
    from scipy.integrate import solve_ivp

    I = true_inertia() if I is None else I
    ts = np.linspace(0.0, span, T)

    def rhs(t, y):
        w, q = y[:3], y[3:]
        K = np.zeros(3) if torque is None else torque(t)
        dw = np.linalg.solve(I, K - np.cross(w, I @ w))
        dq = 0.5 * np.concatenate([[-(q[1:] @ w)], q[0] * w + np.cross(q[1:], w)])
        return np.concatenate([dw, dq])

    y0 = np.concatenate([np.asarray(w0, float), np.asarray(q0, float)])
    sol = solve_ivp(rhs, (0.0, span), y0, t_eval=ts, method="DOP853", rtol=1e-13, atol=1e-13)
    q = sol.y.T[:, 3:]
    return ts, sol.y.T[:, :3], q / np.linalg.norm(q, axis=1, keepdims=True)


def attitude_noise(q, rng):
    """q ∘ exp(δ), δ ~ N(0, NOISE² E)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(q.reshape(-1, 4), scalar_first=True)
    r = r * Rotation.from_rotvec(NOISE * rng.normal(size=(len(r), 3)))
    return r.as_quat(scalar_first=True).reshape(q.shape)


MODES = {
    "gyro": "gyro data, one experiment",
    "attitude": "attitude data only (star tracker), one experiment",
    "gyro_attitude": "gyro and attitude data, one experiment",
    "multi_bias": "gyro data of 3 experiments (other Ω0 each), constant gyro bias fitted",
    "huber": "gyro data with 5% outliers of 0.1 rad/s, loss='huber'",
}
BIAS = (0.02, -0.01, 0.015)
EXTRA_W0 = ((1.0, -0.3, 0.5), (-0.2, 0.6, 1.2))


def mode_data(mode: str, T: int, w0, rng):
    """`(ts, kwargs of identify_inertia)` for one dataset of `mode` (see MODES)."""
    import numpy as np

    sig = dict(sigma_omega=NOISE, sigma_angle=NOISE)
    if mode == "multi_bias":
        runs = [motion(T, w) for w in (w0, *EXTRA_W0)]
        w = np.stack([r[1] for r in runs]) + np.asarray(BIAS)
        w = w + NOISE * rng.normal(size=w.shape)
        return runs[0][0], dict(omega_obs=w, gyro_bias=True, sigma_omega=NOISE)
    ts, w, q = motion(T, w0)
    w = w + NOISE * rng.normal(size=w.shape)
    if mode == "gyro":
        return ts, dict(omega_obs=w, sigma_omega=NOISE)
    if mode == "attitude":
        return ts, dict(quat_obs=attitude_noise(q, rng), sigma_angle=NOISE)
    if mode == "gyro_attitude":
        return ts, dict(omega_obs=w, quat_obs=attitude_noise(q, rng), **sig)
    if mode == "huber":
        bad = rng.choice(w.size, size=w.size // 20, replace=False)
        w.reshape(-1)[bad] += 0.1 * rng.choice([-1.0, 1.0], size=bad.size)
        return ts, dict(omega_obs=w, loss="huber", sigma_omega=NOISE)
    raise ValueError(mode)


def identify_worker(T: int, repeats: int, seed: int, mode: str = "gyro") -> dict:
    t_proc = time.perf_counter()
    _setup_jax()
    import numpy as np

    from rigidjax import identify_inertia

    rss_import = _maxrss_mib()
    import_s = time.perf_counter() - t_proc
    rng = np.random.default_rng(seed)
    ref = true_inertia() / np.trace(true_inertia())
    datasets = [mode_data(mode, T, W0, rng)]
    for _ in range(repeats):  # new data of the same shape: another Ω0 and another noise draw
        datasets.append(mode_data(mode, T, np.asarray(W0) + 0.1 * rng.normal(size=3), rng))

    calls = []
    for ts, kw in datasets:
        est, dt, dc = timed(identify_inertia, ts, **kw)
        err = np.asarray(est.inertia) - ref
        calls.append(
            dict(
                seconds=round(dt, 4),
                cpu_seconds=round(dc, 4),
                converged=bool(est.converged),
                lm_steps=int(est.num_steps),
                max_abs_error_rel_trace=float(np.abs(err).max()),
                max_inertia_std=float(np.max(est.inertia_std)),
                max_abs_error_over_std=float(np.max(np.abs(err) / np.asarray(est.inertia_std))),
                **(
                    dict(bias_error=float(np.abs(np.asarray(est.gyro_bias) - BIAS).max()))
                    if mode == "multi_bias"
                    else {}
                ),
            )
        )
    rep = [c["seconds"] for c in calls[1:]]
    rep_cpu = [c["cpu_seconds"] for c in calls[1:]]
    return dict(
        T=T,
        mode=mode,
        description=MODES[mode],
        span=SPAN,
        import_s=round(import_s, 3),
        first_call_s=calls[0]["seconds"],
        repeat_call_s_min=min(rep) if rep else None,
        repeat_call_s_median=statistics.median_high(rep) if rep else None,
        first_call_cpu_s=calls[0]["cpu_seconds"],
        repeat_call_cpu_s_min=min(rep_cpu) if rep else None,
        calls=calls,
        maxrss_mib_after_import=rss_import,
        maxrss_mib_end=_maxrss_mib(),
    )


# --------------------------------------------------------------------------- design

DESIGN = dict(
    moments=MOMENTS,
    omega0=(0.1, 0.05, -0.05),
    duration=20.0,
    torque_bound=0.1,
    n_segments=8,
    samples_per_segment=10,
    steps=60,
    n_prbs=20,
    n_fits=5,
)


def design_worker(seed: int) -> dict:
    """`design_excitation` against PRBS of the same duration, segments and bound: the
    criterion and the Cramér–Rao std (20 PRBS draws), and actual known-torque fits of SciPy
    data (noise NOISE) with the designed torque and with PRBS (5 draws each)."""
    jax = _setup_jax()
    import jax.numpy as jnp
    import numpy as np

    from rigidjax import design_excitation, identify_inertia
    from rigidjax.fit import fisher_information, prbs
    from rigidjax.fit.design import PiecewiseConstantTorque, log_det_criterion

    d = DESIGN
    I = np.diag(d["moments"])
    w0 = np.asarray(d["omega0"])
    S, b = d["n_segments"], d["torque_bound"]
    design, t_design, c_design = timed(
        design_excitation,
        I,
        w0,
        d["duration"],
        torque_bound=b,
        n_segments=S,
        samples_per_segment=d["samples_per_segment"],
        sigma_omega=NOISE,
        steps=d["steps"],
    )
    ts = np.asarray(design.ts)

    @jax.jit
    def criterion(u):
        F = fisher_information(
            jnp.asarray(I), jnp.asarray(w0), u, design.ts, sigma_omega=NOISE, substeps=4
        )
        return log_det_criterion(F), jnp.sqrt(jnp.diagonal(jnp.linalg.inv(F))[:6])

    phi_d, std_d = criterion(design.torques)
    prbs_u = [prbs(jax.random.PRNGKey(100 + k), S, b) for k in range(d["n_prbs"])]
    prbs_eval = [criterion(u) for u in prbs_u]
    rng = np.random.default_rng(seed)

    def fit(u):
        u = np.asarray(u)
        edges = np.asarray(design.edges)

        def torque_np(t):
            return u[min(int(np.searchsorted(edges, t, side="right")) - 1, S - 1)]

        _, W, _ = motion(len(ts), w0, I=I, torque=torque_np, span=d["duration"])
        est = identify_inertia(
            ts,
            omega_obs=W + NOISE * rng.normal(size=W.shape),
            torque=PiecewiseConstantTorque(jnp.asarray(u), jnp.asarray(edges)),  # one compile
            sigma_omega=NOISE,
        )
        return (
            float(np.abs(np.asarray(est.inertia) - I).max()),
            float(np.max(est.inertia_std)),
            bool(est.converged),
        )

    fits_d = [fit(design.torques) for _ in range(d["n_fits"])]
    fits_p = [fit(u) for u in prbs_u[: d["n_fits"]]]
    return dict(
        parameters=d,
        design_s=round(t_design, 3),
        design_cpu_s=round(c_design, 3),
        log_det_designed=float(phi_d),
        log_det_prbs_mean=float(np.mean([float(p[0]) for p in prbs_eval])),
        log_det_prbs_max=float(np.max([float(p[0]) for p in prbs_eval])),
        cramer_rao_std_designed=np.asarray(std_d).tolist(),
        cramer_rao_std_prbs_mean=np.mean([np.asarray(p[1]) for p in prbs_eval], 0).tolist(),
        fit_max_abs_error_designed=[f[0] for f in fits_d],
        fit_max_std_designed=[f[1] for f in fits_d],
        fit_max_abs_error_prbs=[f[0] for f in fits_p],
        fit_max_std_prbs=[f[1] for f in fits_p],
        fits_converged=all(f[2] for f in fits_d + fits_p),
        history=np.asarray(design.history).tolist(),
    )


# --------------------------------------------------------------------------- driver


def run_worker(args: list[str], log: Log, what: str, line) -> dict:
    """One worker of this script in a fresh process; logs `line(result)` or its error."""
    r = worker(__file__, *args)
    if "process_wall_s" in r:
        r["process_wall_s"] = round(r["process_wall_s"], 2)
    log(f"  {what}: " + (f"ERROR\n{r['error']}" if "error" in r else line(r)))
    return r


def run(args, log: Log) -> dict:
    Ts = [201] if args.quick else [201, 1001]
    Ns = [1000, 10_000]
    configs = ["default"] if args.quick else [*SIM_CONFIGS, "lean_scan", "lean_scan_remat"]
    log(f"bench_identify: T={Ts}, N={Ns}, configs={configs}, load {log.load_start}")
    ident, design, grad = {}, None, {}
    runs = [("gyro", T) for T in Ts] + [(m, 201) for m in MODES if m != "gyro"]
    for mode, T in runs if "identify" in args.parts else []:
        ident[f"{mode}_T{T}"] = run_worker(
            ["--_identify", str(T), "--_mode", mode, "--repeats", str(args.repeats),
             "--seed", str(args.seed)], log, f"identify {mode} T={T}",
            lambda r: f"first call {r['first_call_s']:.2f} s (CPU {r['first_call_cpu_s']:.2f} s), "
            f"repeat {r['repeat_call_s_min']:.3f} s (min), max error "
            f"{max(c['max_abs_error_rel_trace'] for c in r['calls']):.1e}",
        )  # fmt: skip
    if "design" in args.parts:
        design = run_worker(
            ["--_design", "--seed", str(args.seed)], log, "design",
            lambda d: f"{d['design_s']:.1f} s, log det {d['log_det_designed']:.2f} vs PRBS mean "
            f"{d['log_det_prbs_mean']:.2f} (max {d['log_det_prbs_max']:.2f})",
        )  # fmt: skip
    for N in Ns if "grad" in args.parts else []:
        grad[str(N)] = run_worker(
            ["--_grad", str(N), "--repeats", str(args.grad_repeats), "--_configs",
             ",".join(configs)], log, f"grad N={N}",
            lambda r: "forward {forward_s:.2e} s, grad {grad_s:.2e} s, ratio "
            "{grad_over_forward:.1f}".format(**r["configs"]["default"]),
        )  # fmt: skip
    notes = {}  # parts not re-run keep their last recorded results
    previous = json.loads(args.out.read_text()) if args.out.exists() else {}
    for part in ("grad", "design"):
        if part not in args.parts and previous.get(part):
            notes[part] = previous.get("notes", {}).get(part) or (
                f"not re-run: from the run of {previous.get('timestamp')}"
            )
            if part == "grad":
                grad = previous["grad"]
            else:
                design = previous["design"]
    ok = all("error" not in r for r in (*ident.values(), *grad.values()))
    return dict(
        benchmark="bench_identify",
        timestamp=timestamp(),
        quick=args.quick,
        parameters=parameters(args, Ts, Ns, configs),
        machine=machine_info(),
        load_average_start=log.load_start,
        identify=ident,
        design=design,
        grad=grad,
        parts_run=args.parts,
        notes=notes,
        summary=summarise(ident, design, grad) if ok else {},
    )


def parameters(args, Ts, Ns, configs) -> dict:
    return dict(
        inertia_true=dict(moments=MOMENTS, rotvec=ROTVEC, note="I = R diag(moments) Rᵀ"),
        identify=dict(
            omega0=W0, span=SPAN, T=Ts, noise_sigma=NOISE, repeats=args.repeats, seed=args.seed,
            data="SciPy solve_ivp DOP853 rtol=atol=1e-13; repeated calls use new Ω0 "
            "(W0 + 0.1 N(0,1)) and new noise",
        ),
        grad=dict(
            loss="c·Ω(T) + (q(T)·q_c)², grad w.r.t. (I 3×3, Ω0), jax.grad (reverse mode)",
            T=GRAD_T, N=Ns, solver="RK4(), ConstantStepSize(), dt0 = T/N", configs=configs,
            repeats=args.grad_repeats,
            memory_measure="compiled.memory_analysis() (XLA buffer sizes of the jitted "
            "program) and, per process, resource.getrusage(RUSAGE_SELF).ru_maxrss (MiB)",
        ),
    )  # fmt: skip


def summarise(ident: dict, design: dict | None, grad: dict) -> dict:
    summary = {}
    for key, r in ident.items():
        summary[f"identify_{key}_first_call_s"] = r["first_call_s"]
        summary[f"identify_{key}_first_call_cpu_s"] = r["first_call_cpu_s"]
        summary[f"identify_{key}_repeat_call_s"] = r["repeat_call_s_min"]
        summary[f"identify_{key}_max_abs_error"] = max(
            c["max_abs_error_rel_trace"] for c in r["calls"]
        )
    if design is not None and "error" not in design:
        summary["design_s"] = design["design_s"]
        summary["design_log_det_over_prbs_mean"] = round(
            design["log_det_designed"] - design["log_det_prbs_mean"], 3
        )
        ratios = zip(design["cramer_rao_std_designed"], design["cramer_rao_std_prbs_mean"],
                     strict=True)  # fmt: skip
        summary["design_cramer_rao_std_over_prbs_mean_max"] = round(
            max(a / b for a, b in ratios), 3
        )
    for N, r in grad.items():
        for cfg, d in r["configs"].items():
            summary[f"grad_over_forward_N{N}_{cfg}"] = round(d["grad_over_forward"], 2)
            summary[f"grad_temp_bytes_N{N}_{cfg}"] = (d["grad_memory"] or {}).get(
                "temp_size_in_bytes"
            )
        if "lean_scan_remat" in r["configs"]:
            c = r["configs"]
            summary[f"grad_time_default_over_lean_scan_remat_N{N}"] = round(
                c["default"]["grad_s"] / c["lean_scan_remat"]["grad_s"], 2
            )
    return summary


def print_table(out: dict) -> None:
    print("\nidentification (fresh process per mode and T)")
    columns = [("mode", ">20"), ("first call s", ">14.2f"), ("first CPU s", ">13.2f"),
               ("repeat s (min)", ">16.3f"), ("err/tr", ">10.1e"), ("err/std", ">9.2f"),
               ("peak RSS MiB", ">14.0f")]  # fmt: skip
    rows = []
    for key, r in out["identify"].items():
        if "error" in r:
            rows.append([key, *[None] * 6])
            continue
        err, z = (max(c[k] for c in r["calls"]) for k in ("max_abs_error_rel_trace",
                                                          "max_abs_error_over_std"))  # fmt: skip
        rows.append([key, r["first_call_s"], r["first_call_cpu_s"], r["repeat_call_s_min"], err, z,
                     r["maxrss_mib_end"]])  # fmt: skip
    print(table(columns, rows))
    d = out.get("design")
    if d and "error" not in d:
        print(
            f"\ndesign_excitation: {d['design_s']:.1f} s; log det {d['log_det_designed']:.2f} vs "
            f"PRBS mean {d['log_det_prbs_mean']:.2f}; Cramér–Rao std designed "
            f"{[round(x, 6) for x in d['cramer_rao_std_designed'][:3]]} vs PRBS mean "
            f"{[round(x, 6) for x in d['cramer_rao_std_prbs_mean'][:3]]}; fit max error "
            f"designed {max(d['fit_max_abs_error_designed']):.1e}, PRBS "
            f"{max(d['fit_max_abs_error_prbs']):.1e}"
        )
    print("\ngradient through simulate (RK4, fixed steps)")
    columns = [("N", ">6"), ("config", ">16"), ("ckpts", ">7"), ("fwd ms", ">9.2f"),
               ("grad ms", ">10.1f"), ("ratio", ">8.1f"), ("ratio CPU", ">10.1f"),
               ("grad temp B", ">13"), ("fwd temp B", ">12")]  # fmt: skip
    rows, notes = [], []
    for N, r in out["grad"].items():
        if "error" in r:
            rows.append([N, *[None] * 8])
            continue
        for cfg, d in r["configs"].items():
            rows.append([N, cfg, d["checkpoints"], d["forward_s"] * 1e3, d["grad_s"] * 1e3,
                         d["grad_over_forward"], d["grad_over_forward_cpu"],
                         (d["grad_memory"] or {}).get("temp_size_in_bytes"),
                         (d["forward_memory"] or {}).get("temp_size_in_bytes")])  # fmt: skip
        fd = r["grad_check_max_abs_diff_vs_central_fd_rel"]
        notes.append(f"N={N}: peak RSS MiB {r['maxrss_mib']}; grad vs central FD (rel) {fd:.1e}")
    print(table(columns, rows))
    print("\n".join(notes))


def main(argv=None) -> None:
    p = parser(__doc__, "identify.json", quick="T=201 only, default adjoint only", seed=True)
    p.add_argument("--grad-repeats", type=int, default=5, help="timed forward/grad rounds")
    p.add_argument(
        "--parts",
        type=lambda x: x.split(","),
        default=["identify", "design", "grad"],
        help="comma-separated parts to run (identify, design, grad); a part not run keeps "
        "its previous grad results in the JSON",
    )
    p.add_argument("--_identify", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_mode", default="gyro", help=argparse.SUPPRESS)
    p.add_argument("--_design", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--_grad", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_configs", default="default", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args._identify is not None:
        print(json.dumps(identify_worker(args._identify, args.repeats, args.seed, args._mode)))
    elif args._design:
        print(json.dumps(design_worker(args.seed)))
    elif args._grad is not None:
        _setup_jax()
        configs = args._configs.split(",")
        print(json.dumps(grad_worker(args._grad, configs, args.grad_repeats, true_inertia(), W0)))
    else:
        execute(run, args, print_table)


if __name__ == "__main__":
    main()
