"""`rigidjax simulate` (also `rigidjax` with no command): simulate a free rigid body and write
its trajectory (npz, CSV) and a plot.

The defaults are the tennis-racket (Dzhanibekov) flip: a body with I = (1, 2, 3) spun about its
middle axis with a small perturbation, which flips periodically (Zegrya–Parshin 004: rotation
about the middle axis is unstable).

The time span is integrated in equal segments by one compiled program, so the progress bar is
updated between segments from Python: the program has no host callbacks (the inputs are
checked eagerly first), and JAX's persistent compilation cache can store it.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._common import (
    UsageError,
    check_positive,
    check_tolerance,
    checked,
    checks_as_nan,
    print_written,
    pyplot,
    save_figure,
    write_results,
)

DEFAULTS = dict(
    inertia=(1.0, 2.0, 3.0),
    omega0=(0.01, 1.0, 0.01),
    q0=(1.0, 0.0, 0.0, 0.0),
    t_end=60.0,
    num=3001,
    kinematics="quat",
)
MAX_STEPS = 1_000_000  # per output interval
SEGMENTS = 50  # progress updates per run (at most one per output interval)
# simulated time done/total, rounded (sums of segment lengths: 40.800000000000004 → 40.8)
BAR_FORMAT = "{l_bar}{bar}| {n:.6g}/{total:.6g} {unit} [{elapsed}<{remaining}]"


def add_arguments(p: argparse.ArgumentParser) -> None:
    vectors = (
        ("--inertia", ("I1", "I2", "I3"), "principal moments of inertia"),
        ("--omega0", ("W1", "W2", "W3"), "initial body angular velocity [rad/s]"),
        ("--q0", ("W", "X", "Y", "Z"), "initial attitude quaternion, scalar first"),
    )
    for flag, names, text in vectors:
        key = flag.removeprefix("--")
        p.add_argument(
            flag, type=float, nargs=len(names), metavar=names, default=DEFAULTS[key], help=text
        )
    p.add_argument("--t-end", type=float, default=DEFAULTS["t_end"], help="time span [s]")
    p.add_argument("--num", type=int, default=DEFAULTS["num"], help="number of output times")
    p.add_argument(
        "--kinematics",
        default=DEFAULTS["kinematics"],
        choices=["quat", "rotvec", "matrix", "euler", "cayley_klein", "geometric"],
    )
    p.add_argument("--rtol", type=float, default=None, help="relative tolerance")
    p.add_argument("--atol", type=float, default=None, help="absolute tolerance")
    p.add_argument("--float32", action="store_true", help="single precision (default: float64)")
    p.add_argument("--out", type=Path, default=Path("rigidjax_out"), help="output folder")


def check_options(args: argparse.Namespace) -> None:
    """Raise UsageError for option values that are wrong whatever the body."""
    if args.num < 2:
        raise UsageError(f"--num must be at least 2 (output times), got {args.num}")
    if not (math.isfinite(args.t_end) and args.t_end > 0):
        raise UsageError(f"--t-end must be a positive, finite time span [s], got {args.t_end}")
    check_positive(args, "rtol", "atol")
    for name in ("rtol", "atol"):
        check_tolerance(f"--{name}", getattr(args, name), float32=args.float32)


@dataclass(frozen=True)
class _Inputs:
    """The validated arguments of `simulate`, and the segmentation of the output times."""

    body: Any  # RigidBody (imported with JAX)
    omega0: Any
    q0: Any
    ts: np.ndarray  # the output times, (num,)
    segment: Any  # the output times of one segment, starting at 0, (per_segment + 1,)
    num_segments: int
    options: Any  # SolveOptions


def _inputs(args: argparse.Namespace) -> _Inputs:
    """Build and validate the simulation's inputs, eagerly, with the library's own checks."""
    import jax.numpy as jnp

    from .._checks import check_finite, check_times, check_unit_norm, vector
    from .._integrate import SolveOptions
    from ..mechanics.body import RigidBody

    dtype = jnp.float32 if args.float32 else jnp.float64
    unit = "; give a unit quaternion (divide it by its norm)"
    intervals = args.num - 1
    num_segments = min(SEGMENTS, intervals)
    per = -(-intervals // num_segments)  # output intervals per segment (the last padded)
    h = args.t_end / intervals
    ts = checked(
        "--t-end/--num",
        lambda: np.asarray(check_times(jnp.linspace(0.0, args.t_end, args.num, dtype=dtype))),
    )
    return _Inputs(
        body=checked("--inertia", lambda: RigidBody(jnp.asarray(args.inertia, dtype))),
        omega0=checked(
            "--omega0",
            lambda: check_finite(vector(jnp.asarray(args.omega0, dtype), 3, "omega0"), "omega0"),
        ),
        q0=checked(
            "--q0",
            lambda: check_unit_norm(vector(jnp.asarray(args.q0, dtype), 4, "q0"), "q0", unit),
        ),
        ts=ts,
        segment=jnp.arange(per + 1, dtype=dtype) * h,
        num_segments=num_segments,
        options=checked(
            "--rtol/--atol",
            lambda: SolveOptions(
                rtol=args.rtol,
                atol=args.atol,
                max_steps=MAX_STEPS,
                throw=False,  # a failed solve is reported below, not raised from compiled code
            ),
        ),
    )


def _segment(body: Any, omega0: Any, q0: Any, t0: Any, segment: Any, *, kinematics, options):
    """One segment `t0 + segment`, to be compiled once (the inputs were checked eagerly)."""
    from ..mechanics.dynamics import simulate

    traj = simulate(
        body, omega0, q0, t0 + segment, kinematics=kinematics, options=options, check=False
    )
    return traj.omega, traj.quat, traj.stats["num_steps"], traj.result


def _failure(result: Any) -> str | None:
    """The message of a failed solve's `result`, or None if it succeeded."""
    import diffrax

    if bool(result == diffrax.RESULTS.successful):
        return None
    return diffrax.RESULTS[result] or "the solver failed"


def _compile_and_run(args: argparse.Namespace, x: _Inputs) -> tuple[dict, dict]:
    """Trace and compile one segment ahead of time, then run the segments one after the other:
    `(outputs, seconds of tracing, compiling and running)`. A failed segment stops the run
    (`outputs["failure"]` names the cause and the time)."""
    import jax
    from tqdm.auto import tqdm

    f = functools.partial(_segment, kinematics=args.kinematics, options=x.options)
    times = {}
    start = time.perf_counter()
    zero = jax.numpy.zeros((), x.segment.dtype)
    with checks_as_nan():  # the inputs were checked: no host callbacks, a cacheable program
        lowered = jax.jit(f).lower(x.body, x.omega0, x.q0, zero, x.segment)
    times["trace_time_s"] = time.perf_counter() - start
    start = time.perf_counter()
    compiled = lowered.compile()
    times["compile_time_s"] = time.perf_counter() - start
    start = time.perf_counter()
    h = float(x.segment[1])
    per = x.segment.shape[0] - 1
    omegas, quats, steps, failure = [x.omega0[None]], [x.q0[None]], 0, None
    omega, q = x.omega0, x.q0
    with tqdm(
        total=float(x.ts[-1]),
        unit="s",
        desc="simulate",
        bar_format=BAR_FORMAT,
        disable=args.no_progress,
        file=sys.stderr,
    ) as bar:
        for k in range(x.num_segments):
            t0 = jax.numpy.asarray(k * per * h, x.segment.dtype)
            w_seg, q_seg, n, result = compiled(x.body, omega, q, t0, x.segment)
            message = _failure(result)
            if message is not None:
                failure = f"{message} (in the segment from t = {float(t0):g} s)"
                break
            omegas.append(w_seg[1:])
            quats.append(q_seg[1:])
            steps += int(n)
            omega, q = w_seg[-1], q_seg[-1]
            bar.update(min(float(x.ts[-1]), float(t0) + per * h) - bar.n)
    num = x.ts.shape[0]
    out = {
        "omega": np.concatenate([np.asarray(w) for w in omegas])[:num],
        "quat": np.concatenate([np.asarray(v) for v in quats])[:num],
        "num_steps": steps,
        "failure": failure,
    }
    times["run_time_s"] = time.perf_counter() - start
    return out, times


def _derived(body: Any, omega: np.ndarray, q: np.ndarray) -> dict[str, np.ndarray]:
    """The rotation matrices, energy, |M| and body axis 2 in space along the trajectory."""
    import jax.numpy as jnp

    from ..mechanics.invariants import energy, momentum_squared
    from ..rotations import quat

    w, qq = jnp.asarray(omega), jnp.asarray(q)
    return {
        "matrix": np.asarray(quat.to_matrix(qq)),
        "energy": np.asarray(energy(body, w)),
        "momentum_norm": np.sqrt(np.asarray(momentum_squared(body, w))),
        "axis2": np.asarray(quat.rotate(qq, jnp.array([0.0, 1.0, 0.0], qq.dtype))),
    }


def _plot(path: str, ts, omega, energy_drift, momentum_drift, axis_space, inertia) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for k in range(3):
        ax[0].plot(ts, omega[:, k], label=f"Ω{k + 1}")
    ax[0].set_ylabel("body angular velocity [rad/s]")
    ax[0].legend(loc="upper right")
    ax[0].set_title(f"Free rigid body, I = {tuple(float(i) for i in inertia)}")
    ax[1].semilogy(ts, np.maximum(np.abs(energy_drift), 1e-18), label="|T/T(0) − 1|")
    ax[1].semilogy(ts, np.maximum(np.abs(momentum_drift), 1e-18), label="||M|/|M(0)| − 1|")
    ax[1].set_ylabel("relative drift")
    ax[1].legend(loc="lower right")
    for k, name in enumerate("XYZ"):
        ax[2].plot(ts, axis_space[:, k], label=f"{name}")
    ax[2].set_ylabel("body axis 2 in space")
    ax[2].set_xlabel("t [s]")
    ax[2].legend(loc="upper right")
    save_figure(fig, path)


def _write(args: argparse.Namespace, x: _Inputs, r: dict, times: dict) -> dict[str, Path]:
    """Write trajectory.{npz,csv[,png]} in `args.out`; returns the paths by kind."""
    ts, omega, q = x.ts, r["omega"], r["quat"]
    d = _derived(x.body, omega, q)
    T, Mn = d["energy"], d["momentum_norm"]
    table = np.column_stack([ts, omega, q, T, Mn])
    header = "t,omega1,omega2,omega3,q_w,q_x,q_y,q_z,energy,momentum_norm"
    drifts = (T / T[0] - 1, Mn / Mn[0] - 1)
    paths = write_results(
        args.out,
        "trajectory",
        {
            "npz": lambda f: np.savez(
                open(f, "wb"),  # noqa: SIM115 - np.savez closes nothing it did not open
                ts=ts,
                omega=omega,
                quat=q,
                matrix=d["matrix"],
                energy=T,
                momentum_norm=Mn,
                inertia=np.asarray(x.body.inertia),
                kinematics=args.kinematics,
                num_steps=np.asarray(r["num_steps"]),
                **times,
            ),
            "csv": lambda f: np.savetxt(f, table, delimiter=",", header=header, comments=""),
        },
        lambda f: _plot(f, ts, omega, *drifts, d["axis2"], args.inertia),
    )
    r["drift"] = tuple(np.max(np.abs(drift)) for drift in drifts)
    return paths


def _summary(args: argparse.Namespace, r: dict, times: dict, paths: dict[str, Path]) -> None:
    """Print what was simulated, how long tracing, compiling and running took, and the files."""
    precision = "float32" if args.float32 else "float64"
    print(
        f"simulated {args.t_end:g} s ({r['num_steps']} steps, {args.kinematics}, {precision}): "
        f"trace {times['trace_time_s']:.3g} s, compile {times['compile_time_s']:.3g} s, "
        f"run {times['run_time_s']:.3g} s"
    )
    print(f"max relative drift: energy {r['drift'][0]:.2e}, |M| {r['drift'][1]:.2e}")
    print_written(paths)


def run(args: argparse.Namespace) -> int:
    """The command: check, compile, run, write. Raises UsageError for bad input."""
    from ._common import RunError, check_out, set_precision

    check_options(args)
    check_out(args.out)
    set_precision(args.float32)
    inputs = _inputs(args)
    r, times = _compile_and_run(args, inputs)
    if r["failure"] is not None:
        raise RunError(f"simulation failed, nothing written: {r['failure']}")
    _summary(args, r, times, _write(args, inputs, r, times))
    return 0
