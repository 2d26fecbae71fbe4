"""Batched free rigid-body dynamics: rigidjax vs a lean lax.scan RK4 kernel vs NumPy vs SciPy.

Problem
    B free rigid bodies (float64), principal moments I = (1, 2, 3), Ω0 ~ N(0, 1)³, uniformly
    random unit quaternions q0 (scalar first), N fixed steps of dt = 1e-3 (full run: B = 10⁴,
    N = 2000, T = 2): Euler's equations with q̇ = ½ q ∘ (0, Ω), the quaternion renormalised after
    every step by every fixed-step contender (as rigidjax's ``kinematics="quat"`` does).

Contenders (same run, same inputs; README.md describes each and every JSON field)
    rigidjax ``simulate`` with the batch as one state (``rigidjax_rk4``: RK4 at constant step,
    the headline; saving 21 times; Tsit5; RKMK with RK4 and Dopri5; ``jax.vmap`` of single
    bodies); the lean kernels, a hand-written RK4 in ``lax.scan`` on (B, 3)/(B, 4) arrays, under
    ``jax.vmap`` and on seven (B,) components ("the lean kernel" is the fastest); a diagnostic
    ``diffrax.diffeqsolve`` on the lean components; NumPy's RK4; SciPy ``solve_ivp`` (RK45,
    DOP853) per trajectory on S trajectories at the loosest tolerance reaching rigidjax_rk4's
    error; and, after the rounds, rigidjax's defaults, Dopri8 at the largest constant step
    reaching that error, and ``ExactFreeBody``.

Reference: RK4 at dt/8 in ``np.longdouble`` on the S trajectories, cross-checked against DOP853
at rtol 2.5e-14. Timing: the harness's ahead-of-time compile, one warm-up, ``--repeats``
interleaved rounds, best of; the first call in a fresh process (no compilation cache). Targets:
rigidjax_rk4 ≥ 0.7× the lean kernel; ≥ 1000× SciPy per trajectory at equal accuracy; first
compile ≤ 1.5 s.

Usage
    python benchmarks/bench_dynamics.py [--quick] [--repeats 3] [--seed 0]
        [--out benchmarks/results/dynamics.json]
"""

from __future__ import annotations

import time

_T_PROCESS_START = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it

import diffrax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _free_body import (  # noqa: E402
    MOMENTS,
    diag_diffeqsolve_soa_fn,
    errors,
    lean_arrays_fn,
    lean_soa_fn,
    make_inputs,
    norm_drift,
    numpy_rk4,
    reference,
    scipy_solve,
)
from _harness import (  # noqa: E402
    Log,
    Timing,
    block,
    execute,
    interleaved,
    load_average,
    machine_info,
    measure,
    parser,
    print_targets,
    table,
    target,
    timed,
    timestamp,
    worker,
)

from rigidjax import RK4, ExactFreeBody, RigidBody, simulate  # noqa: E402

_T_IMPORTED = time.perf_counter()

FULL: dict[str, Any] = dict(B=10_000, N=2000, dt=1e-3, scipy_subset=16, ref_refine=8)
QUICK: dict[str, Any] = dict(B=1000, N=500, dt=1e-3, scipy_subset=8, ref_refine=4)
DOPRI8_STEPS = (0.25, 0.2, 0.16, 0.125, 0.1, 0.08, 0.0625, 0.05, 0.04)
SCIPY_TOLS = [1e-8, 1e-9, 1e-10, 1e-11, 3e-12, 1e-12, 3e-13, 1e-13, 5e-14, 2.5e-14]
TARGETS = dict(ratio_vs_lean=0.7, scipy_speedup_per_trajectory=1000.0, first_compile_s=1.5)

LOAD_ROUNDS: list = []  # load average after each interleaved JAX timing round

RIGIDJAX_VARIANTS = {  # simulate's options, and the description
    "rk4": (dict(solver=RK4()),
            "simulate, batch as one state, solver=RK4(), ConstantStepSize, dt0=dt"),
    "rk4_saved21": (dict(solver=RK4(), saved=21),
                    "as rigidjax_rk4, saving 21 equally spaced times (every N/20 steps)"),
    "tsit5": ({}, "simulate default solver (Tsit5, unrolled ExplicitRK), constant step dt"),
    "geometric_rk4": (dict(kinematics="geometric", solver=RK4()),
                      "simulate kinematics='geometric', RKMK(RK4), constant step dt"),
    "geometric_default": (dict(kinematics="geometric"),
                          "simulate kinematics='geometric', default RKMK-Dopri5, constant step dt"),
    "vmap_rk4": (dict(solver=RK4()), "jax.vmap over single-body simulate, RK4, constant step dt"),
}  # fmt: skip


def final_state(T: float, saved: int = 2, steps: bool = False, **kw) -> Callable:
    """`simulate` over [0, T] (`saved` equally spaced outputs) with options `kw`: the final
    (Ω, q), and the number of steps if `steps`."""
    moments, ts = jnp.array(MOMENTS), jnp.linspace(0.0, T, saved)

    def solve(w, q):
        tr = simulate(RigidBody(moments), w, q, ts, **kw)
        out = (tr.omega[..., -1, :], tr.quat[..., -1, :])
        return (*out, tr.stats["num_steps"]) if steps else out

    return solve


def rigidjax_fn(N: int, dt: float, variant: str) -> Callable:
    fixed = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=dt, max_steps=N + 1)
    solve = final_state(N * dt, **fixed, **RIGIDJAX_VARIANTS[variant][0])
    return jax.vmap(solve) if variant == "vmap_rk4" else solve


def jax_contenders(N: int, dt: float) -> dict[str, tuple[str, Callable]]:
    """name -> (group, function (w (B, 3), q (B, 4)) -> (w(T), q(T)))."""
    lean = lean_arrays_fn(N, dt)
    return {
        **{f"rigidjax_{v}": ("rigidjax", rigidjax_fn(N, dt, v)) for v in RIGIDJAX_VARIANTS},
        "lean_batch_arrays": ("lean", lean),
        "lean_vmap_single": ("lean", jax.vmap(lean)),
        "lean_batch_soa": ("lean", lean_soa_fn(N, dt)),
        "diag_diffeqsolve_soa": ("diagnostic", diag_diffeqsolve_soa_fn(N, dt)),
    }


DESCRIPTIONS = {
    **{f"rigidjax_{v}": d for v, (_, d) in RIGIDJAX_VARIANTS.items()},
    "lean_batch_arrays": "hand-written RK4 in lax.scan, batch arrays (B,3)/(B,4)",
    "lean_vmap_single": "jax.vmap of the single-body (3,)/(4,) lax.scan RK4 kernel",
    "lean_batch_soa": "hand-written RK4 in lax.scan, seven (B,) component arrays",
    "diag_diffeqsolve_soa": "diagnostic: diffrax.diffeqsolve + rigidjax ExplicitRK(RK4) + "
    "StepEndMap renormalisation on the lean SoA vector field",
    "numpy_rk4": "plain NumPy RK4 vectorised over the batch (SoA)",
}


def time_jax(cfg: dict, w0, q0, repeats: int, log) -> tuple[dict, dict]:
    """Compile every JAX contender ahead of time, warm up, then time interleaved rounds."""
    B, N = cfg["B"], cfg["N"]
    wj, qj = jnp.asarray(w0), jnp.asarray(q0)
    timings, results, outputs = {}, {}, {}
    for name, (group, fn) in jax_contenders(N, cfg["dt"]).items():
        t = timings[name] = Timing(fn, wj, qj)
        out = t.warm_up()
        outputs[name] = (np.asarray(out[0]), np.asarray(out[1]))
        results[name] = dict(
            group=group,
            description=DESCRIPTIONS[name],
            trace_lower_s_in_process=t.trace_lower_s,
            compile_s_in_process=t.compile_s,
            warmup_run_s=t.first_run_s,
        )
        log(
            f"  compiled {name:<28} trace+lower {t.trace_lower_s:5.2f} s  "
            f"compile {t.compile_s:5.2f} s  warm-up run {t.first_run_s:6.2f} s"
        )

    def after_round(r: int) -> None:
        LOAD_ROUNDS.append(load_average())
        log(f"  round {r + 1}/{repeats} done (load {LOAD_ROUNDS[-1]})")

    interleaved(timings.values(), repeats, after_round)
    for name, t in timings.items():
        results[name].update(rates(t, B, N))
    return results, outputs


def compile_probe(name: str, B: int, N: int, dt: float, seed: int) -> dict:
    """Run in a fresh process: time trace+lower, compile and the first run of one contender."""
    wj, qj = block(tuple(jnp.asarray(a) for a in make_inputs(B, seed)))
    t = Timing(jax_contenders(N, dt)[name][1], wj, qj)
    t.warm_up()
    return dict(name=name, import_s=_T_IMPORTED - _T_PROCESS_START, **t.first_call_record())


def fresh_process_probe(name: str, cfg: dict, seed: int) -> dict:
    args = ["--_probe", name, "--seed", str(seed), "--_B", str(cfg["B"]), "--_N", str(cfg["N"])]
    res = worker(__file__, *args, cold=True)
    return dict(error=res["error"], name=name) if "error" in res else res


def rates(t: Timing, B: int, N: int, cpu: bool = True) -> dict:
    return dict(
        t.summary(cpu=cpu), body_steps_per_s=B * N / t.best, seconds_per_trajectory=t.best / B
    )


def time_numpy(cfg, w0, q0, repeats: int, log) -> tuple[dict, tuple]:
    t = measure(numpy_rk4, w0, q0, cfg["N"], cfg["dt"], repeats=repeats, aot=False, warmup=False)
    log(f"  numpy_rk4: best {t.best:.2f} s")
    res = dict(group="numpy", description=DESCRIPTIONS["numpy_rk4"])
    return dict(res, **rates(t, cfg["B"], cfg["N"])), t.output


def calibrate(values, attempt: Callable, target_err: float) -> tuple[list, bool]:
    """`attempt(v)` (a row with its `error`) for each value in turn, until one reaches
    `target_err`: the rows tried (the last one is the choice) and whether it reached it."""
    rows = []
    for v in values:
        rows.append(attempt(v))
        if rows[-1]["error"]["max"] <= target_err:
            return rows, True
    return rows, False


def scipy_part(cfg, w0, q0, refs, target_err: float, repeats: int, log) -> dict:
    """Calibrate each SciPy method's tolerance to rigidjax_rk4's error, then time it."""
    S, T = cfg["scipy_subset"], cfg["N"] * cfg["dt"]
    ws, qs = w0[:S], q0[:S]
    out = {}
    for method in ("RK45", "DOP853"):

        def attempt(tol, method=method):
            (w, q, nfev), el, _ = timed(scipy_solve, ws, qs, T, method, tol, tol)
            return dict(rtol=tol, atol=tol, error=errors(w, q, *refs), nfev_per_trajectory=nfev / S,
                        seconds_per_trajectory_single_run=el / S)  # fmt: skip

        sweep, reached = calibrate(SCIPY_TOLS, attempt, target_err)
        tol = sweep[-1]["rtol"]
        t = measure(scipy_solve, ws, qs, T, method, tol, tol, repeats=repeats, aot=False,
                    warmup=False)  # fmt: skip
        w, q, nfev = t.output
        out[f"scipy_{method.lower()}"] = dict(
            group="scipy",
            description=f"scipy.integrate.solve_ivp {method} per trajectory, rtol = atol = {tol:g}",
            trajectories=S,
            rtol=tol,
            atol=tol,
            reached_equal_accuracy=reached,
            tolerance_sweep=sweep,
            nfev_per_trajectory=nfev / S,
            all_seconds=t.times,
            seconds=t.best,
            seconds_per_trajectory=t.best / S,
            error_vs_reference=errors(w, q, *refs),
            quat_norm_drift=norm_drift(q),
        )
        log(
            f"  scipy {method}: rtol {tol:g} (equal accuracy reached: {reached}), "
            f"{t.best / S * 1e3:.3f} ms / trajectory, nfev {nfev / S:.0f}"
        )
    return out


def batch_row(t: Timing, S: int, refs: tuple, description: str, **fields) -> dict:
    """A rigidjax row timed after the rounds, on the whole batch: its timing, the error of its
    first S trajectories against the reference `refs` = (Ω, q), the norm drift."""
    w, q = t.output[:2]
    return dict(
        group="rigidjax",
        description=description + " (timed after the interleaved rounds)",
        **fields,
        **t.summary(),
        seconds_per_trajectory=t.best / w.shape[0],
        error_vs_reference=errors(np.asarray(w[:S]), np.asarray(q[:S]), *refs),
        quat_norm_drift=norm_drift(q),
    )


def dopri8_part(cfg, wj, qj, refs, target_err: float, repeats: int, log) -> dict:
    """rigidjax's fastest configuration found at equal accuracy: ``simulate`` with
    ``diffrax.Dopri8`` (the Dormand–Prince 8(5,3) tableau of SciPy's DOP853) at the largest
    constant step of ``DOPRI8_STEPS`` whose error is ≤ the target, on the whole batch."""
    S, T = cfg["scipy_subset"], cfg["N"] * cfg["dt"]
    fixed: dict[str, Any] = dict(
        solver=diffrax.Dopri8(), stepsize_controller=diffrax.ConstantStepSize()
    )
    timings = []

    def attempt(h):
        t = Timing(final_state(T, steps=True, dt0=h, **fixed), wj, qj)
        timings.append(t)
        w, q, steps = t.warm_up()  # the sweep's run is the chosen step's warm-up
        err = errors(np.asarray(w[:S]), np.asarray(q[:S]), *refs)
        return dict(dt=h, steps=int(steps), error=err, compile_s=t.trace_lower_compile_s)

    sweep, reached = calibrate(DOPRI8_STEPS, attempt, target_err)
    pick, t = sweep[-1], timings[-1]
    t.run(repeats)  # t: the last step compiled, the chosen one
    log(
        f"  rigidjax Dopri8: dt {pick['dt']:g} ({pick['steps']} steps, equal accuracy reached: "
        f"{reached}), {t.best / wj.shape[0] * 1e6:.2f} us / trajectory"
    )
    return batch_row(
        t,
        S,
        refs,
        f"simulate (CPU kernel), batch as one state, solver=diffrax.Dopri8(), ConstantStepSize, "
        f"dt0={pick['dt']:g} ({pick['steps']} steps): the largest step of the sweep reaching "
        "rigidjax_rk4's error",
        dt=pick["dt"],
        steps=pick["steps"],
        reached_equal_accuracy=reached,
        step_sweep=sweep,
    )


def after_rounds_part(cfg, wj, qj, refs, target_err, repeats: int, log) -> dict:
    """``simulate`` with its defaults (Tsit5, PID at rtol = atol = 1e-10, the step size set by
    the worst member of the batch: what a user gets without choosing) and with
    ``ExactFreeBody()`` (the exact Euler–Poinsot flow, one step from 0 to T per body), on the
    whole batch."""
    T, S = cfg["N"] * cfg["dt"], cfg["scipy_subset"]
    t = measure(final_state(T, steps=True), wj, qj, repeats=repeats)
    steps = int(t.output[2])
    log(f"  rigidjax defaults: {steps} steps, {t.best / wj.shape[0] * 1e6:.2f} us / trajectory")
    out = dict(rigidjax_adaptive_default=batch_row(
        t, S, refs, "simulate with its defaults: Tsit5 (unrolled), PID at rtol = atol = 1e-10 "
        "controlled by the worst member", steps=steps, trace_lower_compile_s=t.trace_lower_compile_s
    ))  # fmt: skip
    t = measure(final_state(T, solver=ExactFreeBody()), wj, qj, repeats=repeats)
    row = out["rigidjax_exact"] = batch_row(
        t, S, refs, "simulate, solver=ExactFreeBody(): the exact flow from 0 to T in one step per "
        "body", trace_lower_compile_s=t.trace_lower_compile_s,
    )  # fmt: skip
    err = row["error_vs_reference"]["max"]
    row["reached_equal_accuracy"] = bool(err <= target_err)
    log(f"  rigidjax ExactFreeBody: error {err:.2e}, {row['seconds_per_trajectory'] * 1e6:.2f} us")
    return out


def run(args, log: Log) -> dict:
    cfg = dict(QUICK if args.quick else FULL)
    B, N, dt, S = cfg["B"], cfg["N"], cfg["dt"], cfg["scipy_subset"]
    T = N * dt
    log(f"bench_dynamics: B={B}, N={N}, dt={dt}, T={T}, repeats={args.repeats}")
    w0, q0 = make_inputs(B, args.seed)

    log("first call in a fresh process")
    probes = {n: fresh_process_probe(n, cfg, args.seed) for n in ("rigidjax_rk4", "lean_batch_soa")}
    for n, p in probes.items():
        keys = ("import_s", "trace_lower_s", "compile_s", "first_run_s")
        log(f"  {n}: " + (p.get("error") or ", ".join(f"{k} {p[k]:.2f}" for k in keys)))

    log("JAX contenders")
    results, outputs = time_jax(cfg, w0, q0, args.repeats, log)
    load_after_jax = load_average()

    log("NumPy")
    results["numpy_rk4"], outputs["numpy_rk4"] = time_numpy(cfg, w0, q0, args.repeats, log)

    log(f"reference: RK4 at dt/{cfg['ref_refine']} in np.longdouble on {S} trajectories")
    t0 = time.perf_counter()
    refs = reference(w0[:S], q0[:S], N, dt, cfg["ref_refine"])
    ref_s = time.perf_counter() - t0
    w_tight, q_tight, _ = scipy_solve(w0[:S], q0[:S], T, "DOP853", 2.5e-14, 1e-16)
    ref_check = errors(w_tight, q_tight, *refs)
    log(f"  {ref_s:.1f} s; tight DOP853 vs reference: {ref_check['max']:.2e}")

    for name, (w, q) in outputs.items():
        results[name].update(
            error_vs_reference=errors(w[:S], q[:S], *refs),
            max_abs_diff_vs_lean=errors(w, q, *outputs["lean_batch_soa"])["max"],
            quat_norm_drift=norm_drift(q),
        )
    target_err = results["rigidjax_rk4"]["error_vs_reference"]["max"]
    log(f"SciPy per trajectory, tolerance calibrated to rigidjax_rk4's error {target_err:.2e}")
    results.update(scipy_part(cfg, w0, q0, refs, target_err, args.repeats, log))
    wj, qj = jnp.asarray(w0), jnp.asarray(q0)
    log("rigidjax with its defaults, and with its exact free-body solver")
    results.update(after_rounds_part(cfg, wj, qj, refs, target_err, args.repeats, log))
    log("rigidjax's fastest configuration at the same accuracy (Dopri8 step sweep)")
    results["rigidjax_dopri8_equal_accuracy"] = dopri8_part(
        cfg, wj, qj, refs, target_err, args.repeats, log
    )

    summary, targets = summarise(results, probes["rigidjax_rk4"], N)
    parameters = dict(
        B=B, N=N, dt=dt, T=T, moments=list(MOMENTS), seed=args.seed, repeats=args.repeats,
        dtype="float64", omega0="N(0, 1)^3 per body", q0="uniform random unit quaternion",
        scipy_subset=S, scipy_tolerances_tried=SCIPY_TOLS,
        reference=f"RK4 at dt/{cfg['ref_refine']} in np.longdouble on the first {S} trajectories "
        "(renormalised each step)",
        error_metric="max over the subset of max|Ω−Ω_ref| and max|q−q_ref| (q up to sign) at t = T",
        timing_statistic="best (minimum) of the repeats after one warm-up; JAX contenders timed in "
        "interleaved rounds",
    )  # fmt: skip
    return dict(
        benchmark="bench_dynamics",
        timestamp=timestamp(),
        quick=args.quick,
        parameters=parameters,
        machine=machine_info(),
        load_average_start=log.load_start,
        load_average_jax_rounds=LOAD_ROUNDS,
        load_average_after_jax=load_after_jax,
        reference_seconds=ref_s,
        reference_check_tight_dop853=dict(rtol=2.5e-14, atol=1e-16, error=ref_check),
        fresh_process=probes,
        results=results,
        summary=summary,
        targets=targets,
    )


def summarise(results: dict, probe: dict, N: int) -> tuple[dict, dict]:
    """The lean kernel (the fastest), every row's ratio to it, the speedups per trajectory over
    SciPy, rigidjax's best configuration at equal accuracy; the summary and the targets."""
    lean = max((n for n, r in results.items() if r["group"] == "lean"),
               key=lambda n: results[n]["body_steps_per_s"])  # fmt: skip
    rj, lean_rate = results["rigidjax_rk4"], results[lean]["body_steps_per_s"]
    for res in results.values():
        rate = res.get("body_steps_per_s")
        res["ratio_vs_lean"] = None if rate is None else rate / lean_rate
    ratio = rj["ratio_vs_lean"]
    scipy = ["scipy_rk45", "scipy_dop853"]
    pool = [n for n in scipy if results[n]["reached_equal_accuracy"]] or scipy
    sp_best = min(pool, key=lambda n: results[n]["seconds_per_trajectory"])
    per = {n: r["seconds_per_trajectory"] for n, r in results.items()}
    exact = ("rigidjax_dopri8_equal_accuracy", "rigidjax_exact")
    speedups = {f"{n}_vs_{sp}": per[sp] / per[n]
                for n in ("rigidjax_rk4", *exact, lean, "numpy_rk4") for sp in scipy}  # fmt: skip
    # the verdict: rigidjax's faster configuration among those reaching the target accuracy
    rj_pool = ["rigidjax_rk4"] + [n for n in exact if results[n]["reached_equal_accuracy"]]
    rj_best = max(rj_pool, key=lambda n: speedups[f"{n}_vs_{sp_best}"])
    speedup = speedups[f"{rj_best}_vs_{sp_best}"]
    first_compile = probe.get("trace_lower_compile_s")
    equal = results[sp_best]["reached_equal_accuracy"]
    summary = dict(
        lean_kernel=lean,
        rigidjax_rk4_body_steps_per_s=rj["body_steps_per_s"],
        lean_kernel_body_steps_per_s=lean_rate,
        ratio_rigidjax_rk4_vs_lean=ratio,
        ratio_rigidjax_rk4_vs_lean_per_round=[
            a / b for a, b in zip(results[lean]["all_seconds"], rj["all_seconds"], strict=True)
        ],
        ratio_rigidjax_rk4_vs_lean_cpu_time=results[lean]["cpu_seconds"] / rj["cpu_seconds"],
        scipy_reference_method=sp_best,
        scipy_equal_accuracy_reached=equal,
        speedup_per_trajectory=speedups,
        rigidjax_rk4_speedup_vs_scipy_per_trajectory=speedups[f"rigidjax_rk4_vs_{sp_best}"],
        rigidjax_best_at_equal_accuracy=rj_best,
        rigidjax_best_speedup_vs_scipy_per_trajectory=speedup,
        body_steps_per_s_needed_for_scipy_target=TARGETS["scipy_speedup_per_trajectory"]
        * N
        / per[sp_best],
        first_compile_s_fresh_process=first_compile,
        first_call_s_fresh_process=probe.get("first_call_s"),
        first_compile_s_in_process=rj["trace_lower_s_in_process"] + rj["compile_s_in_process"],
    )
    how = "trace+lower+XLA compile of rigidjax_rk4 in a fresh process"
    targets = dict(
        ratio_vs_lean=target(ratio, TARGETS["ratio_vs_lean"]),
        scipy_speedup_per_trajectory=target(speedup, TARGETS["scipy_speedup_per_trajectory"],
                                            rigidjax=rj_best, against=sp_best,
                                            equal_accuracy=equal),
        first_compile_s=target(first_compile, TARGETS["first_compile_s"], at_least=False,
                               measured=how),
    )  # fmt: skip
    targets["scipy_speedup_per_trajectory"]["passed"] &= bool(equal)
    return summary, targets


def print_table(out: dict) -> None:
    columns = [("contender", "<32"), ("body-steps/s", ">14.3g"), ("s/traj", ">11.3g"),
               ("vs lean", ">9.3f"), ("compile", ">9.2f"), ("err vs ref", ">12.2e"),
               ("|q|-1", ">10.1e")]  # fmt: skip
    rows = [
        [name, r.get("body_steps_per_s"), r["seconds_per_trajectory"], r.get("ratio_vs_lean"),
         (r["compile_s_in_process"] + r["trace_lower_s_in_process"]) if "compile_s_in_process" in r
         else None,
         r["error_vs_reference"]["max"], r["quat_norm_drift"]]
        for name, r in out["results"].items()
    ]  # fmt: skip
    print("\n" + table(columns, rows) + "\n")
    s = out["summary"]
    print(
        f"lean kernel = {s['lean_kernel']}; rigidjax_rk4 / lean = "
        f"{s['ratio_rigidjax_rk4_vs_lean']:.3f} (per round "
        f"{', '.join(f'{x:.3f}' for x in s['ratio_rigidjax_rk4_vs_lean_per_round'])}; "
        f"by CPU time {s['ratio_rigidjax_rk4_vs_lean_cpu_time']:.3f})"
    )
    for k, v in s["speedup_per_trajectory"].items():
        print(f"speedup per trajectory {k}: {v:.1f}x")
    print_targets(out["targets"])


def main(argv=None) -> None:
    p = parser(__doc__, "dynamics.json", quick="B=1000, N=500 smoke run", seed=True)
    p.add_argument("--_probe", default=None, help=argparse.SUPPRESS)
    p.add_argument("--_B", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_N", type=int, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args._probe:
        print(json.dumps(compile_probe(args._probe, args._B, args._N, FULL["dt"], args.seed)))
        return
    execute(run, args, print_table)


if __name__ == "__main__":
    main()
