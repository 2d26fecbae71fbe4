"""The hand-written C reference kernel (`reference/free_body.c`): built at benchmark time with
the system's C compiler, called in the same process through ctypes."""

from __future__ import annotations

import ctypes
import os
import shlex
import subprocess
import tempfile
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).resolve().parent / "reference" / "free_body.c"
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


def build_library(source: Path) -> tuple[ctypes.CDLL, str, str] | str:
    """`source` compiled with the system's C compiler ($CC) and loaded: the library, the
    compiler's vectorisation report and the command; or a note saying why not."""
    cc = shlex.split(os.environ.get("CC", "cc"))
    folder = Path(tempfile.mkdtemp(prefix="rigidjax-cref-"))
    out = folder / f"{source.stem}.so"
    cmd = [*cc, *FLAGS, "-fopt-info-vec-optimized", str(source), "-o", str(out)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.SubprocessError) as e:
        return f"no C compiler ({e}): the C reference rows are skipped"
    if done.returncode != 0:
        return f"building the C reference failed: {done.stderr[-1000:]}"
    report = "\n".join(line for line in done.stderr.splitlines() if "loop vectorized" in line)
    return ctypes.CDLL(str(out)), report, shlex.join(cmd)


class CReference:
    """`CReference.build()` compiles the kernel (None, with `.note`, when there is no compiler);
    `run(w0 (B, 3), q0 (B, 4), N, dt, moments)` returns `(w, q)` after N RK4 steps."""

    note: str | None = None

    def __init__(self, library: ctypes.CDLL, vectorization_report: str, command: str):
        self.function = library.free_body_rk4
        self.function.argtypes = [
            ctypes.c_void_p,
            ctypes.c_void_p,
            ctypes.c_long,
            ctypes.c_long,
            ctypes.c_double,
        ]
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
