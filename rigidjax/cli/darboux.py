"""`rigidjax darboux GYRO.csv`: the attitude from gyro data (the Darboux problem, Zhilin 3.12):
integrate the measured angular velocity (interpolated between samples) from the initial
attitude --q0, and write the attitude at the sample times to DIR/attitude.csv and .npz, with a
plot DIR/attitude.png.

Columns: t, wx, wy, wz (rad/s), with a header line naming them or in that order. The rates are
body rates (strapdown gyros) unless --frame space."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ._common import check_tolerance, checked, print_written, pyplot, save_figure, write_results
from ._data import prepare

METHODS = ("rotvec", "quat", "matrix", "euler", "cayley_klein", "geometric")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", type=Path, metavar="GYRO.csv", help="t, wx, wy, wz")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: GYRO's name)")
    p.add_argument("--frame", choices=["body", "space"], default="body", help="frame of the rates")
    p.add_argument("--method", choices=METHODS, default="quat", help="the formulation")
    p.add_argument(
        "--q0",
        type=float,
        nargs=4,
        metavar=("W", "X", "Y", "Z"),
        default=(1.0, 0.0, 0.0, 0.0),
        help="initial attitude quaternion, scalar first",
    )
    p.add_argument("--rtol", type=float, default=None, help="relative tolerance")
    p.add_argument("--atol", type=float, default=None, help="absolute tolerance")


def _plot(path: str, t, q, ypr) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for k, name in enumerate("wxyz"):
        ax[0].plot(t, q[:, k], label=f"q{name}")
    ax[0].set_ylabel("attitude quaternion")
    ax[0].legend(loc="upper right", ncol=4, fontsize=8)
    for k, name in enumerate(("yaw ψ", "pitch θ", "roll φ")):
        ax[1].plot(t, ypr[:, k], label=name)
    ax[1].set_ylabel("Euler angles ZYX [deg]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(loc="upper right", fontsize=8)
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    data, out = prepare(args, "rtol", "atol", attitude=False)
    for name in ("rtol", "atol"):
        check_tolerance(f"--{name}", getattr(args, name), float32=False)
    import jax.numpy as jnp

    from .._checks import check_unit_norm, vector
    from ..kinematics.darboux import darboux
    from ..rotations import euler, quat

    t, omega = jnp.asarray(data["t"]), jnp.asarray(data["omega"])
    q0 = checked(
        "--q0",
        lambda: check_unit_norm(vector(jnp.asarray(args.q0), 4, "q0"), "q0", "; give a unit one"),
    )
    start = time.perf_counter()
    P = darboux(
        (t, omega),
        t,
        quat.to_matrix(q0),
        frame=args.frame,
        method=args.method,
        rtol=args.rtol,
        atol=args.atol,
    )
    q = quat.continuous(quat.from_matrix(P))
    q = q * jnp.sign(jnp.sum(q[0] * q0))  # start at the given q0, not at −q0
    seconds = time.perf_counter() - start
    ypr = np.degrees(np.asarray(euler.from_matrix(P, seq="ZYX")))
    q, P = np.asarray(q), np.asarray(P)
    table = np.column_stack([data["t"], q, ypr])
    header = "t,qw,qx,qy,qz,yaw_deg,pitch_deg,roll_deg"
    paths = write_results(
        out,
        "attitude",
        {
            "csv": lambda f: np.savetxt(f, table, delimiter=",", header=header, comments=""),
            "npz": lambda f: np.savez(
                open(f, "wb"),  # noqa: SIM115 - np.savez closes nothing it did not open
                t=data["t"],
                quat=q,
                matrix=P,
                omega=data["omega"],
                frame=args.frame,
                method=args.method,
            ),
        },
        lambda f: _plot(f, data["t"], q, ypr),
    )
    angle = np.degrees(2 * np.arccos(np.clip(abs(np.sum(q[-1] * np.asarray(q0))), 0, 1)))
    print(
        f"integrated {data['t'].size} gyro samples over {data['t'][-1] - data['t'][0]:g} s "
        f"({args.method}, {args.frame} rates) in {seconds:.3g} s; total rotation {angle:.4g}°"
    )
    print_written(paths)
    return 0
