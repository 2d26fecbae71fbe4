"""`rigidjax identify DATA.csv`: fit the inertia tensor (and the initial state) to gyro data,
with attitude data when the file has them; print the tensor with its standard deviations and
write DIR/identify.json and a residual plot DIR/identify.png.

Columns: t, wx, wy, wz (body angular velocity, rad/s) and optionally qw, qx, qy, qz (attitude,
scalar first), with a header line naming them or in that order. Torque-free motion fixes the
tensor only up to scale: it is normalised to trace --trace (default 1)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ._common import checked, print_written, pyplot, save_figure, write_results
from ._data import prepare


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", type=Path, metavar="DATA.csv", help="t, wx, wy, wz [, qw, qx, qy, qz]")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: DATA's name)")
    p.add_argument("--trace", type=float, default=1.0, help="trace of the fitted tensor")
    p.add_argument("--sigma-omega", type=float, default=1.0, help="gyro noise std [rad/s]")
    p.add_argument("--sigma-angle", type=float, default=1.0, help="attitude noise std [rad]")
    p.add_argument("--gyro-only", action="store_true", help="ignore attitude columns")


def _plot(path: str, t, omega, model) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for k in range(3):
        (line,) = ax[0].plot(t, omega[:, k], ".", ms=3, label=f"Ω{k + 1} data")
        ax[0].plot(t, model[:, k], "-", color=line.get_color(), lw=1, label=f"Ω{k + 1} fit")
        ax[1].plot(t, omega[:, k] - model[:, k], ".", ms=3, label=f"Ω{k + 1}")
    ax[0].set_ylabel("body angular velocity [rad/s]")
    ax[0].legend(loc="upper right", ncol=3, fontsize=8)
    ax[1].set_ylabel("residual: data − fit [rad/s]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(loc="upper right", fontsize=8)
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    data, out = prepare(args, "trace", "sigma_omega", "sigma_angle", attitude=not args.gyro_only)
    import jax.numpy as jnp

    from ..fit import identify_inertia
    from ..mechanics.body import RigidBody
    from ..mechanics.dynamics import simulate

    t0 = time.perf_counter()
    est = checked(
        str(args.data),
        lambda: identify_inertia(
            jnp.asarray(data["t"]),
            omega_obs=jnp.asarray(data["omega"]),
            quat_obs=None if "quat" not in data else jnp.asarray(data["quat"]),
            trace=args.trace,
            sigma_omega=args.sigma_omega,
            sigma_angle=args.sigma_angle,
        ),
    )
    seconds = time.perf_counter() - t0
    inertia, std = np.asarray(est.inertia), np.asarray(est.inertia_std)
    model = simulate(RigidBody(est.inertia), est.omega0, est.q0, jnp.asarray(data["t"]))
    fit = np.asarray(model.omega)
    rms = float(np.sqrt(np.mean((data["omega"] - fit) ** 2)))
    result = {
        "data": str(args.data.resolve()),
        "samples": int(data["t"].size),
        "attitude_data": "quat" in data,
        "inertia": inertia.tolist(),
        "inertia_std": std.tolist(),
        "principal_moments": np.asarray(est.principal_moments).tolist(),
        "principal_axes": np.asarray(est.principal_axes).tolist(),
        "omega0": np.asarray(est.omega0).tolist(),
        "q0": np.asarray(est.q0).tolist(),
        "scale": est.scale,
        "converged": bool(est.converged),
        "identifiable": bool(est.identifiable),
        "cost": float(est.cost),
        "gyro_rms_residual": rms,
        "time_s": seconds,
    }
    paths = write_results(
        out,
        "identify",
        {"json": lambda f: Path(f).write_text(json.dumps(result, indent=2))},
        lambda f: _plot(f, data["t"], data["omega"], fit),
    )
    print(f"inertia ({est.scale}), ± one standard deviation:")
    for i in range(3):
        print("  " + "  ".join(f"{inertia[i, j]: .6f} ± {std[i, j]:.1e}" for j in range(3)))
    print("principal moments: " + ", ".join(f"{m:.6f}" for m in result["principal_moments"]))
    status = "converged" if result["converged"] else "NOT converged"
    print(f"{status} in {seconds:.3g} s; gyro rms residual {rms:.3g} rad/s")
    print_written(paths)
    return 0
