"""MkDocs hook: render the committed benchmark results (benchmarks/results/*.json) as tables in
benchmarks.md, replacing the marker `<!-- benchmark-tables -->`."""

from __future__ import annotations

import json
from pathlib import Path

MARKER = "<!-- benchmark-tables -->"
RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"


def _g(x: float | None) -> str:
    return "–" if x is None else f"{x:.3g}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _machine(d: dict) -> str:
    m = d.get("machine", {})
    versions = m.get("versions", {})
    when = d.get("timestamp") or d.get("date") or "?"
    vs = ", ".join(f"{k} {v}" for k, v in versions.items())
    return (
        f"*Measured {when} on {m.get('cpu_count', '?')} CPU cores ({m.get('platform', '?')}), "
        f"JAX backend {m.get('jax_backend', '?')}; {vs}.*"
    )


def _rotations(d: dict) -> str:
    rows = []
    for op, r in d["ops"].items():
        f64 = r.get("float64", {})
        ours = f64.get("rigidjax", {})
        jsp = f64.get("jax_scipy", {})
        scipy = r.get("scipy", {})
        rate, ref = ours.get("rotations_per_s"), scipy.get("rotations_per_s")
        rows.append(
            [
                f"`{op}`",
                _g(rate),
                _g(ref),
                _g(rate / ref) if rate and ref else "–",
                _g(rate / jsp["rotations_per_s"]) if rate and jsp.get("rotations_per_s") else "–",
                _g(ours.get("max_abs_diff_vs_scipy")),
            ]
        )
    head = ["operation (float64)", "rigidjax rot/s", "SciPy rot/s", "× SciPy", "× jax.scipy"]
    return _table([*head, "max diff vs SciPy"], rows)


def _dynamics(d: dict) -> str:
    rows = [
        [f"`{name}`", r.get("description", ""), _g(r.get("body_steps_per_s"))]
        for name, r in d["results"].items()
    ]
    s = d.get("summary", {})
    sp = s.get("speedup_per_trajectory", {})
    extra = [
        f"- rigidjax RK4 / lean `lax.scan` kernel: **{_g(s.get('ratio_rigidjax_rk4_vs_lean'))}×**",
        *(f"- {k.replace('_', ' ')}: **{_g(v)}×**" for k, v in sp.items()),
    ]
    table = _table(["configuration", "what", "body-steps/s"], rows)
    return table + "\n\n" + "\n".join(extra)


def _darboux(d: dict) -> str:
    tp = d["throughput"]
    rows = [
        [
            f"`{name}`",
            _g(m.get("traj_steps_per_s")),
            _g(m.get("compile_s")),
            _g(m.get("max_err_at_t_end")),
        ]
        for name, m in tp["methods"].items()
    ]
    head = ["method", "trajectory-steps/s", "compile s", "error at t end"]
    note = f"Batch {tp.get('batch')}, {tp.get('steps')} fixed steps of {tp.get('dt')}."
    return note + "\n\n" + _table(head, rows)


def _identify(d: dict) -> str:
    rows = [[k.replace("_", " "), _g(v)] for k, v in d["summary"].items() if _num(v)]
    return _table(["quantity", "value"], rows)


def _num(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


SECTIONS = {
    "rotations.json": ("Rotation maps vs SciPy and jax.scipy", _rotations),
    "darboux.json": ("The Darboux problem: batched throughput", _darboux),
    "dynamics.json": ("Batched free-body dynamics", _dynamics),
    "identify.json": ("Identification and gradients", _identify),
}


def render() -> str:
    out = []
    for name, (title, fn) in SECTIONS.items():
        path = RESULTS / name
        if not path.exists():
            out.append(f"## {title}\n\n`benchmarks/results/{name}` has not been produced yet.")
            continue
        d = json.loads(path.read_text())
        out.append(f"## {title}\n\n{fn(d)}\n\n{_machine(d)}")
    return "\n\n".join(out)


def on_page_markdown(markdown: str, **kwargs) -> str:
    return markdown.replace(MARKER, render()) if MARKER in markdown else markdown
