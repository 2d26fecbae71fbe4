"""Build a kernel's C++ source on this machine (once: the shared library is kept in the user's
cache folder, keyed by the source, the compiler and jaxlib) and register its XLA FFI handlers
for the CPU. The translation units that every kernel links (model_ffi.cc: the handlers'
decoding of XLA's operands) are compiled once into object files of the same cache."""

from __future__ import annotations

import concurrent.futures
import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import shlex
import subprocess
import tempfile
import warnings
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path

import jax
import jax.ffi

from .._cache import user_cache_dir

FLAGS = ("-std=c++17", "-O3", "-march=native", "-fno-math-errno", "-fopenmp", "-fPIC")
"""`-fno-math-errno` keeps IEEE results and only lets `sqrt` vectorise; `-march=native`: the
library is built for the machine it runs on."""


Headers = tuple[tuple[str, str], ...]
"""Generated header files of a kernel: (file name, text) pairs."""

Units = tuple[tuple[str, Headers], ...]
"""Translation units that a kernel links: (the name of `rigidjax/kernels/{name}.cc`, its
headers) pairs, each compiled once into an object file shared by every kernel."""


class KernelUnavailable(RuntimeError):
    """The kernel could not be built or loaded here (no C++ compiler, no OpenMP, ...)."""


def _compiler() -> list[str]:
    return shlex.split(os.environ.get("CXX", "c++"))


def _cpu() -> str:
    """This CPU's model and instruction sets (`-march=native` builds for them: a cache folder
    shared by machines with other CPUs must not hand them this build)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.machine() + platform.processor()
    keep = [line for line in lines if line.startswith(("model name", "flags", "Features"))]
    return "\n".join(dict.fromkeys(keep))


@functools.cache
def _version(compiler: tuple[str, ...]) -> str:
    """The compiler's `--version`, asked once per process (a build links two units: each key
    holds it)."""
    try:
        return subprocess.run(
            [*compiler, "--version"], capture_output=True, text=True, timeout=30, check=True
        ).stdout
    except (OSError, subprocess.SubprocessError) as e:
        raise KernelUnavailable(f"no C++ compiler ({' '.join(compiler)}: {e})") from e


def _key(source: bytes, headers: Headers, compiler: list[str], objects: tuple[Path, ...]) -> str:
    version = _version(tuple(compiler))
    h = hashlib.sha256(source)
    for name, text in headers:
        h.update(f"{name}\n{text}".encode())
    for part in (version, " ".join(FLAGS), jax.__version__, jax.ffi.include_dir(), _cpu()):
        h.update(part.encode())
    for obj in objects:  # (their names hold their own keys)
        h.update(obj.name.encode())
    return h.hexdigest()[:16]


@contextlib.contextmanager
def _exclusive(lock: Path) -> Iterator[None]:
    """Hold an exclusive lock on the file `lock` (POSIX `flock`; released when the process
    ends, however it ends), so that processes needing the same kernel compile it once: the
    others wait and load it. Without `fcntl` (Windows), or on a file system that refuses the
    lock (some network file systems), none: each process may compile it, as before."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(lock, "a") as f:  # closing it releases the lock
        with contextlib.suppress(OSError):
            fcntl.flock(f, fcntl.LOCK_EX)
        yield


def build(name: str, headers: Headers = (), link: Units = ()) -> Path:
    """The shared library of `rigidjax/kernels/{name}.cc` with the generated `headers` (file
    name, text) beside it, linked with the object files of the units `link`, each built if not
    in the cache yet: by one process at a time (`_exclusive`; the others find it built), to a
    temporary file renamed into place, so that no process loads half a file. The units' missing
    objects compile while the library's own source does (threads: each a compiler process)."""
    compiler = _compiler()
    objects = tuple(_path(unit, unit_headers, ".o", compiler) for unit, unit_headers in link)
    library = _path(name, headers, ".so", compiler, objects)
    if library.exists():
        return library
    with concurrent.futures.ThreadPoolExecutor(max(len(link), 1)) as pool:
        built = [
            pool.submit(_make, obj, unit, unit_headers, compiler)
            for obj, (unit, unit_headers) in zip(objects, link, strict=True)
        ]
        _make(library, name, headers, compiler, objects, lambda: [b.result() for b in built])
    return library


def _read(name: str) -> bytes:
    """The source of `rigidjax/kernels/{name}.cc`."""
    return resources.files("rigidjax.kernels").joinpath(f"{name}.cc").read_bytes()


def _path(
    name: str, headers: Headers, suffix: str, compiler: list[str], objects: tuple[Path, ...] = ()
) -> Path:
    """Where the cache holds `{name}.cc` compiled with `headers`: an object file (`suffix`
    ".o") or a library linking `objects` (".so")."""
    key = _key(_read(name), headers, compiler, objects)
    return user_cache_dir() / "kernels" / f"{name}-{key}{suffix}"


def _make(
    path: Path,
    name: str,
    headers: Headers,
    compiler: list[str],
    objects: tuple[Path, ...] = (),
    ready: Callable[[], object] = lambda: None,
) -> None:
    """Build `path` (see `_path`) unless the cache has it; `ready()` returns once `objects`
    exist (the library's own source compiles first)."""
    if path.exists():
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with _exclusive(path.with_suffix(".lock")):
            if not path.exists():  # built by another process while this one waited
                _compile(name, headers, compiler, path, objects, ready)
    except (OSError, subprocess.SubprocessError) as e:
        raise KernelUnavailable(f"building {name}.cc failed: {e}") from e


def _run(command: list[str], name: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise KernelUnavailable(
            f"building {name}.cc failed ({shlex.join(command)}):\n{done.stderr[-2000:]}"
        )


def _compile(
    name: str,
    headers: Headers,
    compiler: list[str],
    path: Path,
    objects: tuple[Path, ...],
    ready: Callable[[], object],
) -> None:
    """Compile `name`.cc with `headers` into the object file or the library `path` (by its
    suffix); a library with `objects`: its own object first, then, once `ready()`, the link."""
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        src = Path(tmp) / f"{name}.cc"
        src.write_bytes(_read(name))
        for header, text in headers:
            (Path(tmp) / header).write_text(text)
        out = Path(tmp) / path.name
        compile_ = [*compiler, *FLAGS, f"-I{jax.ffi.include_dir()}", str(src)]
        if path.suffix == ".o":
            _run([*compile_, "-c", "-o", str(out)], name)
        elif not objects:
            _run([*compile_, "-shared", "-o", str(out)], name)
        else:
            own = Path(tmp) / f"{name}.o"
            _run([*compile_, "-c", "-o", str(own)], name)
            ready()
            _run([*compiler, *FLAGS, "-shared", str(own), *map(str, objects), "-o", str(out)], name)
        os.replace(out, path)


@functools.cache
def load(
    name: str, targets: tuple[str, ...], headers: Headers = (), link: Units = ()
) -> str | None:
    """Build `name` (with `headers` and `link`, see `build`) and register its handler symbols
    `targets` as XLA FFI targets of the same names on the CPU; returns None, after one warning,
    where that is not possible."""
    try:
        library = ctypes.CDLL(str(build(name, headers, link)))
        for target in targets:
            handler = jax.ffi.pycapsule(getattr(library, target))
            jax.ffi.register_ffi_target(target, handler, platform="cpu")
    except (KernelUnavailable, OSError, AttributeError) as e:
        warnings.warn(
            f"rigidjax could not build its CPU kernel {name} ({e}); the same integration runs "
            "through Diffrax and XLA instead, 3-10x slower (measured on a 2-core CPU). "
            "Install a C++ compiler with OpenMP (g++, or clang++ with libomp; $CXX chooses it) "
            "to get it.",
            RuntimeWarning,
            stacklevel=2,
        )
        return None
    return name
