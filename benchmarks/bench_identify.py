"""Inertia identification and gradient cost through `simulate`: time, compile, memory.

Part 1: identification (``identify_inertia``), every mode
    A body with a full (non-diagonal) inertia tensor ``I = R diag(1, 2, 2.6) Rᵀ`` (the one in
    ``tests/fit/data.py``), torque-free; body angular velocity and attitude sampled at T equally
    spaced times on [0, 8], generated with SciPy ``solve_ivp`` (DOP853, rtol = atol = 1e-13;
    independent of rigidjax), plus Gaussian noise σ = 1e-3 (rad/s for the gyro, rad for the
    attitude). Modes (``MODES``): gyro data (T = 201 and 1001), attitude only, gyro + attitude,
    three experiments with a gyro bias fitted, gyro data with 5% outliers and the Huber loss
    (T = 201). Each mode and T runs in a fresh Python process (no persistent compilation
    cache): the first call (trace + compile + fit) and then ``--repeats`` calls with NEW data of
    the same shape (another initial Ω0 and another noise draw; the compiled program is
    reused). Wall and CPU time with ``block_until_ready``; data generation is not timed. Also
    recorded: convergence, Levenberg–Marquardt steps, the error of the trace-normalised tensor
    relative to its trace, the largest |error|/std, the bias error, and the peak RSS.

Part 1b: experiment design (``design_excitation``) against PRBS
    Body diag(1, 2, 2.6), Ω0 = (0.1, 0.05, −0.05), 20 s, 8 segments, |u_i| ≤ 0.1, 10 gyro
    samples per segment (σ = 1e-3). Recorded: the design time (first call, compile included),
    the criterion log det (inertia-block information) of the design and of 20 PRBS draws of
    the same duration, segments and bound, their Cramér–Rao std of the six inertia entries,
    and actual known-torque fits of SciPy data (5 noise draws with the design, 5 PRBS draws).

Part 2: gradient / forward cost through ``simulate``
    Scalar loss ``L(I, Ω0) = c·Ω(T) + (q(T)·q_c)²`` of ``simulate(RigidBody(I), Ω0, None,
    [0, T], solver=RK4(), stepsize_controller=ConstantStepSize(), dt0=T/N)`` with T = 10 and N =
    10³ and 10⁴ fixed RK4 steps; gradient with ``jax.grad`` (reverse mode) w.r.t. the full 3×3
    tensor and Ω0. Both the forward function and its gradient are compiled ahead of time
    (``jax.jit(f).lower(...).compile()``), warmed up, then timed in ``--repeats`` interleaved
    rounds; ratio = best gradient time / best forward time. Adjoints compared:
        ``default``    simulate's default ``RecursiveCheckpointAdjoint()`` with its default
                       ``max_steps = 100_000`` (the headline);
        ``tight``      the same adjoint with ``max_steps = N``;
        ``store_all``  ``RecursiveCheckpointAdjoint(checkpoints=N)``: every step stored, no
                       recomputation (contrast: memory ∝ N).
    and, for contrast, the same loss with a hand-written RK4 in ``lax.scan`` (quaternion
    renormalised each step, as simulate does): ``lean_scan`` (plain reverse mode, all stage
    intermediates stored) and ``lean_scan_remat`` (``jax.checkpoint`` on the step: the state is
    stored per step, the stages recomputed). Not run with ``--quick``.
    Memory: XLA's ``compiled.memory_analysis()`` (temp / argument / output bytes of the compiled
    gradient program; available on CPU) is the primary measure. Each N runs in its own process,
    which also records ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` (peak RSS of the whole
    process) after import, after compiling and after running the gradients; the peak is set by
    JAX/XLA start-up and compilation, so it says little about the gradient itself.
    The gradient is checked against central finite differences of the forward function.

Usage
    python benchmarks/bench_identify.py [--quick] [--repeats 3] [--seed 0]
        [--parts identify,design,grad] [--out benchmarks/results/identify.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import resource
import statistics
import sys
import time
from pathlib import Path

from _harness import (  # noqa: E402
    Timing,
    fresh_process,
    interleaved,
    load_average,
    load_report,
    machine_info,
    timed,
    write_json,
)

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "identify.json"
ROTVEC = (0.3, -0.5, 0.2)
MOMENTS = (1.0, 2.0, 2.6)
W0 = (0.4, 1.1, -0.7)
SPAN = 8.0
NOISE = 1e-3
GRAD_T = 10.0
SIM_DEFAULT_MAX_STEPS = 100_000  # simulate's default
SIM_CONFIGS = ["default", "tight", "store_all"]


def _maxrss_mib() -> float:
    # Linux reports kilobytes (macOS bytes)
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(r / (1024**2 if sys.platform == "darwin" else 1024), 1)


def _setup_jax():
    import jax

    jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it
    return jax


def true_inertia():
    import numpy as np
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(ROTVEC).as_matrix()
    return R @ np.diag(MOMENTS) @ R.T


def default_checkpoints(max_steps: int) -> int:
    """Checkpoints used by RecursiveCheckpointAdjoint(checkpoints=None) (equinox's rule:
    ~sqrt(2 max_steps), the fewest for which the recomputation stays O(n log n))."""
    if max_steps == 1:
        return 1
    return min(math.floor(-1.5 + math.sqrt(2 * max_steps + 0.25)) + 1, max_steps)


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


def gyro_data(T: int, w0, rng):
    """Noisy body angular velocity of the torque-free body, SciPy DOP853."""
    ts, w, _ = motion(T, w0)
    return ts, w + NOISE * rng.normal(size=(T, 3))


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


# --------------------------------------------------------------------------- part 2


def make_loss(N: int, config: str):
    import diffrax
    import jax.numpy as jnp

    from rigidjax import RK4, RigidBody, simulate

    if config == "default":
        kw = {}
    elif config == "tight":
        kw = dict(max_steps=N)
    elif config == "store_all":
        kw = dict(max_steps=N, adjoint=diffrax.RecursiveCheckpointAdjoint(checkpoints=N))
    elif not config.startswith("lean_scan"):  # pragma: no cover
        raise ValueError(config)
    c = jnp.array([0.3, -0.2, 0.5])
    qc = jnp.array([0.5, 0.5, -0.5, 0.5])
    if config in ("lean_scan", "lean_scan_remat"):
        return _lean_loss(N, config == "lean_scan_remat", c, qc)

    def loss(I, w0):
        traj = simulate(
            RigidBody(I, check=False),
            w0,
            None,
            jnp.array([0.0, GRAD_T]),
            solver=RK4(),
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=GRAD_T / N,
            **kw,
        )
        return c @ traj.omega[-1] + (traj.quat[-1] @ qc) ** 2

    return loss


def _lean_loss(N: int, remat: bool, c, qc):
    """The same loss with a hand-written RK4 in ``lax.scan`` (quaternion renormalised after each
    step, as simulate does); ``remat``: ``jax.checkpoint`` on the step (stores only the state
    per step and recomputes the stages in the backward pass)."""
    import jax
    import jax.numpy as jnp

    h = GRAD_T / N

    def rhs(y, I, Iinv):
        w, q = y[:3], y[3:]
        dw = Iinv @ (-jnp.cross(w, I @ w))
        dq = 0.5 * jnp.concatenate([-(q[1:] @ w)[None], q[0] * w + jnp.cross(q[1:], w)])
        return jnp.concatenate([dw, dq])

    def loss(I, w0):
        Iinv = jnp.linalg.inv(I)

        def step(y, _):
            k1 = rhs(y, I, Iinv)
            k2 = rhs(y + h / 2 * k1, I, Iinv)
            k3 = rhs(y + h / 2 * k2, I, Iinv)
            k4 = rhs(y + h * k3, I, Iinv)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            return y.at[3:].set(y[3:] / jnp.linalg.norm(y[3:])), None

        y0 = jnp.concatenate([w0, jnp.array([1.0, 0.0, 0.0, 0.0], w0.dtype)])
        y, _ = jax.lax.scan(jax.checkpoint(step) if remat else step, y0, None, length=N)
        return c @ y[:3] + (y[3:] @ qc) ** 2

    return loss


def _mem(compiled) -> dict | None:
    try:
        m = compiled.memory_analysis()
    except Exception as e:  # pragma: no cover
        return dict(error=repr(e))
    if m is None:  # pragma: no cover
        return None
    return {
        k: int(getattr(m, k))
        for k in (
            "temp_size_in_bytes",
            "argument_size_in_bytes",
            "output_size_in_bytes",
            "alias_size_in_bytes",
            "generated_code_size_in_bytes",
        )
        if hasattr(m, k)
    }


def grad_worker(N: int, configs: list[str], repeats: int) -> dict:
    jax = _setup_jax()
    import jax.numpy as jnp
    import numpy as np

    rss = dict(after_import=_maxrss_mib())
    I = jnp.asarray(true_inertia())
    w0 = jnp.asarray(W0)
    out = {}
    timings = {}  # config -> (forward, gradient), compiled ahead of time
    for cfg in configs:
        loss = make_loss(N, cfg)
        f, g = timings[cfg] = Timing(loss, I, w0), Timing(jax.grad(loss, argnums=(0, 1)), I, w0)
        ms = {"default": SIM_DEFAULT_MAX_STEPS, "tight": N, "store_all": N}.get(cfg)
        out[cfg] = dict(
            max_steps=ms,
            checkpoints=(
                N
                if cfg in ("store_all", "lean_scan", "lean_scan_remat")
                else default_checkpoints(ms)
            ),
            forward_trace_lower_s=round(f.trace_lower_s, 3),
            forward_compile_s=round(f.compile_s, 3),
            grad_trace_lower_s=round(g.trace_lower_s, 3),
            grad_compile_s=round(g.compile_s, 3),
            forward_memory=_mem(f.fn),
            grad_memory=_mem(g.fn),
        )
    rss["after_compile"] = _maxrss_mib()
    for f, g in timings.values():
        f.warm_up()
        g.warm_up()
    rss["after_first_runs"] = _maxrss_mib()
    interleaved([t for pair in timings.values() for t in pair], repeats)
    rss["after_timing"] = _maxrss_mib()
    for cfg, (f, g) in timings.items():
        out[cfg].update(
            forward_s=f.best,
            forward_s_median=f.median,
            grad_s=g.best,
            grad_s_median=g.median,
            grad_over_forward=g.best / f.best,
            grad_over_forward_median=g.median / f.median,
            forward_cpu_s=f.cpu_best,
            grad_cpu_s=g.cpu_best,
            grad_over_forward_cpu=g.cpu_best / f.cpu_best,
            forward_us_per_step=f.best / N * 1e6,
        )
    # gradient check: central finite differences of the forward program (default config)
    f, g = (t.fn for t in timings[configs[0]])
    gI, gw = g(I, w0)
    h = 1e-6
    fd_w = np.array([(f(I, w0.at[i].add(h)) - f(I, w0.at[i].add(-h))) / (2 * h) for i in range(3)])
    fd_I = np.array(
        [
            (f(I.at[i, j].add(h), w0) - f(I.at[i, j].add(-h), w0)) / (2 * h)
            for i in range(3)
            for j in range(3)
        ]
    ).reshape(3, 3)
    ad = np.concatenate([np.asarray(gI).ravel(), np.asarray(gw)])
    fd = np.concatenate([fd_I.ravel(), fd_w])
    grad_check = float(np.abs(ad - fd).max() / np.abs(fd).max())
    return dict(
        N=N,
        T=GRAD_T,
        dt=GRAD_T / N,
        configs=out,
        grad_check_max_abs_diff_vs_central_fd_rel=grad_check,
        grad_consistency_across_configs=float(
            max(
                np.abs(
                    np.concatenate([np.asarray(x).ravel() for x in timings[c][1].fn(I, w0)]) - ad
                ).max()
                for c in configs
            )
        ),
        maxrss_mib=rss,
    )


# --------------------------------------------------------------------------- driver


def run_worker(args: list[str]) -> dict:
    res, wall, p = fresh_process(__file__, *args)
    if res is None:
        return dict(error=p.stderr[-4000:], returncode=p.returncode)
    res["process_wall_s"] = round(wall, 2)
    return res


def run(args) -> dict:
    t_start = time.perf_counter()
    load_start = load_average()
    Ts = [201] if args.quick else [201, 1001]
    Ns = [1000, 10_000]
    configs = ["default"] if args.quick else [*SIM_CONFIGS, "lean_scan", "lean_scan_remat"]
    print(f"bench_identify: T={Ts}, N={Ns}, configs={configs}, load {load_start}", flush=True)
    ident = {}
    runs = [("gyro", T) for T in Ts] + [(m, 201) for m in MODES if m != "gyro"]
    for mode, T in runs if "identify" in args.parts else []:
        r = run_worker(
            ["--_identify", str(T), "--_mode", mode]
            + ["--repeats", str(args.repeats), "--seed", str(args.seed)]
        )
        ident[f"{mode}_T{T}"] = r
        if "error" in r:
            print(f"  identify {mode} T={T}: ERROR\n{r['error']}", flush=True)
        else:
            print(
                f"  identify {mode} T={T}: first call {r['first_call_s']:.2f} s "
                f"(CPU {r['first_call_cpu_s']:.2f} s), repeat {r['repeat_call_s_min']:.3f} s "
                f"(min), max error {max(c['max_abs_error_rel_trace'] for c in r['calls']):.1e}",
                flush=True,
            )
    design = None
    if "design" in args.parts:
        design = run_worker(["--_design", "--seed", str(args.seed)])
        if "error" in design:
            print(f"  design: ERROR\n{design['error']}", flush=True)
        else:
            print(
                f"  design: {design['design_s']:.1f} s, log det {design['log_det_designed']:.2f} "
                f"vs PRBS mean {design['log_det_prbs_mean']:.2f} "
                f"(max {design['log_det_prbs_max']:.2f})",
                flush=True,
            )
    grad = {}
    for N in Ns if "grad" in args.parts else []:
        r = run_worker(
            [
                "--_grad",
                str(N),
                "--repeats",
                str(args.grad_repeats),
                "--_configs",
                ",".join(configs),
            ]
        )
        grad[str(N)] = r
        if "error" in r:
            print(f"  grad N={N}: ERROR\n{r['error']}", flush=True)
        else:
            d = r["configs"]["default"]
            print(
                f"  grad N={N}: forward {d['forward_s'] * 1e3:.2f} ms, grad "
                f"{d['grad_s'] * 1e3:.1f} ms, ratio {d['grad_over_forward']:.1f}",
                flush=True,
            )
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
    summary = {}
    ok = all("error" not in r for r in (*ident.values(), *grad.values()))
    if ok:
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
            summary["design_cramer_rao_std_over_prbs_mean_max"] = round(
                max(
                    a / b
                    for a, b in zip(
                        design["cramer_rao_std_designed"],
                        design["cramer_rao_std_prbs_mean"],
                        strict=True,
                    )
                ),
                3,
            )
        for N, r in grad.items():
            for cfg, d in r["configs"].items():
                summary[f"grad_over_forward_N{N}_{cfg}"] = round(d["grad_over_forward"], 2)
                summary[f"grad_temp_bytes_N{N}_{cfg}"] = (d["grad_memory"] or {}).get(
                    "temp_size_in_bytes"
                )
            if "lean_scan_remat" in r["configs"]:
                summary[f"grad_time_default_over_lean_scan_remat_N{N}"] = round(
                    r["configs"]["default"]["grad_s"] / r["configs"]["lean_scan_remat"]["grad_s"], 2
                )
    return dict(
        benchmark="bench_identify",
        timestamp=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        quick=args.quick,
        parameters=dict(
            inertia_true=dict(moments=MOMENTS, rotvec=ROTVEC, note="I = R diag(moments) Rᵀ"),
            identify=dict(
                omega0=W0,
                span=SPAN,
                T=Ts,
                noise_sigma=NOISE,
                repeats=args.repeats,
                seed=args.seed,
                data="SciPy solve_ivp DOP853 rtol=atol=1e-13; repeated calls use new Ω0 "
                "(W0 + 0.1 N(0,1)) and new noise",
            ),
            grad=dict(
                loss="c·Ω(T) + (q(T)·q_c)², grad w.r.t. (I 3×3, Ω0), jax.grad (reverse mode)",
                T=GRAD_T,
                N=Ns,
                solver="RK4(), ConstantStepSize(), dt0 = T/N",
                configs=configs,
                repeats=args.grad_repeats,
                memory_measure="compiled.memory_analysis() (XLA buffer sizes of the jitted "
                "program) and, per process, resource.getrusage(RUSAGE_SELF).ru_maxrss (MiB)",
            ),
        ),
        machine=machine_info(),
        load_average_start=load_start,
        load_average_end=load_average(),
        total_wall_s=round(time.perf_counter() - t_start, 1),
        identify=ident,
        design=design,
        grad=grad,
        parts_run=args.parts,
        notes=notes,
        summary=summary,
    )


def print_table(out: dict) -> None:
    print("\nidentification (fresh process per mode and T)")
    print(
        f"{'mode':>20} {'first call s':>13} {'first CPU s':>12} {'repeat s (min)':>15} "
        f"{'err/tr':>9} {'err/std':>8} {'peak RSS MiB':>13}"
    )
    for key, r in out["identify"].items():
        if "error" in r:
            print(f"{key:>20} ERROR")
            continue
        err = max(c["max_abs_error_rel_trace"] for c in r["calls"])
        z = max(c["max_abs_error_over_std"] for c in r["calls"])
        print(
            f"{key:>20} {r['first_call_s']:>13.2f} {r['first_call_cpu_s']:>12.2f} "
            f"{r['repeat_call_s_min']:>15.3f} {err:>9.1e} {z:>8.2f} "
            f"{r['maxrss_mib_end']:>13.0f}"
        )
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
    print(
        f"{'N':>6} {'config':>15} {'ckpts':>6} {'fwd ms':>8} {'grad ms':>9} {'ratio':>7} "
        f"{'ratio CPU':>9} "
        f"{'grad temp B':>12} {'fwd temp B':>11}"
    )
    for N, r in out["grad"].items():
        if "error" in r:
            print(f"{N:>6} ERROR")
            continue
        for cfg, d in r["configs"].items():
            print(
                f"{N:>6} {cfg:>15} {d['checkpoints']:>6} {d['forward_s'] * 1e3:>8.2f} "
                f"{d['grad_s'] * 1e3:>9.1f} {d['grad_over_forward']:>7.1f} "
                f"{d['grad_over_forward_cpu']:>9.1f} "
                f"{(d['grad_memory'] or {}).get('temp_size_in_bytes')!s:>12} "
                f"{(d['forward_memory'] or {}).get('temp_size_in_bytes')!s:>11}"
            )
        fd = r["grad_check_max_abs_diff_vs_central_fd_rel"]
        print(f"{'':>6} peak RSS MiB {r['maxrss_mib']}; grad vs central FD (rel) {fd:.1e}")
    print(load_report(out))


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="T=201 only, default adjoint only")
    p.add_argument("--repeats", type=int, default=3, help="identification calls after the first")
    p.add_argument("--grad-repeats", type=int, default=5, help="timed forward/grad rounds")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
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
    return p.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    if args._identify is not None:
        print(json.dumps(identify_worker(args._identify, args.repeats, args.seed, args._mode)))
        return
    if args._design:
        print(json.dumps(design_worker(args.seed)))
        return
    if args._grad is not None:
        print(json.dumps(grad_worker(args._grad, args._configs.split(","), args.grad_repeats)))
        return
    out = run(args)
    write_json(args.out, out)
    print_table(out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
