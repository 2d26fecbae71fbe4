"""`rigidjax` command: simulate, sweep, identify, darboux, bench.

`rigidjax` with no command (or with only options) runs `rigidjax simulate`: the tennis-racket
(Dzhanibekov) flip, written to `rigidjax_out/trajectory.{npz,csv,png}`.

Every command keeps JAX's persistent compilation cache in the user's cache folder
(`$RIGIDJAX_CACHE_DIR` to choose it, `--no-cache` to switch it off), so a second run loads its
compiled programs instead of compiling them again.

Exit status: 0 on success; 2 for a bad command line, config or data file (reported as one
`rigidjax: error: ...` line naming the option, file, key or line and the fix, with no
traceback); 1 when the computation itself fails or the results cannot be written. Anything
else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
from collections.abc import Sequence
from typing import Any

from ._common import PROG, RunError, UsageError, compilation_cache, error

COMMANDS = {
    "simulate": "simulate a free rigid body; write its trajectory and a plot (the default)",
    "sweep": "run a parameter sweep from a TOML config; write sweep.zarr and a plot",
    "identify": "fit the inertia tensor to gyro (and attitude) data from a CSV file",
    "darboux": "attitude from gyro data (a CSV file): the Darboux problem",
    "bench": "the headline benchmarks in about a minute: a table and bench.json",
}


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


def _module(name: str):
    return importlib.import_module(f"{__package__}.{name}")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="JAX-accelerated, differentiable rigid-body dynamics. With no command, "
        "`rigidjax` runs `rigidjax simulate` (the tennis-racket flip). Plots need matplotlib: "
        "pip install 'rigidjax[plot]'.",
    )
    p.add_argument("--version", action=_VersionAction)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for name, text in COMMANDS.items():
        module = _module(name)
        q = sub.add_parser(name, help=text, description=(module.__doc__ or text).split("\n\n")[0])
        module.add_arguments(q)
        q.add_argument("--no-progress", action="store_true", help="no progress bar")
        q.add_argument(
            "--no-cache",
            action="store_true",
            help="no persistent compilation cache (default: $RIGIDJAX_CACHE_DIR or the user's "
            "cache folder)",
        )
        q.set_defaults(run=module.run)
    return p


def _with_command(argv: list[str]) -> list[str]:
    """`argv`, with `simulate` in front unless it names a command or asks for the top help."""
    if argv and (argv[0] in COMMANDS or argv[0] in ("-h", "--help", "--version")):
        return argv
    return ["simulate", *argv]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `rigidjax` command on `argv` (default `sys.argv[1:]`); returns the exit status."""
    import sys

    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and not argv[0].startswith("-") and argv[0] not in COMMANDS:  # simulate: no operands
        close = difflib.get_close_matches(argv[0], COMMANDS, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        error(f"unknown command {argv[0]!r}: {hint}the commands are {', '.join(COMMANDS)}")
        return 2
    try:
        args = _parser().parse_args(_with_command(argv))
    except SystemExit as e:  # argparse's own errors (status 2), --help and --version (0)
        return e.code if isinstance(e.code, int) else 1
    try:
        with compilation_cache(not args.no_cache):
            return args.run(args)
    except UsageError as e:
        error(str(e))
        return 2
    except RunError as e:
        error(str(e))
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
