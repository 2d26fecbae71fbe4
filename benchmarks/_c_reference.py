"""The hand-written references: C kernels (`reference/*.c`) built with the system's C compiler
once per source, flags and compiler (cached on disk, keyed by their hash) and called through
ctypes in the same process; the CUDA kernels (`reference/models.cu`) built once per process by
NVRTC through CuPy (which caches the binaries on disk)."""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import re
import shlex
import subprocess
from pathlib import Path

import numpy as np

REFERENCE = Path(__file__).resolve().parent / "reference"
SOURCE = REFERENCE / "free_body.c"
FLAGS = ("-O3", "-march=native", "-fno-math-errno", "-fopenmp", "-shared", "-fPIC")
FLOPS_PER_BODY_STEP = 238
"""Counted in reference/free_body.c as written (adds, multiplies, one sqrt, one divide): four
right-hand sides of 30, three stage arguments of 14, the update 63 (y + h Σ b_l k_l, as Diffrax
sums it), the renormalisation 13."""


def peak_fp64_flops() -> dict:
    """The fp64 peak of this CPU: cores × clock × 16 (AVX2: two 4-wide FMA units), the clock
    from /proc/cpuinfo ("cpu MHz" of the first core); None where it cannot be read."""
    cores = os.cpu_count() or 1
    mhz = None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("cpu MHz"):
                mhz = float(line.split(":")[1])
                break
    except OSError:
        pass
    value = None if mhz is None else cores * mhz * 1e6 * 16
    return dict(flops=value, cores=cores, mhz=mhz, flops_per_cycle_per_core=16)


def cache_folder() -> Path:
    """Where built references are kept: `$RIGIDJAX_BENCH_CACHE`, else
    `$XDG_CACHE_HOME/rigidjax-bench` (`~/.cache/rigidjax-bench`)."""
    if "RIGIDJAX_BENCH_CACHE" in os.environ:
        return Path(os.environ["RIGIDJAX_BENCH_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "rigidjax-bench"


def _sources(source: Path) -> bytes:
    """The source and the local headers it includes (`#include "..."`), as one text."""
    text = source.read_bytes()
    for name in re.findall(rb'#include "([^"]+)"', text):
        text += (source.parent / name.decode()).read_bytes()
    return text


@functools.cache
def build_library(
    source: Path, flags: tuple[str, ...] = FLAGS
) -> tuple[ctypes.CDLL, str, str] | str:
    """`source` compiled with the system's C compiler ($CC) and loaded: the library, the
    compiler's vectorisation report and the command; or a note saying why not. Built once: the
    library and its report are kept in `cache_folder()` under the hash of the sources, flags and
    compiler, and loaded from there while those stay the same."""
    cc = shlex.split(os.environ.get("CC", "cc"))
    key = hashlib.sha256(_sources(source) + repr((cc, flags)).encode()).hexdigest()[:16]
    folder = cache_folder()
    out = folder / f"{source.stem}-{key}.so"
    report_file = out.with_suffix(".report")
    cmd = [*cc, *flags, "-fopt-info-vec-optimized", str(source), "-o", str(out)]
    if not (out.exists() and report_file.exists()):
        folder.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(f".{os.getpid()}.tmp")  # then renamed: another process never
        try:  # loads a half-written library
            done = subprocess.run(
                [*cmd[:-1], str(tmp)], capture_output=True, text=True, timeout=300
            )
        except (OSError, subprocess.SubprocessError) as e:
            return f"no C compiler ({e}): the C reference rows are skipped"
        if done.returncode != 0:
            return f"building the C reference failed: {done.stderr[-1000:]}"
        lines = done.stderr.splitlines()
        report_file.write_text("\n".join(line for line in lines if "loop vectorized" in line))
        tmp.replace(out)
    return ctypes.CDLL(str(out)), report_file.read_text(), shlex.join(cmd)


def bind(library: ctypes.CDLL, name: str, arrays: int, tail: int = 0):
    """`library.name` with the references' calling convention: `arrays` pointers (the state,
    first, advanced in place, then parameters), the batch size B, the steps, the step size, then
    `tail` integers."""
    fn = getattr(library, name)
    fn.argtypes = (
        [ctypes.c_void_p] * arrays
        + [ctypes.c_long, ctypes.c_long, ctypes.c_double]
        + [ctypes.c_long] * tail
    )
    return fn


class CReference:
    """`CReference.build()` compiles the kernel (None, with `.note`, when there is no compiler);
    `run(w0 (B, 3), q0 (B, 4), N, dt, moments)` returns `(w, q)` after N RK4 steps."""

    note: str | None = None

    def __init__(self, library: ctypes.CDLL, vectorization_report: str, command: str):
        self.function = bind(library, "free_body_rk4", 2)
        self.vectorization_report = vectorization_report
        self.vectorized = "loop vectorized" in vectorization_report
        self.command = command

    @classmethod
    def build(cls) -> CReference | None:
        built = build_library(SOURCE)
        if isinstance(built, str):
            cls.note = built
            return None
        return cls(*built)

    @staticmethod
    def pack(w0: np.ndarray, q0: np.ndarray, moments) -> tuple[np.ndarray, np.ndarray]:
        """The kernel's layout: state (7, B), coefficients (3, B)."""
        I1, I2, I3 = moments
        B = w0.shape[0]
        state = np.ascontiguousarray(np.concatenate([w0.T, q0.T]), dtype=np.float64)
        c = np.array([(I2 - I3) / I1, (I3 - I1) / I2, (I1 - I2) / I3])
        coef = np.ascontiguousarray(np.repeat(c[:, None], B, axis=1))
        return state, coef

    def advance(self, state: np.ndarray, coef: np.ndarray, N: int, dt: float) -> np.ndarray:
        """N steps in place on a packed state; returns it."""
        self.function(state.ctypes.data, coef.ctypes.data, state.shape[1], N, dt)
        return state

    def run(self, w0, q0, N: int, dt: float, moments) -> tuple[np.ndarray, np.ndarray]:
        state, coef = self.pack(w0, q0, moments)
        state = self.advance(state, coef, N, dt)
        return state[:3].T.copy(), state[3:].T.copy()


THREADS = 128


class CudaReference:
    """The CUDA references (`reference/models.cu`: one body per thread), built once per process
    by NVRTC through CuPy; `runner(name, state0 (N, B), par, steps, dt)` returns `run(fetch)`,
    which resets the state on the device, runs the kernel and synchronises."""

    def __init__(self):
        import cupy as cp

        self.cp = cp
        self.module = cp.RawModule(
            code=(REFERENCE / "models.cu").read_text(),
            options=("-std=c++17", f"-I{REFERENCE}"),
            backend="nvrtc",
        )

    def runner(self, name: str, state0: np.ndarray, par: np.ndarray, steps: int, dt: float):
        cp = self.cp
        kernel = self.module.get_function(f"{name}_rk4")
        B = state0.shape[1]
        x0 = cp.asarray(np.ascontiguousarray(state0))  # (N, B) rows, as the kernel reads them
        p = cp.asarray(np.ascontiguousarray(par))
        work = cp.empty_like(x0)
        grid = (-(-B // THREADS),)

        def run(fetch: bool = False):
            work[...] = x0
            kernel(grid, (THREADS,), (work, p, np.int64(B), np.int64(steps), np.float64(dt)))
            cp.cuda.Device().synchronize()
            return cp.asnumpy(work) if fetch else work

        return run
