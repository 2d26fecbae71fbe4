"""`rigidjax` command: simulate a rigid body and write its trajectory (npz, CSV) and a plot.

With no arguments it runs the tennis-racket (Dzhanibekov) flip: a body with I = (1, 2, 3) spun
about its middle axis with a small perturbation, which flips periodically (Zegrya–Parshin 004:
rotation about the middle axis is unstable).

Exit status: 0 on success; 2 for a bad command line (reported as one `rigidjax: error: ...`
line, like argparse's own errors, with no traceback); 1 when the integration itself fails or the
results cannot be written. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

PROG = "rigidjax"
DEFAULTS = dict(
    inertia=(1.0, 2.0, 3.0),
    omega0=(0.01, 1.0, 0.01),
    q0=(1.0, 0.0, 0.0, 0.0),
    t_end=60.0,
    num=3001,
    kinematics="quat",
)
MAX_STEPS = 1_000_000  # per output interval

T = TypeVar("T")


class UsageError(Exception):
    """A bad command line: reported as one `rigidjax: error: ...` line, exit status 2."""


def _version() -> str:
    """`rigidjax <version> (jax <version>)`, read without importing JAX."""
    from importlib.metadata import PackageNotFoundError, version

    from .. import __version__

    try:
        jax_version = version("jax")
    except PackageNotFoundError:  # pragma: no cover - jax is a dependency
        jax_version = "not installed"
    return f"{PROG} {__version__} (jax {jax_version})"


class _VersionAction(argparse.Action):
    """`--version`: print `_version()` and exit 0 (computed only when asked for)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any):
        super().__init__(option_strings, dest, nargs=0, help="print the versions and exit")

    def __call__(self, parser: argparse.ArgumentParser, *_: Any) -> None:
        print(_version())
        parser.exit(0)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
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
    p.add_argument("--version", action=_VersionAction)
    return p


# --- checks made before any JAX work ---------------------------------------------------------


def _check_options(args: argparse.Namespace) -> None:
    """Raise UsageError for option values that are wrong whatever the body."""
    if args.num < 2:
        raise UsageError(f"--num must be at least 2 (output times), got {args.num}")
    if not (math.isfinite(args.t_end) and args.t_end > 0):
        raise UsageError(f"--t-end must be a positive, finite time span [s], got {args.t_end}")
    for name in ("rtol", "atol"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UsageError(f"--{name} must be positive and finite, got {value}")


def _nearest_existing(path: Path) -> Path:
    """`path` or its closest ancestor that exists (a dangling link counts as existing)."""
    for p in (path, *path.absolute().parents):
        if p.exists() or p.is_symlink():
            return p
    return Path(path.absolute().anchor)  # pragma: no cover - the root always exists


def _check_out(out: Path) -> None:
    """Raise UsageError unless `out` is, or can be created as, a writable folder. Nothing is
    left behind: writability is probed with a temporary file in `out` or its closest existing
    ancestor (the folder itself is made only when the results are written)."""
    fix = "give a folder path with --out DIR"
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: is an existing file, not a folder; {fix}")
    existing = _nearest_existing(out)
    if not existing.is_dir():
        raise UsageError(f"--out {out}: {existing} exists and is not a folder; {fix}")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as e:
        raise UsageError(
            f"--out {out}: cannot write in {existing} ({e.strerror or e}); choose a writable "
            "folder with --out DIR or change its permissions"
        ) from e


# --- the library's checks of the user's values ----------------------------------------------


@dataclass(frozen=True)
class _Inputs:
    """The validated arguments of `simulate`."""

    body: Any  # RigidBody (imported with JAX)
    omega0: Any
    q0: Any
    ts: Any
    options: Any  # SolveOptions


def _checked(option: str, make: Callable[[], T]) -> T:
    """`make()`, its ValueError/TypeError turned into a UsageError naming `option`.

    This is where the line between user errors and bugs is drawn: `make` only builds or checks
    one library object from the user's concrete value (a constructor or a `_checks` helper, run
    eagerly, never traced), and the library raises ValueError/TypeError exactly for input it
    rejects. Tracing, compiling, running and writing happen outside any such guard, so an
    exception there is not mistaken for a user error and keeps its traceback."""
    try:
        return make()
    except (ValueError, TypeError) as e:
        raise UsageError(f"{option}: {e}") from e


def _inputs(args: argparse.Namespace) -> _Inputs:
    """Build and validate the simulation's inputs, eagerly, with the library's own checks."""
    import diffrax
    import jax.numpy as jnp

    from .._checks import check_finite, check_times, check_unit_norm, vector
    from .._integrate import SolveOptions
    from ..mechanics.body import RigidBody

    dtype = jnp.float32 if args.float32 else jnp.float64
    meter = diffrax.NoProgressMeter() if args.no_progress else diffrax.TextProgressMeter()
    unit = "; give a unit quaternion (divide it by its norm)"
    return _Inputs(
        body=_checked("--inertia", lambda: RigidBody(jnp.asarray(args.inertia, dtype))),
        omega0=_checked(
            "--omega0",
            lambda: check_finite(vector(jnp.asarray(args.omega0, dtype), 3, "omega0"), "omega0"),
        ),
        q0=_checked(
            "--q0",
            lambda: check_unit_norm(vector(jnp.asarray(args.q0, dtype), 4, "q0"), "q0", unit),
        ),
        ts=_checked(
            "--t-end/--num",
            lambda: check_times(jnp.linspace(0.0, args.t_end, args.num, dtype=dtype)),
        ),
        options=_checked(
            "--rtol/--atol",
            lambda: SolveOptions(
                rtol=args.rtol,
                atol=args.atol,
                max_steps=MAX_STEPS,
                progress_meter=meter,
                throw=False,  # a failed solve is reported below, not raised from compiled code
            ),
        ),
    )


# --- compile, run, write ---------------------------------------------------------------------


def _solve(body: Any, omega0: Any, q0: Any, ts: Any, *, kinematics: str, options: Any) -> dict:
    """The whole computation, to be compiled: the trajectory and what is written or plotted."""
    import jax.numpy as jnp

    from ..mechanics.dynamics import simulate
    from ..mechanics.invariants import energy, momentum_squared
    from ..rotations import quat

    traj = simulate(body, omega0, q0, ts, kinematics=kinematics, options=options)
    return dict(
        omega=traj.omega,
        quat=traj.quat,
        matrix=traj.matrix,
        energy=energy(body, traj.omega),
        momentum_norm=jnp.sqrt(momentum_squared(body, traj.omega)),
        axis2=quat.rotate(traj.quat, jnp.array([0.0, 1.0, 0.0], ts.dtype)),
        num_steps=traj.stats["num_steps"],
        result=traj.result,
    )


def _compile_and_run(args: argparse.Namespace, x: _Inputs) -> tuple[dict, float, float]:
    """Compile ahead of time, then run: `(outputs, compile seconds, run seconds)`."""
    import jax

    f = functools.partial(_solve, kinematics=args.kinematics, options=x.options)
    t0 = time.perf_counter()
    compiled = jax.jit(f).lower(x.body, x.omega0, x.q0, x.ts).compile()
    t1 = time.perf_counter()
    out = jax.block_until_ready(compiled(x.body, x.omega0, x.q0, x.ts))
    return out, t1 - t0, time.perf_counter() - t1


def _failure(result: Any) -> str | None:
    """The message of a failed solve's `result`, or None if it succeeded."""
    import diffrax

    if bool(result == diffrax.RESULTS.successful):
        return None
    return diffrax.RESULTS[result] or "the solver failed"


def _write_atomic(path: Path, write: Callable[[str], object]) -> None:
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


def _write(args: argparse.Namespace, x: _Inputs, r: dict, times: dict) -> dict[str, Path]:
    """Write trajectory.{npz,csv[,png]} in `args.out`; returns the paths by kind."""
    ts = np.asarray(x.ts)
    T, Mn = np.asarray(r["energy"]), np.asarray(r["momentum_norm"])
    omega, q = np.asarray(r["omega"]), np.asarray(r["quat"])
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    can_plot = importlib.util.find_spec("matplotlib") is not None
    kinds = ("npz", "csv", "png") if can_plot else ("npz", "csv")
    paths = {k: out / f"trajectory.{k}" for k in kinds}
    table = np.column_stack([ts, omega, q, T, Mn])
    header = "t,omega1,omega2,omega3,q_w,q_x,q_y,q_z,energy,momentum_norm"
    _write_atomic(
        paths["npz"],
        lambda f: np.savez(
            open(f, "wb"),  # noqa: SIM115 - np.savez closes nothing it did not open
            ts=ts,
            omega=omega,
            quat=q,
            matrix=np.asarray(r["matrix"]),
            energy=T,
            momentum_norm=Mn,
            inertia=np.asarray(x.body.inertia),
            kinematics=args.kinematics,
            num_steps=np.asarray(r["num_steps"]),
            **times,
        ),
    )
    _write_atomic(
        paths["csv"], lambda f: np.savetxt(f, table, delimiter=",", header=header, comments="")
    )
    if can_plot:
        drifts = (T / T[0] - 1, Mn / Mn[0] - 1)
        axis2 = np.asarray(r["axis2"])
        _write_atomic(paths["png"], lambda f: _plot(f, ts, omega, *drifts, axis2, args.inertia))
    return paths


def _summary(args: argparse.Namespace, r: dict, times: dict, paths: dict[str, Path]) -> None:
    """Print what was simulated, how long compiling and running took, and what was written."""
    T, Mn = np.asarray(r["energy"]), np.asarray(r["momentum_norm"])
    precision = "float32" if args.float32 else "float64"
    print(
        f"simulated {args.t_end:g} s ({int(r['num_steps'])} steps, {args.kinematics}, "
        f"{precision}): compile {times['compile_time_s']:.3g} s, run {times['run_time_s']:.3g} s"
    )
    print(
        f"max relative drift: energy {np.max(np.abs(T / T[0] - 1)):.2e}, "
        f"|M| {np.max(np.abs(Mn / Mn[0] - 1)):.2e}"
    )
    for k, p in paths.items():
        print(f"wrote {k.upper()}: {p.resolve()}")
    if "png" not in paths:
        print("no plot: matplotlib is not installed (pip install 'rigidjax[plot]')")


def _error(message: str) -> None:
    print(f"{PROG}: error: {message}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `rigidjax` command on `argv` (default `sys.argv[1:]`); returns the exit status."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as e:  # argparse's own errors (status 2), --help and --version (0)
        return e.code if isinstance(e.code, int) else 1
    try:
        _check_options(args)
        _check_out(args.out)
        if not args.float32:
            import jax

            jax.config.update("jax_enable_x64", True)  # the application's choice, not the library's
        inputs = _inputs(args)
    except UsageError as e:
        _error(str(e))
        return 2
    r, compile_s, run_s = _compile_and_run(args, inputs)
    failure = _failure(r["result"])
    if failure is not None:
        _error(f"simulation failed, nothing written: {failure}")
        return 1
    times = {"compile_time_s": compile_s, "run_time_s": run_s}
    try:
        paths = _write(args, inputs, r, times)
    except OSError as e:  # checked up front, but the disk can still fill up or change
        _error(f"could not write the results in {args.out}: {e}")
        return 1
    _summary(args, r, times, paths)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
