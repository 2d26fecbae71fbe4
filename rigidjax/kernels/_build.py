"""Build a kernel's C++ source on this machine (once: the shared library is kept in the user's
cache folder, keyed by the source, the compiler and jaxlib, with XLA's FFI header precompiled
there once) and register its XLA FFI handlers for the CPU."""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shlex
import subprocess
import tempfile
import warnings
from importlib import resources
from pathlib import Path

import jax
import jax.ffi

from .._cache import user_cache_dir

FLAGS = ("-std=c++17", "-O3", "-march=native", "-fno-math-errno", "-fopenmp", "-shared", "-fPIC")
"""`-fno-math-errno` keeps IEEE results and only lets `sqrt` vectorise; `-march=native`: the
library is built for the machine it runs on."""


Headers = tuple[tuple[str, str], ...]
"""Generated header files of a kernel: (file name, text) pairs."""


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


def _toolchain(compiler: list[str]) -> str:
    """What a build's output depends on besides its source: the compiler's version, the flags,
    jaxlib's FFI headers and this CPU (see `_cpu`)."""
    try:
        version = subprocess.run(
            [*compiler, "--version"], capture_output=True, text=True, timeout=30, check=True
        ).stdout
    except (OSError, subprocess.SubprocessError) as e:
        raise KernelUnavailable(f"no C++ compiler ({' '.join(compiler)}: {e})") from e
    h = hashlib.sha256()
    for part in (version, " ".join(FLAGS), jax.__version__, jax.ffi.include_dir(), _cpu()):
        h.update(part.encode())
    return h.hexdigest()


def _key(source: bytes, headers: Headers, toolchain: str) -> str:
    h = hashlib.sha256(source)
    for name, text in headers:
        h.update(f"{name}\n{text}".encode())
    h.update(toolchain.encode())
    return h.hexdigest()[:16]


def _compile(command: list[str], out: Path) -> subprocess.CompletedProcess:
    """Run `command`, which writes `out`'s file into a temporary folder beside it, and rename
    that file into place on success (parallel processes never read half a file)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        done = subprocess.run(
            [*command, "-o", str(Path(tmp) / out.name)], capture_output=True, text=True,
            timeout=600, cwd=tmp,
        )  # fmt: skip
        if done.returncode == 0:
            os.replace(Path(tmp) / out.name, out)
    return done


def _prelude(compiler: list[str], toolchain: str) -> list[str]:
    """`-include` of XLA's FFI header, precompiled once per toolchain into the cache (90 MB;
    it takes 0.5–0.9 s off each kernel's 3.5 s build, measured with GCC 12): the flags that
    make a build read it; none where it cannot be precompiled (the source then parses the
    header itself, as a compiler does that cannot use the file)."""
    header = user_cache_dir() / "kernels" / f"ffi-{toolchain[:16]}" / "ffi_prelude.h"
    if not header.with_suffix(".h.gch").exists():
        try:
            header.parent.mkdir(parents=True, exist_ok=True)
            if not header.exists():
                with tempfile.NamedTemporaryFile("w", dir=header.parent, delete=False) as f:
                    f.write('#include "xla/ffi/api/ffi.h"\n')
                os.replace(f.name, header)
            command = [*compiler, *FLAGS, "-x", "c++-header", f"-I{jax.ffi.include_dir()}"]
            if _compile([*command, str(header)], header.with_suffix(".h.gch")).returncode != 0:
                return []
        except (OSError, subprocess.SubprocessError):
            return []
    return ["-include", str(header)]


def build(name: str, headers: Headers = ()) -> Path:
    """The shared library of `rigidjax/kernels/{name}.cc` with the generated `headers` (file
    name, text) beside it, compiled if not in the cache yet (see `_compile`), with the
    precompiled FFI header where there is one (`_prelude`)."""
    source = resources.files("rigidjax.kernels").joinpath(f"{name}.cc").read_bytes()
    compiler = _compiler()
    toolchain = _toolchain(compiler)
    folder = user_cache_dir() / "kernels"
    path = folder / f"{name}-{_key(source, headers, toolchain)}.so"
    if path.exists():
        return path
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as src:
            (Path(src) / f"{name}.cc").write_bytes(source)
            for header, text in headers:
                (Path(src) / header).write_text(text)
            command = [*compiler, *FLAGS, *_prelude(compiler, toolchain)]
            command += [f"-I{jax.ffi.include_dir()}", str(Path(src) / f"{name}.cc")]
            done = _compile(command, path)
            if done.returncode != 0:
                raise KernelUnavailable(
                    f"building {name}.cc failed ({shlex.join(command)}):\n{done.stderr[-2000:]}"
                )
    except (OSError, subprocess.SubprocessError) as e:
        raise KernelUnavailable(f"building {name}.cc failed: {e}") from e
    return path


@functools.cache
def load(name: str, targets: tuple[str, ...], headers: Headers = ()) -> str | None:
    """Build `name` (with `headers`, see `build`) and register its handler symbols `targets` as
    XLA FFI targets of the same names on the CPU; returns None, after one warning, where that
    is not possible."""
    try:
        library = ctypes.CDLL(str(build(name, headers)))
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
