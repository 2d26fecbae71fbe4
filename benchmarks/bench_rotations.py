"""Throughput of rigidjax's rotation maps against SciPy and jax.scipy on N rotations.

What is measured
    For each map (rotvec→matrix, matrix→rotvec, matrix→quat, quat→matrix, Euler→matrix and
    matrix→Euler for "ZXZ" and "xyz"), the wall-clock time to convert N rotations at once with

    * ``scipy.spatial.transform.Rotation`` (float64, NumPy in → NumPy out, constructor included:
      e.g. ``Rotation.from_rotvec(x).as_matrix()``),
    * ``rigidjax`` (``so3.exp``, ``so3.log``, ``quat.from_matrix``, ``quat.to_matrix``,
      ``euler.to_matrix``, ``euler.from_matrix``) under ``jax.jit``, float64 and float32,
    * ``jax.scipy.spatial.transform.Rotation`` under ``jax.jit``, float64 and float32 (skipped,
      and recorded as unavailable in the JSON, if the installed JAX lacks it).

    The functions completed against SciPy (issue 17) are timed against SciPy in the same run
    (``extras`` in the JSON; rigidjax under ``jax.jit`` in float64, ``--n-extra`` rotations):
    ``quat.align_vectors`` (one problem of ``--n-extra`` vector pairs; 1000 problems of 8 pairs,
    ``jax.vmap`` against a SciPy loop), ``RotationSpline`` (100 keys: construction plus
    attitude, rate and acceleration at ``--n-extra`` times), ``Slerp`` (100 keys), ``quat.power``,
    ``quat.magnitude``, ``quat.approx_equal``, ``quat.reduce`` (octahedral group on both sides,
    at most 5000 rotations) and ``euler.to_quat`` of a 2-axis sequence in degrees.

How
    All libraries get the same inputs: N uniformly random rotations (seeded), expressed as
    rotation vectors, matrices, quaternions (SciPy's x, y, z, w order; rigidjax's w, x, y, z) and
    Euler angles. JAX inputs are placed on the device beforehand, so transfers are not timed. Each
    JAX function is lowered and compiled ahead of time (reported as ``compile_s``), called once to
    warm up, then timed ``--repeats`` times with ``block_until_ready``; SciPy is timed the same way
    after one warm-up call. Rates use the best (minimum) time; the median is also recorded.
    ``max_abs_diff_vs_scipy`` compares each JAX result with SciPy's float64 result: quaternions up
    to sign, rotation vectors up to the θ ↔ −θ ambiguity at |θ| = π, angles modulo 2π.

Usage
    python benchmarks/bench_rotations.py [--n 1000000] [--n-extra 100000] [--repeats 5]
        [--out benchmarks/results/rotations.json]
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import jax

jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _harness import Log, Timing, finish, machine_info, measure, parser, table, timestamp  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402
from scipy.spatial.transform import RotationSpline as SciPySpline  # noqa: E402
from scipy.spatial.transform import Slerp as SciPySlerp  # noqa: E402

from rigidjax import RotationSpline, Slerp, euler, quat, so3  # noqa: E402

try:
    from jax.scipy.spatial.transform import Rotation as JaxRotation  # noqa: E402
except ImportError as _e:  # pragma: no cover - depends on the installed JAX
    JaxRotation = None
    JAX_SCIPY_NOTE = f"jax.scipy.spatial.transform.Rotation not importable: {_e}"
else:
    JAX_SCIPY_NOTE = "jax.scipy.spatial.transform.Rotation available"

DTYPES = {"float64": jnp.float64, "float32": jnp.float32}


# --------------------------------------------------------------------------- operations


@dataclass(frozen=True)
class Op:
    """One rotation map in the three libraries: ``convert(R, x)`` is the SciPy expression with
    ``R`` the ``Rotation`` class (SciPy's, or jax.scipy's if installed: the same code).

    ``scipy_in``/``rigidjax_in`` name the input arrays (they differ only in quaternion order);
    ``rigidjax_post`` maps rigidjax's output to SciPy's convention before comparison; ``compare``
    selects the difference measure (``plain``, ``rotvec``, ``quat`` or ``angle``).
    """

    name: str
    scipy_in: str
    convert: Callable
    rigidjax_fn: Callable
    compare: str = "plain"
    rigidjax_post: Callable = staticmethod(lambda y: y)
    rigidjax_in: str = ""  # if not scipy_in

    def scipy_fn(self, x):
        return self.convert(Rotation, x)

    @property
    def jax_scipy_fn(self) -> Callable | None:
        return None if JaxRotation is None else lambda x: self.convert(JaxRotation, x)


def _wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    return np.roll(q, -1, axis=-1)


def build_ops() -> list[Op]:
    """The benchmarked maps, in table order."""
    ops = [
        Op("rotvec_to_matrix", "rotvec", lambda R, x: R.from_rotvec(x).as_matrix(), so3.exp),
        Op("matrix_to_rotvec", "matrix", lambda R, x: R.from_matrix(x).as_rotvec(), so3.log,
           compare="rotvec"),
        Op("matrix_to_quat", "matrix", lambda R, x: R.from_matrix(x).as_quat(), quat.from_matrix,
           compare="quat", rigidjax_post=_wxyz_to_xyzw),
        Op("quat_to_matrix", "quat_xyzw", lambda R, x: R.from_quat(x).as_matrix(),
           quat.to_matrix, rigidjax_in="quat_wxyz"),
    ]  # fmt: skip
    for seq in ("ZXZ", "xyz"):
        ops += [
            Op(f"euler_to_matrix_{seq}", f"euler_{seq}",
               lambda R, x, seq=seq: R.from_euler(seq, x).as_matrix(),
               lambda x, seq=seq: euler.to_matrix(x, seq)),
            Op(f"matrix_to_euler_{seq}", "matrix",
               lambda R, x, seq=seq: R.from_matrix(x).as_euler(seq),
               lambda x, seq=seq: euler.from_matrix(x, seq), compare="angle"),
        ]  # fmt: skip
    return ops


# --------------------------------------------------------------------------- inputs


def make_inputs(n: int, seed: int) -> dict[str, np.ndarray]:
    """N uniformly random rotations in every representation the ops consume (float64)."""
    r = Rotation.random(n, rng=np.random.default_rng(seed))
    q_xyzw = r.as_quat()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gimbal-lock warnings are irrelevant for inputs
        eul = {f"euler_{s}": r.as_euler(s) for s in ("ZXZ", "xyz")}
    return {
        "rotvec": r.as_rotvec(),
        "matrix": r.as_matrix(),
        "quat_xyzw": q_xyzw,
        "quat_wxyz": np.roll(q_xyzw, 1, axis=-1),
        **eul,
    }


# --------------------------------------------------------------------------- timing


def _rates(t: Timing, n: int) -> dict:
    return {**t.summary(), "rotations_per_s": n / t.best}


def time_scipy(fn: Callable, x: np.ndarray, repeats: int) -> tuple[dict, np.ndarray]:
    """Time a NumPy → NumPy SciPy call after one warm-up call; returns the summary and result."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SciPy warns on gimbal lock in as_euler
        t = measure(fn, x, repeats=repeats, aot=False)
    return _rates(t, len(x)), t.output


def time_jax(fn: Callable, x: np.ndarray, dtype, repeats: int) -> tuple[dict, np.ndarray]:
    """AOT-compile `fn` for `x` cast to `dtype`, warm up once, then time `repeats` calls."""
    xd = jax.device_put(jnp.asarray(x, dtype=dtype))
    t = measure(fn, xd, repeats=repeats)
    summary = _rates(t, len(x))
    summary["compile_s"] = t.trace_lower_compile_s
    summary["output_dtype"] = str(t.output.dtype)
    return summary, np.asarray(t.output, dtype=np.float64)


# --------------------------------------------------------------------------- accuracy


def _wrap(d: np.ndarray) -> np.ndarray:
    return (d + np.pi) % (2 * np.pi) - np.pi


def max_abs_diff(y: np.ndarray, ref: np.ndarray, kind: str) -> float:
    """Largest absolute deviation from SciPy's result, modulo the representation's ambiguity."""
    n = len(ref)
    d = np.abs(y - ref).reshape(n, -1).max(axis=1)
    if kind == "quat":  # q and −q are the same rotation
        d = np.minimum(d, np.abs(y + ref).reshape(n, -1).max(axis=1))
    elif kind == "rotvec":  # at |θ| = π, θ and −θ are the same rotation
        near_pi = np.linalg.norm(ref, axis=-1) > 3.0
        flipped = np.abs(y + ref).max(axis=1)
        d = np.where(near_pi, np.minimum(d, flipped), d)
    elif kind == "angle":
        d = np.abs(_wrap(y - ref)).max(axis=1)
    return float(d.max())


# --------------------------------------------------------------------------- extras (issue 17)


@dataclass(frozen=True)
class Extra:
    """A function completed against SciPy: SciPy's and rigidjax's callables on the same inputs
    (rigidjax's compiled with `jax.jit`), `size` items per call, and the maximum deviation
    between their (float64) outputs, measured by `diff`."""

    name: str
    scipy_fn: Callable
    rigidjax_fn: Callable
    scipy_args: tuple
    size: int
    diff: Callable
    rigidjax_args: tuple | None = None  # if not scipy_args


def _q_diff(y, ref) -> float:
    """Largest deviation of quaternions (..., 4) up to sign."""
    y, ref = np.asarray(y), np.asarray(ref)
    return float(np.minimum(np.abs(y - ref).max(-1), np.abs(y + ref).max(-1)).max())


def _plain_diff(y, ref) -> float:
    return float(np.max(np.abs(np.asarray(y, dtype=np.float64) - np.asarray(ref, np.float64))))


def _spline_diff(y, ref) -> float:
    return max(_q_diff(y[0], ref[0]), _plain_diff(y[1], ref[1]), _plain_diff(y[2], ref[2]))


def build_extras(n: int, seed: int) -> list[Extra]:
    rng = np.random.default_rng(seed)
    r = Rotation.random(n, rng=rng)
    s = Rotation.random(n, rng=rng)
    q, q2 = r.as_quat(scalar_first=True), s.as_quat(scalar_first=True)
    a = rng.normal(size=(n, 3))
    b = Rotation.random(rng=rng).apply(a) + 0.01 * rng.normal(size=(n, 3))
    w = rng.uniform(0.5, 2.0, n)
    ab = rng.normal(size=(1000, 8, 3))
    bb = ab + 0.05 * rng.normal(size=(1000, 8, 3))
    keys = Rotation.random(100, rng=rng)
    kt = np.cumsum(rng.uniform(0.5, 1.5, 100))
    kq = keys.as_quat(scalar_first=True)
    t = np.sort(rng.uniform(kt[0], kt[-1], n))
    g = Rotation.create_group("O")
    gq = g.as_quat(scalar_first=True)
    eul = rng.uniform(-180, 180, (n, 2))
    n_reduce = min(n, 5000)

    def sp_spline(kt, keys, t):
        sp = SciPySpline(kt, keys)
        return sp(t).as_quat(scalar_first=True), sp(t, 1), sp(t, 2)

    def rj_spline(kt, kq, t):
        sp = RotationSpline(kt, kq)
        return sp(t), sp(t, 1), sp(t, 2)

    def sp_align_many(a, b):
        return np.stack(
            [
                Rotation.align_vectors(x, y)[0].as_quat(scalar_first=True)
                for x, y in zip(a, b, strict=True)
            ]
        )

    return [
        Extra(
            "align_vectors",
            lambda a, b, w: Rotation.align_vectors(a, b, w)[0].as_quat(scalar_first=True),
            lambda a, b, w: quat.align_vectors(a, b, w)[0],
            (a, b, w),
            n,
            _q_diff,
        ),
        Extra(
            "align_vectors_1000x8",
            sp_align_many,
            jax.vmap(lambda a, b: quat.align_vectors(a, b)[0]),
            (ab, bb),
            1000,
            _q_diff,
        ),
        Extra(
            "rotation_spline_100_keys",
            sp_spline,
            rj_spline,
            (kt, keys, t),
            n,
            _spline_diff,
            (kt, kq, t),
        ),
        Extra(
            "slerp_100_keys",
            lambda kt, keys, t: SciPySlerp(kt, keys)(t).as_quat(scalar_first=True),
            lambda kt, kq, t: Slerp(kt, kq)(t),
            (kt, keys, t),
            n,
            _q_diff,
            (kt, kq, t),
        ),
        Extra(
            "power_0.5",
            lambda x: (Rotation.from_quat(x, scalar_first=True) ** 0.5).as_quat(scalar_first=True),
            lambda x: quat.power(x, 0.5),
            (q,),
            n,
            _q_diff,
        ),
        Extra(
            "magnitude",
            lambda x: Rotation.from_quat(x, scalar_first=True).magnitude(),
            quat.magnitude,
            (q,),
            n,
            _plain_diff,
        ),
        Extra(
            "approx_equal",
            lambda x, y: Rotation.from_quat(x, scalar_first=True).approx_equal(
                Rotation.from_quat(y, scalar_first=True), 0.5
            ),
            lambda x, y: quat.approx_equal(x, y, 0.5),
            (q, q2),
            n,
            _plain_diff,
        ),
        Extra(  # SciPy's reduce runs ~2e3 rotations/s for O × O: fewer rotations
            "reduce_O_O",
            lambda x: Rotation.from_quat(x, scalar_first=True).reduce(g, g).magnitude(),
            lambda x: quat.magnitude(quat.reduce(x, gq, gq)),
            (q[:n_reduce],),
            n_reduce,
            _plain_diff,
        ),
        Extra(
            "euler_to_quat_xy_degrees",
            lambda x: Rotation.from_euler("xy", x, degrees=True).as_quat(scalar_first=True),
            lambda x: euler.to_quat(x, "xy", degrees=True),
            (eul,),
            n,
            _q_diff,
        ),
    ]


def bench_extra(e: Extra, repeats: int) -> dict:
    """SciPy (NumPy in, NumPy out) and rigidjax (`jax.jit`, float64, inputs on the device)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ts = measure(e.scipy_fn, *e.scipy_args, repeats=repeats, aot=False)
    args = [jax.device_put(jnp.asarray(x)) for x in (e.rigidjax_args or e.scipy_args)]
    tr = measure(e.rigidjax_fn, *args, repeats=repeats)
    sp = {**ts.summary(), "items_per_s": e.size / ts.best}
    rj = {
        **tr.summary(),
        "items_per_s": e.size / tr.best,
        "compile_s": tr.trace_lower_compile_s,
        "max_abs_diff_vs_scipy": e.diff(tr.output, ts.output),
    }
    return {"items": e.size, "scipy": sp, "rigidjax": rj, "ratio_vs_scipy": sp["seconds"] / tr.best}


def extra_table(extras: dict) -> str:
    columns = [("function (float64)", "<26"), ("items", ">9"), ("SciPy/s", ">12.3g"),
               ("rigidjax/s", ">12.3g"), ("rj/SciPy", ">10.2f"), ("compile", ">9.2f"),
               ("diff", ">10.1e")]  # fmt: skip
    rows = [[name, r["items"], r["scipy"]["items_per_s"], rj["items_per_s"], r["ratio_vs_scipy"],
             rj["compile_s"], rj["max_abs_diff_vs_scipy"]]
            for name, r in extras.items() for rj in [r["rigidjax"]]]  # fmt: skip
    return table(columns, rows)


# --------------------------------------------------------------------------- driver


def _ratio(a: dict | None, b: dict | None) -> float | None:
    if a is None or b is None:
        return None
    return a["rotations_per_s"] / b["rotations_per_s"]


def bench_dtype(op: Op, inputs: dict, dtype, repeats: int, ref: np.ndarray, sp: dict) -> dict:
    """rigidjax and jax.scipy results for one op at one dtype, with ratios and accuracy."""
    rj, y = time_jax(op.rigidjax_fn, inputs[op.rigidjax_in or op.scipy_in], dtype, repeats)
    rj["max_abs_diff_vs_scipy"] = max_abs_diff(op.rigidjax_post(y), ref, op.compare)
    js = None
    if op.jax_scipy_fn is not None:
        js, yj = time_jax(op.jax_scipy_fn, inputs[op.scipy_in], dtype, repeats)
        js["max_abs_diff_vs_scipy"] = max_abs_diff(yj, ref, op.compare)
    return {
        "rigidjax": rj,
        "jax_scipy": js,
        "ratio_vs_scipy": _ratio(rj, sp),
        "ratio_vs_jax_scipy": _ratio(rj, js),
        "jax_scipy_ratio_vs_scipy": _ratio(js, sp),
    }


def bench_op(op: Op, inputs: dict, repeats: int) -> dict:
    sp, ref = time_scipy(op.scipy_fn, inputs[op.scipy_in], repeats)
    result = {"scipy": sp}
    for name, dtype in DTYPES.items():
        result[name] = bench_dtype(op, inputs, dtype, repeats, ref, sp)
    return result


def ops_table(results: dict) -> str:
    columns = [("op", "<22"), ("dtype", "<9"), ("SciPy", ">9.2f"), ("rigidjax", ">10.2f"),
               ("jax.sp", ">9.2f"), ("rj/SciPy", ">10.2f"), ("rj/jax.sp", ">11.2f"),
               ("compile rj", ">12.3f"), ("compile js", ">12.3f"), ("diff rj", ">10.1e"),
               ("diff js", ">10.1e")]  # fmt: skip

    def rate(entry: dict | None):  # 10⁶ rotations/s
        return None if entry is None else entry["rotations_per_s"] / 1e6

    rows = []
    for name, r in results.items():
        for dt in DTYPES:
            d = r[dt]
            rj, js = d["rigidjax"], d["jax_scipy"] or {}
            rows.append([name, dt, rate(r["scipy"]), rate(rj), rate(d["jax_scipy"]),
                         d["ratio_vs_scipy"], d["ratio_vs_jax_scipy"], rj["compile_s"],
                         js.get("compile_s"), rj["max_abs_diff_vs_scipy"],
                         js.get("max_abs_diff_vs_scipy")])  # fmt: skip
    return table(columns, rows)


def main(argv: list[str] | None = None) -> dict:
    p = parser(__doc__, "rotations.json", repeats=5, seed=True)
    p.add_argument("--n", type=int, default=1_000_000, help="number of rotations")
    p.add_argument(
        "--n-extra", type=int, default=100_000, help="rotations / times / vector pairs (extras)"
    )
    args = p.parse_args(argv)
    log = Log()
    inputs = make_inputs(args.n, args.seed)
    results = {}
    for op in build_ops():
        results[op.name] = bench_op(op, inputs, args.repeats)
        log(f"  done {op.name}")
    extras = {}
    for e in build_extras(args.n_extra, args.seed):
        extras[e.name] = bench_extra(e, args.repeats)
        log(f"  done {e.name}")
    report = {
        "benchmark": "rotations",
        "timestamp": timestamp(),
        "n": args.n,
        "repeats": args.repeats,
        "seed": args.seed,
        "timing_statistic": "best of repeats (seconds); median in seconds_median",
        "jax_scipy_rotation": {"available": JaxRotation is not None, "note": JAX_SCIPY_NOTE},
        "machine": machine_info(),
        "load_average_start": log.load_start,
        "ops": results,
        "n_extra": args.n_extra,
        "extras": extras,
    }
    print(f"N = {args.n}, rates in 10⁶ rotations/s (best of {args.repeats}); diff = max |Δ|")
    print(ops_table(results))
    print(f"\nCompleted against SciPy: items/s (best of {args.repeats}), diff = max |Δ| vs SciPy")
    print(extra_table(extras))
    finish(report, args.out, log.t0)
    return report


if __name__ == "__main__":
    main()
