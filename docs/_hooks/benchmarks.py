"""MkDocs hook: the benchmark results as tables.

At build time, reads `benchmarks/results/*.json` (written by the scripts in `benchmarks/`) and
replaces the marker `<!-- benchmark-tables -->` in `benchmarks.md` with one section per file:
the key rows with the throughputs, ratios and errors the file records, and the machine it ran
on. The result plots (`benchmarks/results/*.png`) are added to the site as `benchmarks/<name>`
without copying them into `docs/`.

Robust to missing fields (shown as "–"); a file whose layout is not recognised is shown by its
numeric `summary` entries, and a file that cannot be read is named with the reason. Numbers are
printed as recorded (3 significant digits), never computed here except unit scaling.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

MARKER = "<!-- benchmark-tables -->"
ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
log = logging.getLogger("mkdocs.hooks.benchmarks")


# ---------------------------------------------------------------- formatting helpers


def _num(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _g(x: object, digits: int = 3) -> str:
    """A number to 3 significant digits; '–' for missing, text as is."""
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "**no**"
    if isinstance(x, int) or (isinstance(x, float) and x.is_integer() and 1 <= abs(x) < 1e7):
        return str(int(x))
    if _num(x):
        r = float(f"{x:.{digits}g}")
        return f"{r:.0f}" if 1e3 <= abs(r) < 1e7 else f"{r:.{digits}g}"
    return str(x)


def _rate(x: object) -> str:
    """A per-second rate with an M (10⁶) or k (10³) suffix."""
    if not _num(x):
        return _g(x)
    if abs(x) >= 1e6:
        return f"{x / 1e6:.3g} M"
    if abs(x) >= 1e3:
        return f"{x / 1e3:.3g} k"
    return f"{x:.3g}"


def _ms(x: object) -> str:
    return _g(x * 1e3) if _num(x) else _g(x)


def _us(x: object) -> str:
    return _g(x * 1e6) if _num(x) else _g(x)


def _ratio(x: object) -> str:
    return f"{_g(x)}×" if _num(x) else _g(x)


def _bytes(x: object) -> str:
    if not _num(x):
        return _g(x)
    return f"{x / 1024:.3g} KiB" if x < 1024**2 else f"{x / 1024**2:.3g} MiB"


def _cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def _table(header: list[str], rows: Iterable[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _get(d: Any, *keys: str | int, default: Any = None) -> Any:
    for k in keys:
        if isinstance(d, dict) and k in d:
            d = d[k]
        elif isinstance(d, list) and isinstance(k, int) and -len(d) <= k < len(d):
            d = d[k]
        else:
            return default
    return d


def _obj(d: Any) -> dict:
    return d if isinstance(d, dict) else {}


def _list(d: Any) -> list:
    return d if isinstance(d, list) else []


def _dicts(d: Any) -> dict[str, dict]:
    return {k: v for k, v in d.items() if isinstance(v, dict)} if isinstance(d, dict) else {}


def _load(x: Any) -> str:
    return ", ".join(f"{v:.2f}" for v in x) if isinstance(x, list) and all(map(_num, x)) else "–"


def _machine(d: dict) -> str:
    m = _obj(d.get("machine"))
    versions = _obj(m.get("versions"))
    when = d.get("timestamp") or d.get("date") or "?"
    vs = ", ".join(f"{k} {v}" for k, v in versions.items())
    parts = [
        f"Measured {when} on {m.get('cpu_count', '?')} CPU cores ({m.get('platform', '?')}), "
        f"JAX backend `{m.get('jax_backend', '?')}`"
    ]
    if vs:
        parts.append(vs)
    commit = m.get("git_commit")
    if isinstance(commit, str) and commit:
        dirty = m.get("rigidjax_has_uncommitted_changes")
        parts.append(f"commit `{commit[:10]}`" + (" with uncommitted changes" if dirty else ""))
    start = d.get("load_average_start") or m.get("loadavg_at_start")
    end = d.get("load_average_end") or m.get("loadavg_at_record")
    if start or end:
        parts.append(f"load average (1/5/15 min) {_load(start)} at start, {_load(end)} at end")
    wall = d.get("total_wall_s", d.get("total_s"))
    if _num(wall):
        parts.append(f"whole run {wall:.0f} s")
    if d.get("quick"):
        parts.append("**quick run** (smaller sizes)")
    return "*" + "; ".join(parts) + ".*"


# ---------------------------------------------------------------- one renderer per file


def _rotations(d: dict) -> str:
    out = []
    n = d.get("n")
    if n is not None:
        out.append(
            f"N = {n} random rotations, best of {d.get('repeats', '?')} runs; rates in "
            "rotations per second (M = 10⁶), ratios > 1: rigidjax faster. "
            "Max |Δ|: largest difference from SciPy's float64 result."
        )
    jsp = _obj(d.get("jax_scipy_rotation"))
    if isinstance(jsp, dict) and jsp.get("available") is False:
        out.append(f"jax.scipy: {jsp.get('note', 'not available')}.")
    for dtype in ("float64", "float32"):
        rows = []
        for op, r in _dicts(d.get("ops")).items():
            t = r.get(dtype)
            if not isinstance(t, dict):
                continue
            ours, ref = _obj(t.get("rigidjax")), _obj(t.get("jax_scipy"))
            rows.append(
                [
                    f"`{op}`",
                    _rate(_get(ours, "rotations_per_s")),
                    _rate(_get(ref, "rotations_per_s")),
                    _rate(_get(r, "scipy", "rotations_per_s")),
                    _ratio(t.get("ratio_vs_scipy")),
                    _ratio(t.get("ratio_vs_jax_scipy")),
                    _g(_get(ours, "max_abs_diff_vs_scipy"), 2),
                    _g(_get(ours, "compile_s"), 2),
                ]
            )
        if rows:
            head = [
                f"operation ({dtype})",
                "rigidjax /s",
                "jax.scipy /s",
                "SciPy (f64) /s",
                "rigidjax ÷ SciPy",
                "rigidjax ÷ jax.scipy",
                "max \\|Δ\\| vs SciPy",
                "compile s",
            ]
            out.append(_table(head, rows))
    return "\n\n".join(out)


def _darboux(d: dict) -> str:
    out = []
    p = _obj(d.get("parameters"))
    if isinstance(p, dict) and p.get("problem"):
        out.append(
            f"Problem: {p['problem']} (rate {_g(p.get('rate_rad_s'))} rad/s, "
            f"β = {_g(p.get('beta_rad'))} rad), {p.get('dtype', '')}. "
            f"Solvers: {p.get('solvers', '–')}."
        )

    # Work-precision: PID tolerance sweep on [0, t_end].
    wp = _dicts(d.get("work_precision"))
    tols_all = sorted(
        {r["tol"] for m in wp.values() for r in _list(m.get("rows")) if _num(_get(r, "tol"))},
        reverse=True,
    )
    pick = [t for t in (1e-6, 1e-9, 1e-12) if t in tols_all] or tols_all[-1:]
    if wp and pick:
        rows = []
        for name, m in wp.items():
            by_tol = {r["tol"]: r for r in _list(m.get("rows")) if _num(_get(r, "tol"))}
            orth = [r.get("orthogonality_max") for r in by_tol.values()]
            orth = [x for x in orth if _num(x)]
            row = [f"`{name}`"]
            for t in pick:
                r = by_tol.get(t, {})
                row += [_g(r.get("rhs_evals")), _g(r.get("err_max_abs"), 2)]
            row.append(_g(max(orth), 2) if orth else "–")
            rows.append(row)
        head = ["method"]
        for t in pick:
            head += [f"RHS evals, tol {t:g}", f"max error, tol {t:g}"]
        head.append("max \\|PᵀP − E\\| (all tols)")
        out.append(
            f"**Work–precision** (t ∈ [0, {_g(p.get('t_end'))}], "
            "`PIDController(rtol = atol = tol)`; RHS evaluations counted, error = max over "
            "the save times of max |P − P_exact|):\n\n" + _table(head, rows)
        )

    # Long-time drift at a constant step.
    dr = _obj(d.get("drift"))
    methods = _dicts(_get(dr, "methods"))
    if methods:
        rows = [
            [
                f"`{name}`",
                str(m.get("solver", "–")),
                _g(m.get("num_steps")),
                _g(m.get("final_err_max_abs"), 2),
                _g(m.get("max_orthogonality"), 2),
                _g(m.get("run_s"), 2),
            ]
            for name, m in methods.items()
        ]
        head = ["method", "solver", "steps", "error at t end", "max \\|PᵀP − E\\|", "run s"]
        out.append(
            f"**Drift** (constant dt = {_g(dr.get('dt'))} to t = {_g(dr.get('t_end'))}):\n\n"
            + _table(head, rows)
        )

    # Batched throughput.
    tp = _obj(d.get("throughput"))
    methods = _dicts(_get(tp, "methods"))
    if methods:
        rows = [
            [
                f"`{name}`",
                _rate(m.get("traj_steps_per_s")),
                _ms(m.get("run_s_min")),
                _g(m.get("compile_s"), 2),
                _g(m.get("max_err_at_t_end"), 2),
            ]
            for name, m in methods.items()
        ]
        head = ["method", "trajectory-steps/s", "run ms (best)", "compile s", "error at t end"]
        note = (
            f"**Throughput** (`jit(vmap)`, batch {tp.get('batch', '?')}, {tp.get('steps', '?')} "
            f"fixed steps of {_g(tp.get('dt'))}):"
        )
        ctrl = tp.get("control")
        if isinstance(ctrl, str):
            ctrl = ctrl.removeprefix("control:").strip()
        table = _table(head, rows)
        out.append(note + "\n\n" + table + (f"\n\n`control` — {ctrl}" if ctrl else ""))
    return "\n\n".join(out)


def _dynamics(d: dict) -> str:
    out = []
    p = _obj(d.get("parameters"))
    if isinstance(p, dict) and p:
        keys = [k for k in ("B", "N", "dt", "T") if k in p]
        if keys:
            out.append("Parameters: " + ", ".join(f"{k} = {_g(p[k])}" for k in keys) + ".")
    rows = []
    for name, r in _dicts(d.get("results")).items():
        rows.append(
            [
                f"`{name}`",
                str(r.get("group", "–")),
                _rate(r.get("body_steps_per_s")),
                _us(r.get("seconds_per_trajectory")),
                _ratio(r.get("ratio_vs_lean")),
                _g(_get(r, "error_vs_reference", "max"), 2),
                _g(r.get("quat_norm_drift"), 2),
            ]
        )
    if rows:
        head = [
            "contender",
            "group",
            "body-steps/s",
            "µs per trajectory",
            "÷ lean kernel",
            "error at T",
            "\\|\\|q\\| − 1\\|",
        ]
        out.append(_table(head, rows))
        descr = [
            f"- `{name}`: {r['description']}"
            for name, r in _dicts(d.get("results")).items()
            if r.get("description")
        ]
        if descr:
            out.append(
                '??? note "What each contender is"\n\n' + "\n".join("    " + s for s in descr)
            )

    s = _obj(d.get("summary"))
    if isinstance(s, dict) and s:
        items = []
        if "ratio_rigidjax_rk4_vs_lean" in s:
            items.append(
                f"- `rigidjax_rk4` ÷ the lean kernel (`{s.get('lean_kernel', '?')}`): "
                f"**{_ratio(s['ratio_rigidjax_rk4_vs_lean'])}** "
                f"(by CPU time {_ratio(s.get('ratio_rigidjax_rk4_vs_lean_cpu_time'))})"
            )
        speedups = s.get("speedup_per_trajectory")
        for k, v in speedups.items() if isinstance(speedups, dict) else ():
            items.append(f"- speedup per trajectory, {k.replace('_vs_', ' vs ')}: {_ratio(v)}")
        if "rigidjax_best_at_equal_accuracy" in s:
            items.append(
                f"- fastest rigidjax configuration at equal accuracy: "
                f"`{s['rigidjax_best_at_equal_accuracy']}`, "
                f"{_ratio(s.get('rigidjax_best_speedup_vs_scipy_per_trajectory'))} SciPy "
                f"(`{s.get('scipy_reference_method', '?')}`) per trajectory"
            )
        labels = {
            "first_compile_s_fresh_process": "first compile (trace + lower + XLA), fresh process",
            "first_call_s_fresh_process": "first call (compile + first run), fresh process",
        }
        for k, label in labels.items():
            if k in s:
                items.append(f"- {label}: {_g(s[k])} s")
        if items:
            out.append("**Summary**\n\n" + "\n".join(items))

    targets = _dicts(d.get("targets"))
    if targets:
        rows = [
            [f"`{k}`", _g(t.get("target")), _g(t.get("value")), _g(t.get("passed"))]
            for k, t in targets.items()
        ]
        out.append("**Targets**\n\n" + _table(["target", "goal", "measured", "met"], rows))
    return "\n\n".join(out)


def _identify(d: dict) -> str:
    out = []
    ident = _dicts(d.get("identify"))
    if ident:
        rows = []
        for T, r in ident.items():
            calls = [c for c in _list(r.get("calls")) if isinstance(c, dict)]
            errs = [c.get("max_abs_error_rel_trace") for c in calls]
            errs = [e for e in errs if _num(e)]
            conv = [c.get("converged") for c in calls]
            rows.append(
                [
                    str(T),
                    _g(r.get("first_call_s")),
                    _g(r.get("repeat_call_s_min")),
                    f"{sum(bool(c) for c in conv)}/{len(conv)}" if conv else "–",
                    _g(max(errs), 2) if errs else "–",
                    _g(_get(calls, 0, "max_inertia_std"), 2),
                ]
            )
        head = [
            "samples T",
            "first call s (incl. compile)",
            "repeat call s (best)",
            "converged",
            "max rel. tensor error",
            "max std (first call)",
        ]
        out.append(
            "**Identification** (`identify_inertia` on noisy gyro data):\n\n" + _table(head, rows)
        )

    grad = _dicts(d.get("grad"))
    if grad:
        rows = []
        for N, g in grad.items():
            for cfg, c in _dicts(g.get("configs")).items():
                rows.append(
                    [
                        str(N),
                        f"`{cfg}`",
                        _g(c.get("checkpoints")),
                        _ms(c.get("forward_s")),
                        _ms(c.get("grad_s")),
                        _ratio(c.get("grad_over_forward")),
                        _ratio(c.get("grad_over_forward_cpu")),
                        _bytes(_get(c, "grad_memory", "temp_size_in_bytes")),
                    ]
                )
        head = [
            "steps N",
            "adjoint",
            "checkpoints",
            "forward ms",
            "gradient ms",
            "grad ÷ fwd (wall)",
            "grad ÷ fwd (CPU)",
            "gradient temp memory",
        ]
        checks = [
            f"N = {N}: gradient vs central finite differences "
            f"{_g(g.get('grad_check_max_abs_diff_vs_central_fd_rel'), 2)} (relative), "
            f"adjoints agree to {_g(g.get('grad_consistency_across_configs'), 2)}"
            for N, g in grad.items()
        ]
        out.append(
            "**Gradient cost** (`jax.grad` of a loss of `simulate` with fixed-step RK4, "
            "reverse mode):\n\n" + _table(head, rows) + "\n\n" + "; ".join(checks) + "."
        )
    return "\n\n".join(out)


def _checks(d: dict) -> str:
    head = ["bodies B", "steps N", "validated", "traced", "host checks", "in-loop checks"]
    rows = [
        [
            _g(r.get("B")),
            _g(r.get("N")),
            _ms(_get(r, "validated", "seconds")),
            _ms(_get(r, "traced", "seconds")),
            f"{_ms(_get(r, 'checks', 'seconds'))} ({_ratio(r.get('checks_share'))})",
            f"{_ms(_get(r, 'loop_check', 'seconds'))} ({_ratio(r.get('loop_check_share'))})",
        ]
        for r in _list(d.get("results"))
    ]
    return (
        "Cost of the input checks of `simulate` (RK4, an output at every step): the eager, "
        "validated call; the same program compiled with `jax.jit` (no host checks); the host "
        "checks alone and the driver's in-loop finiteness checks alone, with their share of the "
        "call.\n\n" + _table(head, rows)
    )


def _sweep(d: dict) -> str:
    par = d.get("parameters", {})
    raw = [[_g(r.get("B")), _g(r.get("body_steps_per_s"))] for r in _list(d.get("raw"))]
    sweeps = [
        [
            _g(r.get("points")),
            _g(r.get("chunk")),
            _g(r.get("body_steps_per_s")),
            _ratio(r.get("ratio_to_raw")),
        ]
        for r in _list(d.get("sweep"))
    ]
    devices = [
        [_g(r.get("num_devices")), _g(r.get("body_steps_per_s"))] for r in _list(d.get("devices"))
    ]
    memory = [
        [
            _g(r.get("points")),
            _bytes(r.get("peak_rss_bytes")),
            _g(r.get("seconds")),
            _g(r.get("body_steps_per_s")),
        ]
        for r in _list(d.get("memory"))
    ]
    return "\n\n".join(
        [
            f"`sweep.run` against one batched `simulate` (the whole batch as one state), "
            f"{_g(par.get('steps'))} steps of {par.get('solver', '–')}, outputs at the end "
            "only; times exclude compiling.",
            "**Raw batched simulate** (the baseline is the best batch):\n\n"
            + _table(["bodies B", "body-steps/s"], raw),
            "**Sweep** (in memory):\n\n"
            + _table(["points", "chunk", "body-steps/s", "÷ best raw"], sweeps),
            "**Virtual CPU devices** (`--xla_force_host_platform_device_count`):\n\n"
            + _table(["devices", "body-steps/s"], devices),
            f"**Memory** (a Zarr store; peak RSS, largest sweep ÷ smallest "
            f"{_ratio(d.get('memory_ratio'))} for {_g(d.get('memory_ratio_points'))}× the "
            "points):\n\n"
            + _table(["points", "peak RSS", "seconds (no compiling)", "body-steps/s"], memory),
        ]
    )


def _models(d: dict) -> str:
    sp, prob = _obj(d.get("speed")), _obj(d.get("problem"))
    speed = [
        [
            name.replace("_", " "),
            _g(r.get("rigidjax_body_steps_per_s")),
            _g(r.get("c_body_steps_per_s")),
            _ratio(r.get("ratio_rigidjax_over_c")),
            _g(r.get("max_abs_difference")),
        ]
        for name, r in _dicts(sp.get("models")).items()
    ]
    slow = [
        [name.replace("_", " "), _g(r.get("body_steps_per_s")), _ratio(r.get("vs_fast_path"))]
        for name, r in _dicts(sp.get("diffrax_path")).items()
    ]
    grads = [
        [name.replace("_", " "), str(r.get("wrt", "–")), _ratio(r.get("ratio"))]
        for name, r in _dicts(d.get("gradient")).items()
    ]
    first = [
        [
            label.replace("_", " "),
            name.replace("_", " "),
            _g(r.get("forward_s")),
            _g(r.get("gradient_s")),
        ]
        for label, runs in _dicts(d.get("first_calls")).items()
        for name, r in _dicts(runs).items()
    ]
    return "\n\n".join(
        [
            f"Each model at {_g(prob.get('bodies'))} bodies × {_g(prob.get('steps'))} RK4 steps "
            "(float64) on rigidjax's fast path (the CPU kernel written from the JAX field) and "
            "as a hand-written C kernel of the same model (`benchmarks/reference/models.c`), "
            "timed in interleaved rounds; the last column is the largest difference of their "
            "final states.",
            _table(
                ["model", "rigidjax body-steps/s", "C body-steps/s", "rigidjax ÷ C", "max |Δ|"],
                speed,
            ),
            "**The Diffrax path** on the same steps (`ExplicitRK(RK4())`: what adaptive and "
            "implicit solvers use):\n\n" + _table(["model", "body-steps/s", "÷ fast path"], slow),
            "**Gradients** (`jax.value_and_grad` of a loss of the final states, over the forward "
            "run):\n\n" + _table(["model", "with respect to", "÷ forward"], grads),
            "**First calls** in a fresh process (trace, kernel build, compile, run; 1000 bodies), "
            "with empty caches and again with the caches of the first process:\n\n"
            + _table(["caches", "model", "forward s", "gradient s"], first),
        ]
    )


def _gpu(d: dict) -> str:
    sp, prob = _obj(d.get("speed")), _obj(d.get("problem"))
    rows = [
        [
            name.replace("_", " "),
            _g(r.get("pallas_body_steps_per_s")),
            _g(r.get("cuda_body_steps_per_s")),
            _ratio(r.get("ratio_pallas_over_cuda")),
            _g(r.get("diffrax_body_steps_per_s")),
            _ratio(r.get("pallas_over_diffrax")),
            _g(r.get("max_abs_difference_cuda")),
        ]
        for name, r in _dicts(sp.get("models")).items()
    ]
    grads = [
        [
            name.replace("_", " "),
            _ratio(r.get("ratio")),
            _ratio(r.get("diffrax_ratio")),
            _g(r.get("max_rel_difference_diffrax")),
        ]
        for name, r in _dicts(d.get("gradient")).items()
    ]
    first = _obj(d.get("first_call"))
    return "\n\n".join(
        [
            f"Each model at {_g(prob.get('bodies'))} bodies × {_g(prob.get('steps'))} RK4 steps "
            "(float64) on a GPU: rigidjax's Pallas kernel (the JAX field evaluated on register "
            "vectors), a hand-written CUDA kernel of the same model (one body per thread, "
            "`benchmarks/reference/models.cu`) and the Diffrax path (XLA's loop over the whole "
            "batch), in interleaved rounds; the last column is the largest difference of the "
            "Pallas and CUDA final states.",
            _table(
                [
                    "model",
                    "Pallas body-steps/s",
                    "CUDA body-steps/s",
                    "Pallas ÷ CUDA",
                    "Diffrax body-steps/s",
                    "Pallas ÷ Diffrax",
                    "max |Δ|",
                ],
                rows,
            ),
            "**Gradients** (value and gradient over the forward run): the Pallas kernel's own "
            "reverse mode, and the same steps through Diffrax, with the largest relative "
            "difference of the two gradients:\n\n"
            + _table(["model", "÷ forward", "through Diffrax ÷ forward", "max rel. |Δ|"], grads),
            f"**First call** of a new torque model (1000 bodies, trace, check, compile, run): "
            f"{_g(first.get('first_forward_s'))} s.",
        ]
    )


def _first_call(d: dict) -> str:
    head = ["map", "jaxlie counterpart"]
    for k in ("value", "jacfwd", "jacrev"):
        head += [f"{k} rigidjax", f"{k} jaxlie"]
    rows = []
    for r in _list(d.get("results")):
        row = [f"`{r.get('map')}`", f"`{r.get('jaxlie')}`"]
        for k in ("value", "jacfwd", "jacrev"):
            row += [_ms(_get(r, k, "rigidjax_seconds")), _ms(_get(r, k, "jaxlie_seconds"))]
        rows.append(row)
    return (
        "First call of each rotation map, eager, and of its eager `jax.jacfwd`/`jax.jacrev`, "
        "each in a fresh process after JAX has started (float64, a half-turn), against jaxlie "
        "measured in the same run; best of the rounds.\n\n" + _table(head, rows)
    )


def _generic(d: dict) -> str:
    s = d.get("summary")
    items = s.items() if isinstance(s, dict) else ()
    rows = [[k.replace("_", " "), _g(v)] for k, v in items if _num(v)]
    return _table(["quantity", "value"], rows) if rows else "No summary table recorded."


SECTIONS: dict[str, tuple[str, Callable[[dict], str]]] = {
    "rotations.json": ("Rotation maps vs SciPy and jax.scipy", _rotations),
    "darboux.json": ("The Darboux problem: work–precision, drift, throughput", _darboux),
    "dynamics.json": ("Batched free-body dynamics", _dynamics),
    "identify.json": ("Inertia identification and gradient cost", _identify),
    "identify_long.json": ("Inertia identification from long records", _generic),
    "checks.json": ("What the input checks cost", _checks),
    "sweep.json": ("Sweeps: throughput, devices, memory", _sweep),
    "kernel.json": ("The CPU kernels against hand-written C, 1e3 to 1e7 bodies", _generic),
    "models.json": ("Every model at kernel speed: torques, tops, 6-DOF bodies against C", _models),
    "gpu.json": ("Every model on a GPU: the Pallas kernel against CUDA and Diffrax", _gpu),
    "first_call.json": ("First calls of the rotation maps vs jaxlie", _first_call),
}


def _section(path: Path) -> str:
    title, fn = SECTIONS.get(path.name, (path.stem.replace("_", " ").capitalize(), _generic))
    head = f"## {title}\n\n`benchmarks/results/{path.name}`"
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        return f"{head}: could not be read ({type(e).__name__}: {e})."
    if not isinstance(d, dict):
        return f"{head}: not a JSON object."
    try:
        body = fn(d)
    except Exception as e:  # noqa: BLE001 - an unexpected layout must not break the site
        log.info("benchmarks hook: %s: layout not recognised (%r); showing summary", path.name, e)
        body = _generic(d)
    png = path.with_suffix(".png")
    if png.exists():
        body += f"\n\n![{path.stem} results](benchmarks/results/{png.name})"
    return f"{head}\n\n{body}\n\n{_machine(d)}"


def render() -> str:
    if not RESULTS.is_dir():
        return "No results yet: `benchmarks/results/` does not exist."
    order = list(SECTIONS)
    paths = sorted(
        RESULTS.glob("*.json"),
        key=lambda p: (order.index(p.name) if p.name in order else len(order), p.name),
    )
    return "\n\n".join(_section(p) for p in paths) or "No results yet in `benchmarks/results/`."


# ---------------------------------------------------------------- MkDocs events


def on_files(files: Files, config, **kwargs) -> Files:
    """Serve the result plots as `benchmarks/results/<name>.png` (no copy in docs/)."""
    if RESULTS.is_dir():
        for png in sorted(RESULTS.glob("*.png")):
            files.append(
                File.generated(config, f"benchmarks/results/{png.name}", abs_src_path=str(png))
            )
    return files


def on_page_markdown(markdown: str, **kwargs) -> str:
    return markdown.replace(MARKER, render()) if MARKER in markdown else markdown
