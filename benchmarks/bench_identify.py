"""Inertia identification and gradient cost through `simulate`: time, compile, memory.

Part 1: identification (``identify_inertia`` on gyro data)
    A body with a full (non-diagonal) inertia tensor ``I = R diag(1, 2, 2.6) Rᵀ`` (the one in
    ``tests/test_identify.py``), torque-free; body angular velocity sampled at T equally spaced
    times on [0, 8] (T = 201 and 1001), generated with SciPy ``solve_ivp`` (DOP853, rtol = atol
    = 1e-13; independent of rigidjax), plus Gaussian noise σ = 1e-3. Each T runs in a fresh Python
    process (no persistent compilation cache): the first call (trace + compile + fit) and then
    ``--repeats`` calls with NEW data of the same shape (another initial Ω0 and another noise
    draw; the compiled program is reused). Wall time with ``block_until_ready``; data generation
    is not timed. Also recorded: convergence, Levenberg–Marquardt steps, the error of the
    trace-normalised tensor relative to its trace, and the process's peak RSS.

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
        [--out benchmarks/results/identify.json]
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


def gyro_data(T: int, w0, rng):
    """Noisy body angular velocity of the torque-free body, SciPy DOP853."""
    import numpy as np
    from scipy.integrate import solve_ivp

    I = true_inertia()
    ts = np.linspace(0.0, SPAN, T)
    sol = solve_ivp(
        lambda t, w: np.linalg.solve(I, -np.cross(w, I @ w)),
        (0.0, SPAN),
        np.asarray(w0, float),
        t_eval=ts,
        method="DOP853",
        rtol=1e-13,
        atol=1e-13,
    )
    return ts, sol.y.T + NOISE * rng.normal(size=(T, 3))


def identify_worker(T: int, repeats: int, seed: int) -> dict:
    t_proc = time.perf_counter()
    _setup_jax()
    import numpy as np

    from rigidjax import identify_inertia

    rss_import = _maxrss_mib()
    import_s = time.perf_counter() - t_proc
    rng = np.random.default_rng(seed)
    ref = true_inertia() / np.trace(true_inertia())
    datasets = [gyro_data(T, W0, rng)]
    for _ in range(repeats):  # new data of the same shape: another Ω0 and another noise draw
        datasets.append(gyro_data(T, np.asarray(W0) + 0.1 * rng.normal(size=3), rng))

    calls = []
    for ts, w in datasets:
        est, dt, dc = timed(identify_inertia, ts, omega_obs=w)
        calls.append(
            dict(
                seconds=round(dt, 4),
                cpu_seconds=round(dc, 4),
                converged=bool(est.converged),
                lm_steps=int(est.num_steps),
                max_abs_error_rel_trace=float(np.abs(np.asarray(est.inertia) - ref).max()),
                max_inertia_std=float(np.max(est.inertia_std)),
            )
        )
    rep = [c["seconds"] for c in calls[1:]]
    rep_cpu = [c["cpu_seconds"] for c in calls[1:]]
    return dict(
        T=T,
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
    for T in Ts:
        r = run_worker(
            ["--_identify", str(T), "--repeats", str(args.repeats), "--seed", str(args.seed)]
        )
        ident[str(T)] = r
        if "error" in r:
            print(f"  identify T={T}: ERROR\n{r['error']}", flush=True)
        else:
            print(
                f"  identify T={T}: first call {r['first_call_s']:.2f} s, "
                f"repeat {r['repeat_call_s_min']:.3f} s (min)",
                flush=True,
            )
    grad = {}
    for N in Ns:
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
    summary = {}
    ok = all("error" not in r for r in (*ident.values(), *grad.values()))
    if ok:
        for T, r in ident.items():
            summary[f"identify_T{T}_first_call_s"] = r["first_call_s"]
            summary[f"identify_T{T}_repeat_call_s"] = r["repeat_call_s_min"]
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
        grad=grad,
        summary=summary,
    )


def print_table(out: dict) -> None:
    print("\nidentification (gyro data, fresh process per T)")
    print(
        f"{'T':>6} {'first call s':>13} {'repeat s (min)':>15} {'repeat CPU s':>13} "
        f"{'err/tr':>9} {'peak RSS MiB':>13}"
    )
    for T, r in out["identify"].items():
        if "error" in r:
            print(f"{T:>6} ERROR")
            continue
        err = max(c["max_abs_error_rel_trace"] for c in r["calls"])
        print(
            f"{T:>6} {r['first_call_s']:>13.2f} {r['repeat_call_s_min']:>15.3f} "
            f"{r['repeat_call_cpu_s_min']:>13.3f} {err:>9.1e} "
            f"{r['maxrss_mib_end']:>13.0f}"
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
    p.add_argument("--_identify", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_grad", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_configs", default="default", help=argparse.SUPPRESS)
    return p.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    if args._identify is not None:
        print(json.dumps(identify_worker(args._identify, args.repeats, args.seed)))
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
