"""Darboux problem (attitude from angular velocity): every formulation on a closed-form motion.

Problem
    Classical coning, ``P(t) = Rz(Ωt) Rx(β) Rz(−Ωt)``, space angular velocity
    ``ω(t) = Ω (−sin β sin Ωt, sin β cos Ωt, 1 − cos β)``, Ω = 2π rad/s, β = 0.3 rad,
    ``P(0) = Rx(β)``, float64; the exact solution from the closed form in NumPy.

Methods
    ``matrix`` (Poisson equation), ``rotvec`` (shadow switching), ``quat``, ``euler``
    (``EULER_SEQ``; its distance from gimbal lock is recorded), ``cayley_klein``, all with Tsit5
    (unrolled) in ``StepEndMap``, and ``geometric`` (RKMK, Dopri5): the defaults of
    ``rigidjax.darboux``, whose setup the benchmark replicates to read ``sol.stats`` (and checks
    against ``rigidjax.darboux`` itself: ``max_abs_diff_vs_darboux``).

What is measured
    1. Work–precision on [0, 10], 201 save times, PID at rtol = atol = tol: the max entrywise
       and geodesic errors; right-hand-side evaluations counted exactly (a separate compilation
       whose vector field counts through ``jax.debug.callback``); wall time of a callback-free
       compilation (ahead of time; one compilation for all tolerances), median and minimum.
    2. Orthogonality drift ‖PᵀP − E‖_F and attitude error at constant dt over [0, T_drift], and
       the Poisson matrix method with explicit Euler.
    3. Batched throughput: ``jax.jit(jax.vmap(solve))`` over B attitudes ``exp(δ_b) P(0)``,
       δ_b ~ N(0, 0.3² E), 1000 steps of 1e-3: trajectory-steps per second (best of up to 3),
       compile time, and the error at t = 1; a control row runs plain diffrax Tsit5 on ẏ = −y.

Usage
    python benchmarks/bench_darboux.py [--quick] [--out-dir benchmarks/results] [--repeats 5]
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it

import diffrax  # noqa: E402
import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _harness import (  # noqa: E402
    RESULTS,
    Log,
    Timing,
    aot_compile,
    block,
    figure,
    machine_info,
    measure,
    parser,
    timestamp,
    write_json,
)

from rigidjax import darboux, euler, so3  # noqa: E402
from rigidjax.kinematics import METHODS as KINEMATICS  # noqa: E402
from rigidjax.kinematics import AbstractKinematics, check_omega  # noqa: E402
from rigidjax.solvers.explicit_rk import unrolled  # noqa: E402
from rigidjax.solvers.rkmk import RKMK, LieTerm  # noqa: E402
from rigidjax.solvers.step_end_map import StepEndMap  # noqa: E402

METHODS = ["matrix", "rotvec", "quat", "euler", "cayley_klein", "geometric"]
EULER_SEQ = "ZYX"  # Tait–Bryan: |det J| = |cos pitch| ≥ cos β on this motion (checked below)
RATE = 2 * np.pi  # Ω, rad/s
BETA = 0.3  # cone half-angle, rad

FULL = dict(
    tols=[1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12],
    t_end=10.0,
    n_save=201,
    drift_t=100.0,
    drift_dt=1e-3,
    drift_n_save=201,
    batch=1024,
    batch_steps=1000,
    batch_dt=1e-3,
)
QUICK = dict(FULL, tols=[1e-4, 1e-6, 1e-8, 1e-10, 1e-12], drift_t=10.0, drift_n_save=101, batch=128)


def rot(axis: int, a) -> np.ndarray:
    """Rotations by the angles `a` about the coordinate axis `axis`, shape (..., 3, 3)."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    i, j = (k for k in range(3) if k != axis)
    R = np.zeros((*a.shape, 3, 3))
    R[..., axis, axis] = 1.0
    R[..., i, i], R[..., j, j], R[..., i, j], R[..., j, i] = c, c, -s, s
    return R


def exact(ts) -> np.ndarray:
    """Closed-form coning attitude P(t) = Rz(Ωt) Rx(β) Rz(−Ωt), shape (T, 3, 3)."""
    ts = np.asarray(ts, dtype=np.float64)
    return rot(2, RATE * ts) @ rot(0, np.full_like(ts, BETA)) @ rot(2, -RATE * ts)


class ConingOmega(eqx.Module):
    """Space angular velocity of the coning motion (floats are static: one stable hash)."""

    rate: float = eqx.field(static=True)
    beta: float = eqx.field(static=True)

    def __call__(self, t):
        s, c = np.sin(self.beta), np.cos(self.beta)
        a = self.rate * t
        return self.rate * jnp.stack([-s * jnp.sin(a), s * jnp.cos(a), (1 - c) + 0 * t])


OMEGA = ConingOmega(float(RATE), float(BETA))

# --------------------------------------------------------------------------- counting vector fields

_COUNT = [0]


def _increment(_):
    _COUNT[0] += 1


def _maybe_count(w, t, count: bool):
    if count:
        jax.debug.callback(_increment, t)
    return w


class _Field(eqx.Module):
    """`(t, y) -> ẏ` for a kinematics formulation (as rigidjax's `_KinematicsField`)."""

    kin: AbstractKinematics
    omega: Callable
    count: bool = eqx.field(static=True)

    def __call__(self, t, y, args):
        w = _maybe_count(check_omega(self.omega(t)), t, self.count)
        return self.kin.vector_field(y, w.astype(y.dtype))


class _LieField(eqx.Module):
    """`(t, (R, None)) -> (ω, None)` for RKMK (as `rigidjax.kinematics.darboux._LieField`)."""

    omega: Callable
    count: bool = eqx.field(static=True)

    def __call__(self, t, y, args):
        w = _maybe_count(check_omega(self.omega(t)), t, self.count)
        return w.astype(y[0].dtype), None


def kinematics(method: str) -> AbstractKinematics:
    cls = KINEMATICS[method]
    return cls(seq=EULER_SEQ) if method == "euler" else cls()


def setup(method: str, P0, count: bool = False, base_solver=None):
    """(term, solver, y0, to_matrix) exactly as `rigidjax.darboux` builds them (space frame)."""
    if method == "geometric":
        solver = RKMK(frame="space") if base_solver is None else RKMK(method=base_solver)
        return LieTerm(_LieField(OMEGA, count)), solver, (P0, None), lambda ys: ys[0]
    kin = kinematics(method)
    solver = StepEndMap(unrolled(base_solver), kin.step_end)
    return diffrax.ODETerm(_Field(kin, OMEGA, count)), solver, kin.from_matrix(P0), kin.to_matrix


def _stats(sol):
    return {k: sol.stats[k] for k in ("num_steps", "num_accepted_steps", "num_rejected_steps")}


def solve(term, solver, y0, t1: float, dt0, ts, controller, max_steps: int):
    """`diffrax.diffeqsolve` from 0 to `t1`, saving at `ts`: the solution."""
    return diffrax.diffeqsolve(
        term, solver, 0.0, t1, dt0, y0, saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller, max_steps=max_steps,
    )  # fmt: skip


def _matrices(method: str, sol, to_matrix):
    return sol.ys[0] if method == "geometric" else jax.vmap(to_matrix)(sol.ys)


def adaptive_solver(method: str, ts, count: bool):
    """`f(tol, P0) -> (P at ts, stats)`, PID with rtol = atol = tol (a traced scalar)."""

    def f(tol, P0):
        term, solver, y0, to_matrix = setup(method, P0, count)
        pid = diffrax.PIDController(rtol=tol, atol=tol)
        sol = solve(term, solver, y0, ts[-1], None, ts, pid, 100_000)
        return _matrices(method, sol, to_matrix), _stats(sol)

    return jax.jit(f)


def fixed_solver(method: str, t_end: float, dt: float, n_steps: int, ts_save, base_solver=None):
    """`f(P0) -> (P at ts_save, stats)` with `n_steps` constant steps (not jitted)."""

    def f(P0):
        term, solver, y0, to_matrix = setup(method, P0, False, base_solver)
        fixed = diffrax.ConstantStepSize()
        sol = solve(term, solver, y0, t_end, dt, ts_save, fixed, n_steps + 16)
        return _matrices(method, sol, to_matrix), _stats(sol)

    return f


CONTROL_NOTE = (
    "control: plain diffrax.Tsit5 (no StepEndMap, no rigidjax) on ẏ = −y with the same (3, 3) "
    "state, same steps and batch: diffrax's own per-step cost under vmap on this backend"
)


def control_solver(t_end: float, dt: float, n_steps: int, ts_save):
    def f(P0):
        term, fixed = diffrax.ODETerm(lambda t, y, args: -y), diffrax.ConstantStepSize()
        sol = solve(term, diffrax.Tsit5(), P0, t_end, dt, ts_save, fixed, n_steps + 16)
        return sol.ys, _stats(sol)

    return f


def max_abs(P, Q) -> float:
    return float(np.max(np.abs(np.asarray(P) - np.asarray(Q))))


# --------------------------------------------------------------------------- 1. work–precision


def euler_chart_margin(P) -> float:
    """min |det J| of the Euler chart along attitudes P (0 at gimbal lock, 1 far from it)."""
    angles = euler.from_matrix(jnp.asarray(P), EULER_SEQ)
    return float(jnp.min(jnp.abs(jnp.linalg.det(euler.jacobian(angles, EULER_SEQ, "space")))))


def work_precision(cfg, repeats: int, log) -> dict:
    ts = jnp.linspace(0.0, cfg["t_end"], cfg["n_save"])
    P_ex = exact(np.asarray(ts))
    P0 = jnp.asarray(P_ex[0])
    out = {}
    for method in METHODS:
        fast, c_fast = aot_compile(adaptive_solver(method, ts, False), jnp.asarray(1e-8), P0)
        counted, c_counted = aot_compile(adaptive_solver(method, ts, True), jnp.asarray(1e-8), P0)
        rows = []
        for tol in cfg["tols"]:
            tol_a = jnp.asarray(tol)
            jax.effects_barrier()
            _COUNT[0] = 0
            P, stats = block(counted(tol_a, P0))
            jax.effects_barrier()
            n_eval = _COUNT[0]
            t = measure(fast, tol_a, P0, repeats=repeats, aot=False, min_total=0.2)
            P_t, stats_t = t.output
            P_d = darboux(OMEGA, ts, P0=P0, method=method, seq=EULER_SEQ, rtol=tol_a, atol=tol_a)
            stats = {k: int(v) for k, v in stats.items()}
            steps = stats["num_steps"]
            row = dict(
                tol=tol,
                rhs_evals=n_eval,
                **stats,
                evals_per_step=n_eval / max(steps, 1),
                err_max_abs=max_abs(P_t, P_ex),
                err_geodesic=float(jnp.max(so3.distance(P_t, jnp.asarray(P_ex)))),
                orthogonality_max=float(jnp.max(so3.orthogonality_error(P_t))),
                wall_s_median=t.median,
                wall_s_min=t.best,
                n_timed=t.repeats,
                max_abs_diff_counted_vs_timed=max_abs(P, P_t),
                steps_timed_equal=all(int(stats_t[k]) == stats[k] for k in stats),
                max_abs_diff_vs_darboux=max_abs(P_d, P_t),
            )
            rows.append(row)
            log(
                f"  {method:13s} tol={tol:.0e} evals={n_eval:6d} steps={steps:5d} "
                f"(rej {stats['num_rejected_steps']:3d}) err={row['err_max_abs']:.2e} "
                f"wall={1e3 * row['wall_s_median']:.2f} ms"
            )
        c_time, c_count = c_fast["total_s"], c_counted["total_s"]
        out[method] = dict(compile_s=c_time, compile_counting_s=c_count, rows=rows)
    return out


# --------------------------------------------------------------------------- 2. drift


def drift(cfg, log) -> dict:
    t_end, dt = cfg["drift_t"], cfg["drift_dt"]
    n_steps = round(t_end / dt)
    ts = jnp.linspace(0.0, t_end, cfg["drift_n_save"])
    P_ex = exact(np.asarray(ts))
    P0 = jnp.asarray(P_ex[0])
    variants = [(m, m, None) for m in METHODS] + [("matrix_euler", "matrix", diffrax.Euler())]
    out = {}
    for name, method, base in variants:
        fn = jax.jit(fixed_solver(method, t_end, dt, n_steps, ts, base))
        t = Timing(fn, P0)  # compiled ahead of time, then one timed (first) run
        P, stats = t.warm_up()
        c, run_s = t.trace_lower_compile_s, t.first_run_s
        orth = np.asarray(so3.orthogonality_error(P))
        err = np.max(np.abs(np.asarray(P) - P_ex), axis=(-2, -1))
        out[name] = dict(
            method=method,
            solver="Euler"
            if base is not None
            else ("RKMK-Dopri5" if name == "geometric" else "Tsit5"),
            compile_s=c,
            run_s=run_s,
            num_steps=int(stats["num_steps"]),
            orthogonality=orth.tolist(),
            err_max_abs=err.tolist(),
            final_orthogonality=float(orth[-1]),
            max_orthogonality=float(orth.max()),
            final_err_max_abs=float(err[-1]),
        )
        log(
            f"  {name:13s} steps={out[name]['num_steps']} ‖PᵀP−E‖(T)={orth[-1]:.2e} "
            f"max={orth.max():.2e} err(T)={err[-1]:.2e} run={run_s:.2f} s"
        )
    return dict(ts=np.asarray(ts).tolist(), dt=dt, t_end=t_end, methods=out)


# --------------------------------------------------------------------------- 3. throughput


def throughput(cfg, repeats: int, log) -> dict:
    B, n, dt = cfg["batch"], cfg["batch_steps"], cfg["batch_dt"]
    t_end = n * dt
    ts = jnp.array([0.0, t_end])
    P_ex = exact(np.asarray(ts))
    delta = 0.3 * jax.random.normal(jax.random.key(0), (B, 3), dtype=jnp.float64)
    P0s = so3.exp(delta) @ jnp.asarray(P_ex[0])
    P_end_ex = np.asarray(P_ex[1] @ P_ex[0].T @ np.asarray(P0s))
    # Euler chart margin along the batch (superposed closed form on a grid of 101 times)
    grid = exact(np.linspace(0.0, t_end, 101))
    P_batch_grid = np.einsum("tij,jk,bkl->btil", grid, P_ex[0].T, np.asarray(P0s))
    margin = euler_chart_margin(P_batch_grid.reshape(-1, 3, 3))
    out = {}
    for method in [*METHODS, "control"]:
        if method == "control":
            fn = jax.jit(jax.vmap(control_solver(t_end, dt, n, ts)))
        else:
            fn = jax.jit(jax.vmap(fixed_solver(method, t_end, dt, n, ts)))
        t = measure(fn, P0s, repeats=repeats)
        P, stats = t.output
        c, best = t.trace_lower_compile_s, t.best
        steps = np.asarray(stats["num_steps"])
        out[method] = dict(
            compile_s=c,
            run_s_min=best,
            run_s_median=t.median,
            steps_per_trajectory=int(steps.max()),
            steps_all_equal=bool(np.all(steps == steps[0])),
            traj_steps_per_s=B * int(steps.max()) / best,
            max_err_at_t_end=max_abs(P[:, -1], P_end_ex) if method != "control" else None,
        )
        log(
            f"  {method:13s} compile={c:5.2f} s run={best * 1e3:8.1f} ms "
            f"→ {out[method]['traj_steps_per_s']:.3e} traj·steps/s "
            f"err(t_end)={out[method]['max_err_at_t_end'] or 0:.1e}"
        )
    return dict(
        batch=B,
        steps=n,
        dt=dt,
        euler_chart_min_abs_det=margin,
        control=CONTROL_NOTE,
        methods=out,
    )


COLORS = dict(matrix="tab:red", matrix_euler="tab:pink", rotvec="tab:blue", quat="tab:green",
              euler="tab:orange", cayley_klein="tab:purple", geometric="black")  # fmt: skip
MARKERS = dict(matrix="s", rotvec="o", quat="^", euler="D", cayley_klein="v", geometric="*")


def plot(res: dict, path: Path) -> None:
    floor = 1e-17
    with figure(path, 2, 2, figsize=(13, 9.5)) as (fig, axes):
        ax = axes[0, 0]
        for m, d in res["work_precision"].items():
            ev = [r["rhs_evals"] for r in d["rows"]]
            er = [max(r["err_max_abs"], floor) for r in d["rows"]]
            solver = "RKMK-Dopri5" if m == "geometric" else "Tsit5"
            ax.loglog(ev, er, marker=MARKERS[m], color=COLORS[m], label=f"{m} ({solver})", ms=5)
        for r in res["work_precision"]["quat"]["rows"]:
            ax.annotate(f"{r['tol']:.0e}", (r["rhs_evals"], r["err_max_abs"]),
                        textcoords="offset points", xytext=(-8, -12), ha="right", fontsize=7,
                        color="green")  # fmt: skip
        ax.set_xlabel("right-hand-side evaluations (counted)")
        ax.set_ylabel("max over t of max |P − P_exact| (entrywise)")
        ax.set_title("(a) Work–precision, PID rtol = atol (labels: tol for quat), t ∈ [0, 10]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")

        dr = res["drift"]
        ts = np.asarray(dr["ts"])
        for col, key, title in [
            (axes[0, 1], "orthogonality", "(b) Orthogonality drift ‖PᵀP − E‖_F"),
            (axes[1, 0], "err_max_abs", "(c) Attitude error max |P − P_exact|"),
        ]:
            for name, d in dr["methods"].items():
                y = np.maximum(np.asarray(d[key]), floor)
                label = f"{name} ({d['solver']})"
                col.semilogy(ts[1:], y[1:], color=COLORS[name], label=label, lw=1.3)
            col.set_xlabel("t [s]")
            col.set_title(f"{title}, constant dt = {dr['dt']:g}")
            col.grid(True, which="both", alpha=0.3)
            col.legend(fontsize=8, loc="center right")
        axes[0, 1].set_ylabel(f"‖PᵀP − E‖_F (values < {floor:g} drawn at {floor:g})")
        axes[1, 0].set_ylabel("max |P − P_exact|")

        ax = axes[1, 1]
        tp = res["throughput"]
        names = list(tp["methods"])
        rates = [tp["methods"][m]["traj_steps_per_s"] for m in names]
        labels = [m if m != "control" else "control:\nTsit5 ẏ=−y" for m in names]
        bars = ax.bar(labels, rates, color=[COLORS.get(m, "lightgray") for m in names])
        bars[-1].set_hatch("//")
        for b, m in zip(bars, names, strict=True):
            d = tp["methods"][m]
            ax.annotate(f"{d['traj_steps_per_s']:.2g}\ncompile {d['compile_s']:.1f} s",
                        (b.get_x() + b.get_width() / 2, b.get_height()), ha="center",
                        va="bottom", fontsize=8)  # fmt: skip
        ax.set_yscale("log")
        ax.set_ylabel("trajectory·steps per second (log)")
        ax.set_title(
            f"(d) Throughput: jit(vmap), B = {tp['batch']}, {tp['steps']} steps of {tp['dt']:g}"
        )
        ax.set_ylim(min(rates) / 3, max(rates) * 8)
        ax.tick_params(axis="x", labelsize=8)
        ax.grid(True, axis="y", which="both", alpha=0.3)
        m, v = res["machine"], res["machine"]["versions"]
        fig.suptitle(
            f"rigidjax Darboux benchmark: coning Ω = 2π rad/s, β = {BETA} rad, float64 — "
            f"{m['jax_backend']} ({m['cpu_count']} cores), jax {v['jax']}, diffrax {v['diffrax']}",
            fontsize=11,
        )


def main(argv=None) -> int:
    ap = parser(__doc__, None, quick="fewer tolerances, shorter drift, B=128", repeats=5)
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    cfg = QUICK if args.quick else FULL
    log = Log()
    ts_check = np.linspace(0.0, cfg["t_end"], cfg["n_save"])
    margin = euler_chart_margin(exact(ts_check))
    log(f"Euler chart {EULER_SEQ!r}: min |det J| along the coning motion = {margin:.4f}")
    log("1. work–precision")
    wp = work_precision(cfg, args.repeats, log)
    log("2. orthogonality drift")
    dr = drift(cfg, log)
    log("3. batched throughput")
    tp = throughput(cfg, max(1, min(args.repeats, 3)), log)
    parameters = dict(
        problem="coning P(t) = Rz(Ωt) Rx(β) Rz(−Ωt), space angular velocity",
        rate_rad_s=RATE, beta_rad=BETA, P0="exact(0) = Rx(β)", dtype="float64",
        euler_seq=EULER_SEQ, euler_chart_min_abs_det=margin,
        error_metric="err_max_abs: max over save times of max_ij |P - P_exact|; err_geodesic: "
        "max of rigidjax.so3.distance",
        rhs_count="exact, jax.debug.callback in the vector field (separate compilation)",
        wall_time="median (and min) of repeated solves of a callback-free jax.jit compilation",
        solvers="Tsit5 in StepEndMap for the kinematics classes; RKMK (Dopri5 tableau)",
        controller="diffrax.PIDController(rtol=tol, atol=tol), dt0=None",
        repeats=args.repeats, **cfg,
    )  # fmt: skip
    res = dict(
        benchmark="darboux",
        date=timestamp(),
        quick=args.quick,
        machine=dict(machine_info(), loadavg_at_start=log.load_start),
        parameters=parameters,
        work_precision=wp,
        drift=dr,
        throughput=tp,
    )
    res["total_s"] = log.elapsed()
    write_json(args.out_dir / "darboux.json", res)
    plot(res, args.out_dir / "darboux.png")
    log(f"wrote {args.out_dir / 'darboux.json'} and {args.out_dir / 'darboux.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
