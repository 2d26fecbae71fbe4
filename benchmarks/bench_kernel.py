"""rigidjax's fixed-step free-body path against a hand-written C kernel, from 1e3 to 1e7 bodies,
and the cost of its gradients.

Problem
    As bench_dynamics.py: B free rigid bodies, I = (1, 2, 3), Ω0 ~ N(0, 1)³, random unit q0,
    N RK4 steps of dt = 1e-3 with the quaternion renormalised after each, float64.

Parts (one run)
    scaling   For each B (1e3 … 1e7; --quick: 1e3 … 1e5), a fresh process times
              ``simulate(body, Ω0, q0, [0, N dt], solver=RK4(), ConstantStepSize, dt0)`` (jit,
              best of --repeats after a warm-up) and then the C reference
              (``benchmarks/reference/free_body.c``, built here with the system compiler, called
              through ctypes on its packed (7, B) state; packing is not timed) in interleaved
              rounds, after checking that their final states agree to 1e-10. Recorded: both
              rates, their ratio, the fraction of the fp64 peak (238 flops per body-step, peak =
              cores × clock × 16) and the process's peak RSS after the rigidjax part (inputs,
              outputs and the program; the kernel itself holds one 64-body block per thread).
              N = max(200, 2e8 / B) steps: ~1 s of work per point up to 1e6 bodies, and at least
              200 steps, so that reading the inputs and writing the trajectory (a pass over
              memory that the C reference, working in place, does not make) stays small.
    flat      Every batch size in one fresh process, both kernels compiled and warmed up
              first, then --flat-repeats rounds (default 3) that each time every size once,
              rigidjax then C; best per size. This shared 2-core machine drifts by about 20%
              over minutes, for both kernels alike: separate processes minutes apart read that
              drift as a dependence on B, interleaved rounds do not. The flat-scaling figure
              (worst size over best) comes from this part.
    gradient  B = 1e4 bodies, 500 steps: ``jax.value_and_grad`` of a loss of the final states with
              respect to the principal moments, over the forward run alone, for the kernel path
              (``RK4()``) and, for contrast, the Diffrax path (``ExplicitRK(RK4())``), timed in
              interleaved rounds.
    float32   The same forward run in float32 (B = 1e4): rate, and the error against float64.

Targets (issue 14): ≥ 0.8× the C kernel at large batches; every batch from 1e3 to 1e7 within
0.9× of the best; gradient ≤ 3× forward.

Usage
    python benchmarks/bench_kernel.py [--quick] [--repeats 3] [--flat-repeats 3]
        [--out benchmarks/results/kernel.json]
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
from pathlib import Path
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it

import diffrax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _c_reference import FLOPS_PER_BODY_STEP, CReference, peak_fp64_flops  # noqa: E402
from _harness import (  # noqa: E402
    Log,
    Timing,
    execute,
    interleaved,
    machine_info,
    parser,
    print_targets,
    target,
    timestamp,
    worker,
)

import rigidjax as rj  # noqa: E402

MOMENTS = (1.0, 2.0, 3.0)
DT = 1e-3
FULL_BATCHES = (1_000, 10_000, 100_000, 1_000_000, 10_000_000)
QUICK_BATCHES = (1_000, 10_000, 100_000)
TARGETS = dict(ratio_vs_c=0.8, flat_within=0.9, gradient_over_forward=3.0)


def make_inputs(B: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w0 = rng.normal(size=(B, 3))
    q0 = rng.normal(size=(B, 4))
    return w0, q0 / np.linalg.norm(q0, axis=1, keepdims=True)


def forward(N: int, solver=None, dtype=jnp.float64):
    """Final (Ω, q) after N steps, for a batch of initial states."""
    body = rj.RigidBody(jnp.asarray(MOMENTS, dtype))
    ts = jnp.asarray([0.0, N * DT], dtype)

    def run(w, q):
        tr = rj.simulate(
            body,
            w,
            q,
            ts,
            solver=rj.RK4() if solver is None else solver,
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=DT,
            max_steps=N + 1,
            check=False,  # inputs made here are valid; no runtime checks in the timed program
        )
        return tr.omega[:, -1], tr.quat[:, -1]

    return run


def steps_for(B: int) -> int:
    return max(200, int(2e8 // B))


def contenders(B: int) -> tuple[Timing, Timing | None, dict]:
    """rigidjax (compiled ahead of time and warmed up) and the C reference (None without a
    compiler) for B bodies and N = steps_for(B) steps, after checking that their final states
    agree to 1e-10; and what was recorded on the way."""
    N = steps_for(B)
    w0, q0 = make_inputs(B)
    t_rj = Timing(forward(N), jnp.asarray(w0), jnp.asarray(q0))
    w, q = (np.asarray(a) for a in t_rj.warm_up())
    info: dict[str, Any] = dict(
        B=B,
        N=N,
        compile_s=t_rj.trace_lower_compile_s,
        peak_rss_bytes=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
    )
    c = CReference.build()
    if c is None:
        info["c_note"] = CReference.note
        return t_rj, None, info
    state, coef = c.pack(w0, q0, MOMENTS)
    wc, qc = (a.T for a in np.split(c.advance(state.copy(), coef, N, DT), [3]))
    diff = float(max(np.max(np.abs(w - wc)), np.max(np.abs(q - qc))))
    if not diff <= 1e-10:
        raise SystemExit(f"rigidjax and the C reference disagree by {diff:.3g} at B = {B}")

    class _C(Timing):  # the packed state is copied outside the timed call
        def run(self, repeats=1, min_total=0.0, max_calls=200):
            self.args = (state.copy(), coef, N, DT)
            return super().run(repeats, min_total, max_calls)

    info.update(max_abs_diff_vs_c=diff, c_vectorized=c.vectorized, c_command=c.command)
    return t_rj, _C(c.advance, state.copy(), coef, N, DT, aot=False), info


def measured(t_rj: Timing, t_c: Timing | None, info: dict) -> dict:
    """`info` with the best times, rates and their ratio."""
    B, N = info["B"], info["N"]
    out = dict(info, rigidjax_seconds=t_rj.best, rigidjax_body_steps_per_s=B * N / t_rj.best)
    if t_c is not None:
        out.update(c_seconds=t_c.best, c_body_steps_per_s=B * N / t_c.best)
        out["ratio_vs_c"] = t_c.best / t_rj.best
    return out


def probe(B: int, repeats: int) -> dict:
    """One batch size, in this (fresh) process: rigidjax and the C reference, interleaved."""
    t_rj, t_c, info = contenders(B)
    interleaved([t for t in (t_rj, t_c) if t is not None], repeats)
    return measured(t_rj, t_c, info)


def flat_probe(batches: tuple[int, ...], repeats: int) -> list[dict]:
    """Every batch size in one process, timed in interleaved rounds (each round calls every
    size once, rigidjax then C): a drift of the machine's speed hits all sizes alike."""
    pairs = [contenders(B) for B in batches]
    interleaved([t for t_rj, t_c, _ in pairs for t in (t_rj, t_c) if t is not None], repeats)
    return [measured(*pair) for pair in pairs]


def gradient_part(repeats: int, log) -> dict:
    B, N = 10_000, 500
    w0, q0 = make_inputs(B, seed=1)
    wj, qj = jnp.asarray(w0), jnp.asarray(q0)
    weights = jnp.arange(1.0, 8.0)
    timings = {}
    for name, solver in (("kernel", rj.RK4()), ("diffrax", rj.ExplicitRK(rj.RK4()))):
        body_ts = jnp.asarray([0.0, N * DT])

        def loss(I, solver=solver, ts=body_ts):
            tr = rj.simulate(
                rj.RigidBody(I),
                wj,
                qj,
                ts,
                solver=solver,
                stepsize_controller=diffrax.ConstantStepSize(),
                dt0=DT,
                max_steps=N + 1,
                check=False,
            )
            y = jnp.concatenate([tr.omega[:, -1], tr.quat[:, -1]], axis=-1)
            return jnp.sum(y * weights)

        I = jnp.asarray([1.0, 2.0, 2.5])
        timings[f"{name}_forward"] = Timing(loss, I)
        timings[f"{name}_value_and_grad"] = Timing(jax.value_and_grad(loss), I)
    for t in timings.values():
        t.warm_up()
    gk = timings["kernel_value_and_grad"].output[1]
    gd = timings["diffrax_value_and_grad"].output[1]
    agree = float(jnp.max(jnp.abs(gk - gd)) / jnp.max(jnp.abs(gd)))
    interleaved(timings.values(), repeats)
    res = {k: t.summary() for k, t in timings.items()}
    out = dict(B=B, N=N, wrt="principal moments (3,)", timings=res, gradient_rel_diff=agree)
    for name in ("kernel", "diffrax"):
        out[f"{name}_ratio"] = (
            timings[f"{name}_value_and_grad"].best / timings[f"{name}_forward"].best
        )
    out["kernel_gradient_vs_diffrax_gradient"] = (
        timings["diffrax_value_and_grad"].best / timings["kernel_value_and_grad"].best
    )
    log(
        f"  gradient/forward: kernel {out['kernel_ratio']:.2f}x, diffrax "
        f"{out['diffrax_ratio']:.2f}x; kernel gradient "
        f"{out['kernel_gradient_vs_diffrax_gradient']:.1f}x faster than the Diffrax path's; "
        f"agree to {agree:.1e}"
    )
    return out


def float32_part(repeats: int) -> dict:
    B, N = 10_000, 2000
    w0, q0 = make_inputs(B, seed=2)
    t64 = Timing(forward(N), jnp.asarray(w0), jnp.asarray(q0))
    t32 = Timing(
        forward(N, dtype=jnp.float32),
        jnp.asarray(w0, jnp.float32),
        jnp.asarray(q0, jnp.float32),
    )
    w64, q64 = t64.warm_up()
    w32, q32 = t32.warm_up()
    interleaved([t64, t32], repeats)
    err = float(max(jnp.max(jnp.abs(w32 - w64)), jnp.max(jnp.abs(q32 - q64))))
    return dict(
        B=B,
        N=N,
        float64_body_steps_per_s=B * N / t64.best,
        float32_body_steps_per_s=B * N / t32.best,
        speedup=t64.best / t32.best,
        max_abs_error_vs_float64=err,
    )


def with_peak_fraction(res: dict, peak: dict) -> dict:
    """`res` with each rate as a fraction of the fp64 peak (FLOPS_PER_BODY_STEP per step)."""
    for who in ("rigidjax", "c"):
        rate = res.get(f"{who}_body_steps_per_s")
        if rate is not None and peak["flops"]:
            res[f"{who}_fraction_of_fp64_peak"] = rate * FLOPS_PER_BODY_STEP / peak["flops"]
    return res


def probe_process(*args: str) -> dict:
    """`worker` on this script, stopping the run where it failed."""
    res = worker(__file__, *args)
    if "error" in res:
        raise SystemExit(f"probe {args} failed:\n{res['error']}")
    return res


def run(args, log: Log) -> dict:
    batches = QUICK_BATCHES if args.quick else FULL_BATCHES
    peak = peak_fp64_flops()
    log(f"bench_kernel: batches {batches}, repeats {args.repeats}, load {log.load_start}")
    points = []
    for B in batches:
        res = probe_process("--_probe", str(B), "--repeats", str(args.repeats))
        points.append(with_peak_fraction(res, peak))
        log(
            f"  B={B:>9,} N={res['N']:>6}: rigidjax {res['rigidjax_body_steps_per_s']:.3g}, C "
            f"{res.get('c_body_steps_per_s', float('nan')):.3g} body-steps/s, ratio "
            f"{res.get('ratio_vs_c', float('nan')):.2f}, peak RSS "
            f"{res['peak_rss_bytes'] / 2**20:.0f} MiB"
        )
    log("flat scaling: every batch size in one process, interleaved rounds")
    sizes = ",".join(map(str, batches))
    flat = probe_process("--_flat", sizes, "--repeats", str(args.flat_repeats))
    flat_points = [with_peak_fraction(p, peak) for p in flat["points"]]
    for p in flat_points:
        log(
            f"  B={p['B']:>9,}: rigidjax {p['rigidjax_body_steps_per_s']:.3g}, C "
            f"{p.get('c_body_steps_per_s', float('nan')):.3g} body-steps/s"
        )
    log("gradient vs forward")
    gradient = gradient_part(args.repeats, log)
    log("float32")
    f32 = float32_part(args.repeats)
    log(f"  float32 {f32['speedup']:.2f}x float64, error {f32['max_abs_error_vs_float64']:.1e}")

    def spread(pts, who):
        r = [p[f"{who}_body_steps_per_s"] for p in pts if f"{who}_body_steps_per_s" in p]
        return min(r) / max(r) if r else None

    ratios = [p["ratio_vs_c"] for p in points if "ratio_vs_c" in p]
    large = [p["ratio_vs_c"] for p in points if "ratio_vs_c" in p and p["B"] >= 10_000]
    flat = spread(flat_points, "rigidjax")
    summary = dict(
        best_rigidjax_body_steps_per_s=max(p["rigidjax_body_steps_per_s"] for p in flat_points),
        worst_over_best_rigidjax=flat,
        worst_over_best_c=spread(flat_points, "c"),
        worst_over_best_rigidjax_separate_processes=spread(points, "rigidjax"),
        worst_over_best_c_separate_processes=spread(points, "c"),
        min_ratio_vs_c=min(ratios) if ratios else None,
        min_ratio_vs_c_at_large_batches=min(large) if large else None,
        gradient_over_forward_kernel=gradient["kernel_ratio"],
        gradient_over_forward_diffrax=gradient["diffrax_ratio"],
        float32_speedup=f32["speedup"],
    )
    targets = dict(
        ratio_vs_c=target(summary["min_ratio_vs_c_at_large_batches"], TARGETS["ratio_vs_c"]),
        flat_scaling=target(flat, TARGETS["flat_within"]),
        gradient_over_forward=target(
            gradient["kernel_ratio"], TARGETS["gradient_over_forward"], at_least=False
        ),
    )
    return dict(
        benchmark="bench_kernel",
        timestamp=timestamp(),
        quick=args.quick,
        parameters=dict(
            moments=list(MOMENTS),
            dt=DT,
            steps="max(200, 2e8 / B)",
            repeats=args.repeats,
            flat_repeats=args.flat_repeats,
            flops_per_body_step=FLOPS_PER_BODY_STEP,
            fp64_peak=peak,
            timing_statistic="best of the repeats after one warm-up, interleaved rounds "
            "(scaling: rigidjax and C per batch size, each size in a fresh process; flat: every "
            "size and both kernels in one process)",
        ),
        machine=machine_info(),
        load_average_start=log.load_start,
        scaling=points,
        flat=flat_points,
        gradient=gradient,
        float32=f32,
        summary=summary,
        targets=targets,
    )


def plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = out["flat"]
    B = [p["B"] for p in pts]
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(B, [p["rigidjax_body_steps_per_s"] for p in pts], "o-", label="rigidjax simulate, RK4")
    if all("c_body_steps_per_s" in p for p in pts):
        ax.plot(B, [p["c_body_steps_per_s"] for p in pts], "s--", label="hand-written C (OpenMP)")
    ax.set_xscale("log")
    ax.set_ylim(bottom=0)
    ax.set_xlabel("bodies B")
    ax.set_ylabel("body-steps / s")
    ax.set_title("Fixed-step free body, float64, one process, interleaved rounds")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    p = parser(__doc__, "kernel.json", quick="1e3 … 1e5 bodies only")
    p.add_argument(
        "--flat-repeats", type=int, default=3, help="rounds of the one-process flat-scaling part"
    )
    p.add_argument("--_probe", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_flat", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args._probe is not None:
        print(json.dumps(probe(args._probe, args.repeats)))
        return
    if args._flat is not None:
        sizes = tuple(int(b) for b in args._flat.split(","))
        print(json.dumps(dict(points=flat_probe(sizes, args.repeats))))
        return
    out = execute(run, args, lambda out: print_targets(out["targets"]))
    plot(out, args.out.with_suffix(".png"))


if __name__ == "__main__":
    sys.exit(main())
