"""What the `rigidjax` subcommands share: user errors, the output folder, atomic writes, the
persistent compilation cache, precision and plots."""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from .._cache import user_cache_dir
from .._folders import write_problem

PROG = "rigidjax"
T = TypeVar("T")


class UsageError(Exception):
    """A bad command line, config or data file: one `rigidjax: error: ...` line, exit status 2."""


class RunError(Exception):
    """The computation failed or its results could not be written: one line, exit status 1."""


def error(message: str) -> None:
    print(f"{PROG}: error: {message}", file=sys.stderr)


def checked(where: str, make: Callable[[], T]) -> T:
    """`make()`, its ValueError/TypeError turned into a UsageError that names `where`.

    This is where the line between user errors and bugs is drawn: `make` only builds or checks
    one library object from the user's concrete values (a constructor or a `_checks` helper,
    run eagerly, never traced), and the library raises ValueError/TypeError exactly for input
    it rejects. Tracing, compiling, running and writing happen outside any such guard, so an
    exception there is not mistaken for a user error and keeps its traceback."""
    try:
        return make()
    except (ValueError, TypeError) as e:
        raise UsageError(f"{where}: {e}") from e


def check_out(out: Path) -> None:
    """Raise UsageError unless `out` is, or can be created as, a writable folder. Nothing is
    left behind (`rigidjax._folders.write_problem`; the folder itself is made only when the
    results are written)."""
    problem = write_problem(out)
    if problem is not None:
        raise UsageError(
            f"--out {out}: {problem}; choose a writable folder with --out DIR or change its "
            "permissions"
        )


def write_atomic(path: Path, write: Callable[[str], object]) -> None:
    """Write through a temporary file in the same folder and rename: never a half-written file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def can_plot() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


NO_PLOT = "no plot: matplotlib is not installed (pip install 'rigidjax[plot]')"


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str) -> None:
    """Lay out `fig`, write it to `path` as PNG and close it."""
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    pyplot().close(fig)


def write_results(
    out: Path, name: str, writers: dict[str, Callable[[str], object]], plot: Callable[[str], object]
) -> dict[str, Path]:
    """Make `out` and write `out/NAME.KIND` with each of `writers` (by KIND) and, when matplotlib
    is installed, `out/NAME.png` with `plot`, each atomically; the paths by KIND. RunError when
    one cannot be written (`out` was checked up front, but the disk can still fill up or change).
    """
    if can_plot():
        writers = {**writers, "png": plot}
    paths = {kind: out / f"{name}.{kind}" for kind in writers}
    try:
        out.mkdir(parents=True, exist_ok=True)
        for kind, write in writers.items():
            write_atomic(paths[kind], write)
    except OSError as e:
        raise RunError(f"could not write the results in {out}: {e}") from e
    return paths


def print_written(paths: dict[str, Path]) -> None:
    """A `wrote KIND: path` line per file, and the reason when there is no plot."""
    for kind, path in paths.items():
        print(f"wrote {kind.upper()}: {path.resolve()}")
    if "png" not in paths:
        print(NO_PLOT)


def check_positive(args, *names: str) -> None:
    """UsageError unless each option `names` (argparse dests) is None or positive and finite."""
    for name in names:
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UsageError(f"--{name.replace('_', '-')} must be positive and finite, got {v}")


def check_tolerance(where: str, value: float | None, *, float32: bool) -> None:
    """UsageError if a tolerance `value` (option or config key `where`) asks for more than the
    precision can give (`rigidjax._tolerances.attainable`): the library only warns, and the
    solve would end in max_steps or a step size that overflows to NaN."""
    from .._tolerances import attainable

    floor = attainable("float32" if float32 else "float64")
    if value is not None and value < floor:
        fix = ", or compute in float64" if float32 else ""
        raise UsageError(
            f"{where}: {value:g} is below what {'float32' if float32 else 'float64'} can reach; "
            f"give at least {floor:.1g}{fix}"
        )


def set_precision(float32: bool) -> None:
    """float64 unless `float32`, and full-precision matrix products (no TF32 on GPUs, whose
    10-bit mantissa would cost float32 runs three digits): the application's choice (the
    library never sets either)."""
    import jax

    jax.config.update("jax_default_matmul_precision", "highest")
    if not float32:
        jax.config.update("jax_enable_x64", True)


def cache_dir() -> Path:
    """Where the command keeps JAX's persistent compilation cache: `$RIGIDJAX_CACHE_DIR`, else
    `jax/` in the user's cache folder (`rigidjax._cache.user_cache_dir`)."""
    explicit = os.environ.get("RIGIDJAX_CACHE_DIR")
    if explicit:
        return Path(explicit).expanduser()
    return user_cache_dir() / "jax"


@contextlib.contextmanager
def compilation_cache(enabled: bool) -> Iterator[Path | None]:
    """JAX's persistent compilation cache in `cache_dir()` while the command runs (every program
    is stored: on the kernels a run's program compiles in well under a second, and a second run
    loads it instead of compiling, the kernel itself cached apart, `kernels/`). The
    previous settings are restored afterwards, so calling `main` from Python leaves the
    process as it was. Yields the folder, or None when disabled or not writable."""
    if not enabled:
        yield None
        return
    import jax
    from jax.experimental.compilation_cache import compilation_cache as cc

    path = cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        yield None  # an unusable cache folder only costs compile time
        return
    settings = {
        "jax_compilation_cache_dir": str(path),
        "jax_persistent_cache_min_compile_time_secs": 0.0,
    }
    old = {k: getattr(jax.config, k) for k in settings}
    for k, v in settings.items():
        jax.config.update(k, v)
    cc.reset_cache()  # JAX reads the settings when it first compiles: make it read them again
    try:
        yield path
    finally:
        for k, v in old.items():
            jax.config.update(k, v)
        cc.reset_cache()


@contextlib.contextmanager
def checks_as_nan() -> Iterator[None]:
    """Trace programs whose inputs the command has checked eagerly with Equinox's runtime checks
    (`eqx.error_if`: the library's, and Diffrax's check of the step size's sign) compiled the
    way `EQX_ON_ERROR=nan` compiles them: a failing check gives NaN, which the command detects
    through the solver's `result` or non-finite values, instead of a host callback.

    Why: JAX's persistent compilation cache refuses every program with a host callback, and
    each runtime check is one. Equinox reads `EQX_ON_ERROR` only when it is imported (before
    the command starts), so its module setting is switched here, only if it is the default
    `raise`, and restored afterwards; the traces and compiled programs made meanwhile are
    dropped (`jax.clear_caches`), so later calls in the same process check as usual."""
    import jax

    try:
        from equinox import _errors
    except ImportError:  # pragma: no cover - another Equinox layout: checks stay callbacks
        yield
        return
    if getattr(_errors, "EQX_ON_ERROR", None) != "raise":
        yield  # the user chose another mode (nan, breakpoint, off): keep it
        return
    setattr(_errors, "EQX_ON_ERROR", "nan")  # noqa: B010 - a module setting, not an export
    try:
        yield
    finally:
        setattr(_errors, "EQX_ON_ERROR", "raise")  # noqa: B010
        jax.clear_caches()
        sweep_run = sys.modules.get("rigidjax.sweep.run")  # its compiled programs, if any
        if sweep_run is not None:
            sweep_run._compiled.cache_clear()
