"""`rigidjax sweep CONFIG.toml`: a parameter sweep of the free rigid body from a TOML config,
written to DIR/sweep.zarr (resumable: run the same command again after an interruption) with
a plot (heat maps for a 2-D grid, curves for a 1-D grid, histograms otherwise).

The config holds the body and initial state (any number may be a factor name), the design,
the times, the solver and the observables: see `examples/*.toml`. Several machines: start the
same command on each with `--coordinator HOST:PORT --num-processes N --process-id I` (or with
none of them under SLURM and other launchers JAX detects), all writing to one shared --out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ._common import (
    NO_PLOT,
    RunError,
    UsageError,
    can_plot,
    checked,
    checks_as_nan,
    pyplot,
    save_figure,
    write_atomic,
)
from ._config import Config, fill, load, make_design
from ._sweep_model import make_model

STORE = "sweep.zarr"
CONFIG_COPY = "sweep.toml"  # the config the store was made with


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, metavar="CONFIG.toml", help="the sweep's config")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: CONFIG's name)")
    p.add_argument(
        "--coordinator", metavar="HOST:PORT", help="multi-machine: the coordinator's address"
    )
    p.add_argument("--num-processes", type=int, metavar="N", help="multi-machine: process count")
    p.add_argument("--process-id", type=int, metavar="I", help="multi-machine: this process")


def _distributed(args: argparse.Namespace) -> None:
    """`jax.distributed.initialize` with the given flags (CPU collectives over gloo)."""
    given = [args.coordinator, args.num_processes, args.process_id]
    if all(v is None for v in given):
        return
    if any(v is None for v in given):
        raise UsageError(
            "--coordinator, --num-processes and --process-id go together: give all three "
            "(or none, under a launcher JAX detects, such as SLURM)"
        )
    if args.num_processes < 1 or not 0 <= args.process_id < args.num_processes:
        raise UsageError(
            f"--process-id must be in [0, --num-processes) and --num-processes ≥ 1, got "
            f"{args.process_id} of {args.num_processes}"
        )
    import jax

    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        args.coordinator, num_processes=args.num_processes, process_id=args.process_id
    )


def check_points(c: Config, design) -> None:
    """Check the body and initial state at every design point, eagerly and all at once; the
    first bad point is found by bisection and named with its factor values."""
    import jax.numpy as jnp

    from .._checks import check_finite, check_unit_norm
    from ..mechanics.body import RigidBody

    dtype = jnp.float32 if c.float32 else jnp.float64
    values = {k: np.asarray(v) for k, v in design.points.items()}

    def check(lo: int, hi: int) -> None:
        sub = {k: jnp.asarray(v[lo:hi], dtype) for k, v in values.items()}
        inertia = fill(c.inertia, sub, jnp)
        if inertia.ndim == 2:  # moments (n, 3): never read as one tensor when n = 3
            inertia = inertia[:, None, :]
        RigidBody(inertia)
        check_finite(fill(c.omega0, sub, jnp), "omega0")
        check_unit_norm(fill(c.q0, sub, jnp), "q0", "; give a unit quaternion")
        if c.wheels is not None:
            check_finite(fill(c.wheels["tilt"], sub, jnp), "[wheels] tilt")

    try:
        check(0, design.size)
        return
    except ValueError as e:
        first = e
    lo, hi = 0, design.size  # the first bad point lies in [lo, hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            check(lo, mid)
            lo = mid
        except ValueError:
            hi = mid
    point = ", ".join(f"{k} = {v[lo]:.6g}" for k, v in values.items())
    where = f"{c.path}: the design point {point}"
    checked(where, lambda: check(lo, lo + 1))
    raise UsageError(f"{c.path}: {first}")  # not reached: the bisection found the point


def _same_config(out: Path, c: Config) -> None:
    """Refuse to resume a store made with another config (same design, other model)."""
    import tomllib

    copy = out / CONFIG_COPY
    if (out / STORE).exists() and copy.exists():
        try:
            kept = tomllib.loads(copy.read_text(encoding="utf-8-sig"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            why = e.strerror or e if isinstance(e, OSError) else e
            raise UsageError(
                f"--out {out}: cannot read its copy of the config {copy} ({why}); choose "
                f"another --out, or delete {out} to start again"
            ) from e
        if kept != tomllib.loads(c.text):
            raise UsageError(
                f"--out {out}: holds a sweep made with another config ({copy}); choose another "
                f"--out, or delete {out / STORE} to start again"
            )


def _scalar_observables(ds) -> list[str]:
    return [n for n in ds.data_vars if n != "status" and ds[n].dims == ds["status"].dims]


def _plot(path: str, ds, c: Config) -> None:
    """Heat maps (2-D grid), curves (1-D grid) or histograms (samples, larger grids) of the
    scalar observables; failed points are left out."""
    plt = pyplot()
    from matplotlib.colors import LogNorm

    names = _scalar_observables(ds)
    failed = ds["status"] >= 2  # the integration failed or the model raised: no values
    dims = list(ds["status"].dims)
    cols = min(2, len(names))
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 4.2 * rows), squeeze=False)
    kind = c.design["kind"]
    for ax, name in zip(axes.flat, names, strict=False):
        v = ds[name].where(~failed & np.isfinite(ds[name]))  # first_flip_time = inf: no flip
        positive = np.asarray(v.values)[np.isfinite(v.values)]
        log = positive.size > 0 and positive.min() > 0 and positive.max() > 100 * positive.min()
        if kind == "grid" and len(dims) == 2:
            y, x = dims
            norm = LogNorm() if log else None  # drifts span decades
            m = ax.pcolormesh(ds[x].values, ds[y].values, v.values, shading="nearest", norm=norm)
            fig.colorbar(m, ax=ax, label=name)
            ax.set_xlabel(x)
            ax.set_ylabel(y)
            for d, set_scale in ((x, ax.set_xscale), (y, ax.set_yscale)):
                if d in c.log_factors:
                    set_scale("log")
        elif kind == "grid" and len(dims) == 1:
            ax.plot(ds[dims[0]].values, v.values, marker=".")
            if log:
                ax.set_yscale("log")
            ax.set_xlabel(dims[0])
            ax.set_ylabel(name)
            if dims[0] in c.log_factors:
                ax.set_xscale("log")
        else:
            finite = np.asarray(v.values).ravel()
            finite = finite[np.isfinite(finite)]
            ax.hist(finite, bins=min(50, max(10, finite.size // 20)))
            ax.set_xlabel(name)
            ax.set_ylabel("points")
        ax.set_title(name)
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    counts = {k: v for k, v in ds.attrs.get("failures", {}).items() if v}
    note = ", ".join(f"{v} {k}" for k, v in counts.items()) or "no failures"
    fig.suptitle(f"{c.path.name}: {ds['status'].size} points; {note}")
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    from ._common import check_out, set_precision

    c = load(args.config)
    out: Path = args.out or Path(f"{args.config.stem}_out")
    check_out(out)
    _same_config(out, c)
    _distributed(args)
    set_precision(c.float32)
    design = checked(f"{c.path}: [design]", lambda: make_design(c))
    check_points(c, design)
    model = make_model(c)
    out.mkdir(parents=True, exist_ok=True)
    import jax

    from .. import sweep
    from ..sweep import _store

    store = out / STORE
    if jax.process_index() == 0 and not (out / CONFIG_COPY).exists():
        try:  # (before the copy is written: a refused --out keeps only what it held)
            _store.refuse_foreign(store)
        except ValueError as e:
            raise UsageError(f"--out {out}: {e}") from e
        write_atomic(out / CONFIG_COPY, lambda f: Path(f).write_text(c.text, encoding="utf-8"))
    try:
        with checks_as_nan():  # every point was checked: no host callbacks, cacheable
            ds = sweep.run(
                model, design, store=store, chunk_size=c.chunk_size, progress=not args.no_progress
            )
    except ValueError as e:  # the store: another design, not writable
        raise UsageError(f"--out {out}: {e}") from e
    if jax.process_index() != 0:
        return 0
    _summary(ds, store)
    if can_plot():
        png = out / "sweep.png"
        try:
            write_atomic(png, lambda f: _plot(f, ds, c))
        except OSError as e:
            raise RunError(f"could not write {png}: {e}") from e
        print(f"wrote PNG: {png.resolve()}")
    else:
        print(NO_PLOT)
    return 0


def _summary(ds: Any, store: Path) -> None:
    a = ds.attrs
    failed = ", ".join(f"{k} {v}" for k, v in a["failures"].items() if v) or "none"
    print(
        f"swept {ds['status'].size} points on {a['num_devices']} device(s), "
        f"{a['num_processes']} process(es): compile {a['compile_time_s']:.3g} s, "
        f"total {a['wall_time_s']:.3g} s; failed: {failed}"
    )
    for name in _scalar_observables(ds):
        v = np.asarray(ds[name].where(ds["status"] == 0).values, float)
        finite = v[np.isfinite(v)]
        if finite.size:
            never = int(np.sum(np.isinf(v)))
            note = f" ({never} points inf)" if never else ""
            print(f"  {name}: min {finite.min():.4g}, max {finite.max():.4g}{note}")
    print(f"wrote Zarr: {store.resolve()}", file=sys.stdout)
