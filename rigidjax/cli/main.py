"""`rigidjax` command: simulate a rigid body and write its trajectory (npz, CSV) and a plot.

With no arguments it runs the tennis-racket (Dzhanibekov) flip: a body with I = (1, 2, 3) spun
about its middle axis with a small perturbation, which flips periodically (Zegrya–Parshin 004:
rotation about the middle axis is unstable).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULTS = dict(
    inertia=(1.0, 2.0, 3.0),
    omega0=(0.01, 1.0, 0.01),
    q0=(1.0, 0.0, 0.0, 0.0),
    t_end=60.0,
    num=3001,
    kinematics="quat",
)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rigidjax",
        description="Simulate a free (torque-free) rigid body and write trajectory.npz, "
        "trajectory.csv and trajectory.png (the plot needs matplotlib: pip install "
        "'rigidjax[plot]'). Defaults: the tennis-racket flip.",
    )
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
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def _write_atomic(path: Path, write) -> None:
    """Write through a temporary file in the same folder and rename: never a half-written file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _plot(path: str, ts, omega, energy_drift, momentum_drift, axis_space, inertia) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.num < 2 or not args.t_end > 0:
        print("rigidjax: --num must be ≥ 2 and --t-end > 0", file=sys.stderr)
        return 2

    import diffrax
    import jax

    if not args.float32:
        jax.config.update("jax_enable_x64", True)  # the application's choice, not the library's
    import jax.numpy as jnp

    from ..mechanics.body import RigidBody
    from ..mechanics.dynamics import simulate
    from ..mechanics.invariants import energy, momentum_squared
    from ..rotations import quat

    dtype = jnp.float32 if args.float32 else jnp.float64
    try:
        body = RigidBody(jnp.asarray(args.inertia, dtype))
        ts = jnp.linspace(0.0, args.t_end, args.num, dtype=dtype)
        t0 = time.perf_counter()
        traj = simulate(
            body,
            jnp.asarray(args.omega0, dtype),
            jnp.asarray(args.q0, dtype),
            ts,
            kinematics=args.kinematics,
            rtol=args.rtol,
            atol=args.atol,
            max_steps=1_000_000,
            progress_meter=(
                diffrax.NoProgressMeter() if args.no_progress else diffrax.TextProgressMeter()
            ),
        )
        jax.block_until_ready(traj.omega)
        elapsed = time.perf_counter() - t0
    except Exception as e:  # noqa: BLE001 - report any failure cleanly, write nothing
        print(f"rigidjax: simulation failed, nothing written: {e}", file=sys.stderr)
        return 1

    ts_np = np.asarray(ts)
    omega = np.asarray(traj.omega)
    q = np.asarray(traj.quat)
    P = np.asarray(traj.matrix)
    T = np.asarray(energy(body, traj.omega))
    Mn = np.sqrt(np.asarray(momentum_squared(body, traj.omega)))
    e_drift, m_drift = T / T[0] - 1, Mn / Mn[0] - 1
    axis2 = np.asarray(quat.rotate(traj.quat, jnp.array([0.0, 1.0, 0.0], dtype)))

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    can_plot = importlib.util.find_spec("matplotlib") is not None
    kinds = ("npz", "csv", "png") if can_plot else ("npz", "csv")
    paths = {k: out / f"trajectory.{k}" for k in kinds}
    table = np.column_stack([ts_np, omega, q, T, Mn])
    header = "t,omega1,omega2,omega3,q_w,q_x,q_y,q_z,energy,momentum_norm"
    _write_atomic(
        paths["npz"],
        lambda f: np.savez(
            open(f, "wb"),  # noqa: SIM115 - np.savez closes nothing it did not open
            ts=ts_np,
            omega=omega,
            quat=q,
            matrix=P,
            energy=T,
            momentum_norm=Mn,
            inertia=np.asarray(body.inertia),
            kinematics=args.kinematics,
        ),
    )
    _write_atomic(
        paths["csv"], lambda f: np.savetxt(f, table, delimiter=",", header=header, comments="")
    )
    if can_plot:
        _write_atomic(
            paths["png"], lambda f: _plot(f, ts_np, omega, e_drift, m_drift, axis2, args.inertia)
        )
    print(
        f"simulated {args.t_end:g} s ({traj.stats['num_steps']} steps, {args.kinematics}, "
        f"{'float32' if args.float32 else 'float64'}) in {elapsed:.2f} s"
    )
    print(
        f"max relative drift: energy {np.max(np.abs(e_drift)):.2e}, "
        f"|M| {np.max(np.abs(m_drift)):.2e}"
    )
    for k, p in paths.items():
        print(f"wrote {k.upper()}: {p.resolve()}")
    if not can_plot:
        print("no plot: matplotlib is not installed (pip install 'rigidjax[plot]')")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
