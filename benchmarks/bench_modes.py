"""What derivatives cost on each path, in both modes (issue 34): the value, the reverse-mode
gradient (`jax.grad`) and the forward-mode Jacobian (`jax.jacfwd`) of one loss, on the CPU kernel
(fixed RK4 steps), on the Diffrax path (the default adaptive tolerances), and with an event,
whose derivatives run on the Diffrax path (one body's solve, mapped over the bodies), with
default options.

Problem: B bodies, principal moments (1.5, 2, 2.5) ± 10 %, Ω0 ~ N(0, 1)³, random unit
quaternions, a damping torque `−g Ω` with a closed-over gain g, t ∈ [0, 2], 5 output times;
RK4 at dt = 1e-2 on the kernel (B = 1000), rtol = atol = 1e-8 on the Diffrax path
(B = 100); with the event, a gravity-gradient torque instead, rtol = atol = 1e-8 (B = 16).
Loss: the sum of squares of the final rates. Gradient w.r.t. (moments (B, 3), g);
Jacobian of the final rates w.r.t. g (forward mode: one tangent).

`--baseline DIR` runs the same measurements on another checkout of rigidjax (e.g. a `git
worktree` of the last release) in a fresh process, in the same run: its times are
the baseline of `value_vs_baseline`, `grad_vs_baseline` and `jacfwd_vs_baseline`.

Usage
    python benchmarks/bench_modes.py [--repeats 5] [--baseline DIR]
        [--out benchmarks/results/modes.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import diffrax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _harness import (  # noqa: E402
    finish,
    fresh_process,
    interleaved,
    load_average,
    machine_info,
    measure,
    parser,  # noqa: E402
)

import rigidjax as rj  # noqa: E402

TS = jnp.linspace(0.0, 2.0, 5)
E_Z = jnp.array([0.0, 0.0, 1.0])
PATHS = {
    "kernel": (
        1000,
        dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=1e-2),
    ),
    "diffrax": (100, dict(rtol=1e-8, atol=1e-8)),
    # a gravity-gradient torque and a terminating event (Ω1 = 0): the adaptive kernel runs the
    # value, the Diffrax path (one body's solve, mapped) both derivatives
    "event": (16, dict(rtol=1e-8, atol=1e-8, event=rj.Event(lambda t, w, q: w[0]))),
}


def _torque(path: str, g):
    """The damping torque −g Ω, or (the events' path) g times the gravity-gradient torque
    c × (I c), c = P(q)ᵀ e_Z, with the inertia of a body of moments (1.5, 2, 2.5)."""
    if path != "event":
        return lambda t, w, q: -g * w
    moments = jnp.array([1.5, 2.0, 2.5])
    return lambda t, w, q: (
        g
        * jnp.cross(
            rj.quat.rotate(rj.quat.conj(q), E_Z), moments * rj.quat.rotate(rj.quat.conj(q), E_Z)
        )
    )


def _problem(B: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    moments = jnp.asarray(np.array([1.5, 2.0, 2.5]) * rng.uniform(0.9, 1.1, (B, 3)))
    q = rng.normal(size=(B, 4))
    return (
        moments,
        jnp.asarray(rng.normal(size=(B, 3))),
        jnp.asarray(q / np.linalg.norm(q, axis=1)[:, None]),
    )


def _measure(repeats: int, forward_mode: bool) -> dict:
    out = {}
    for path, (B, kw) in PATHS.items():
        moments, w0, q0 = _problem(B)

        def rates(moments, g, w0=w0, q0=q0, kw=kw, path=path):
            torque = _torque(path, g)
            return rj.simulate(rj.RigidBody(moments), w0, q0, TS, torque=torque, **kw).omega[:, -1]

        def loss(moments, g, rates=rates):
            return jnp.sum(rates(moments, g) ** 2)

        g = jnp.asarray(0.1)
        timings = {
            "value": measure(loss, moments, g, repeats=1),
            "grad": measure(jax.grad(loss, argnums=(0, 1)), moments, g, repeats=1),
        }
        if forward_mode:
            timings["jacfwd"] = measure(jax.jacfwd(rates, argnums=1), moments, g, repeats=1)
        interleaved(timings.values(), repeats)
        row = {"bodies": B, **{k: t.summary() for k, t in timings.items()}}
        for k, t in timings.items():
            row[k]["compile_s"] = t.trace_lower_compile_s
        if forward_mode:
            jr = jax.jacrev(rates, argnums=1)(moments, g)
            row["jacfwd_vs_jacrev_max_abs"] = float(jnp.max(jnp.abs(timings["jacfwd"].output - jr)))
        row["grad_per_value"] = timings["grad"].best / timings["value"].best
        out[path] = row
    return out


def main() -> None:
    ap = parser(__doc__, "modes.json", repeats=5)
    ap.add_argument("--baseline", type=Path, default=None, help="another checkout of rigidjax")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:  # the baseline checkout
        print(json.dumps(_measure(args.repeats, forward_mode=True)))
        return
    t0 = time.perf_counter()
    out: dict = {"machine": machine_info(), "load_average_start": load_average()}
    out["paths"] = _measure(args.repeats, forward_mode=True)
    if args.baseline is not None:
        env = {**os.environ, "PYTHONPATH": str(args.baseline.resolve())}
        base, _, proc = fresh_process(__file__, "--worker", "--repeats", str(args.repeats), env=env)
        if base is None:
            raise SystemExit(f"the baseline run failed:\n{proc.stderr[-2000:]}")
        out["baseline"] = {"checkout": str(args.baseline), "paths": base}
        for path, row in out["paths"].items():
            for k in ("value", "grad", "jacfwd"):
                row[f"{k}_vs_baseline"] = row[k]["seconds"] / base[path][k]["seconds"]
    for path, row in out["paths"].items():
        line = ", ".join(
            f"{k} {row[k]['seconds'] * 1e3:.1f} ms" for k in ("value", "grad", "jacfwd")
        )
        extra = "".join(
            f", {k}_vs_baseline {row[f'{k}_vs_baseline']:.3g}x"
            for k in ("value", "grad", "jacfwd")
            if f"{k}_vs_baseline" in row
        )
        print(f"{path} ({row['bodies']} bodies): {line}{extra}")
    finish(out, args.out, t0)


if __name__ == "__main__":
    main()
