"""First calls of the rotation maps against jaxlie: what an eager call, and an eager
`jax.jacfwd`/`jax.jacrev` of it, costs in a process that has just started JAX (issue 26).

Each measurement runs in a fresh Python process (`fresh_process`): import JAX, rigidjax and
jaxlie, enable float64, start the CPU backend (one tiny computation), then time the first call
`f(x)` to completion and, for reference, the second. `x` is a 3×3 half-turn `2nnᵀ − E` about
n = (1, 2, 2)/3 for the matrix maps, its rotation vector, quaternion or `xyz` angles for the
others. jaxlie (eager, op by op) is measured in the same run, interleaved with rigidjax
(`--repeats` rounds, each running every process once); `seconds` is the best of the rounds,
`ratio = rigidjax / jaxlie` of the bests. A map without a jaxlie counterpart (`mrp.from_matrix`)
is compared with the jaxlie code a user would write for the same output (`SO3.from_matrix`, its
quaternion's sign made canonical, then `λ/(1 + λ0)`).

Usage
    python benchmarks/bench_first_call.py [--repeats 3] [--out benchmarks/results/first_call.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import finish, fresh_process, load_average, machine_info, parser  # noqa: E402

DERIVATIVES = ("value", "jacfwd", "jacrev")

# map name -> (input kind, jaxlie counterpart as text)
MAPS = {
    "quat.from_matrix": ("matrix", "SO3.from_matrix(P).wxyz"),
    "so3.log": ("matrix", "SO3.from_matrix(P).log()"),
    "mrp.from_matrix": ("matrix", "q = canonical(SO3.from_matrix(P).wxyz); q[1:] / (1 + q[0])"),
    "so3.distance(E, P)": ("matrix", "norm((SO3.identity().inverse() @ SO3.from_matrix(P)).log())"),
    "euler.from_matrix(P, 'xyz')": ("matrix", "stack(SO3.from_matrix(P).as_rpy_radians())"),
    "so3.exp": ("rotvec", "SO3.exp(theta).as_matrix()"),
    "quat.to_matrix": ("quat", "SO3(wxyz=q).as_matrix()"),
    "euler.to_matrix(a, 'xyz')": ("angles", "SO3.from_rpy_radians(*a).as_matrix()"),
}


def _jaxlie_mrp(P):
    """MRP of P with jaxlie: its quaternion, of λ0 ≥ 0, then `λ/(1 + λ0)`."""
    import jax.numpy as jnp
    import jaxlie

    q = jaxlie.SO3.from_matrix(P).wxyz
    q = jnp.where(q[0] < 0, -q, q)
    return q[1:] / (1 + q[0])


def _functions(name: str):
    """`(rigidjax function, jaxlie function)` of map `name` (imported in the worker only)."""
    import jax.numpy as jnp
    import jaxlie

    import rigidjax as rj

    SO3 = jaxlie.SO3
    return {
        "quat.from_matrix": (rj.quat.from_matrix, lambda P: SO3.from_matrix(P).wxyz),
        "so3.log": (rj.so3.log, lambda P: SO3.from_matrix(P).log()),
        "mrp.from_matrix": (rj.mrp.from_matrix, _jaxlie_mrp),
        "so3.distance(E, P)": (
            lambda P: rj.so3.distance(jnp.eye(3), P),
            lambda P: jnp.linalg.norm((SO3.identity().inverse() @ SO3.from_matrix(P)).log()),
        ),
        "euler.from_matrix(P, 'xyz')": (
            lambda P: rj.euler.from_matrix(P, "xyz"),
            lambda P: jnp.stack(SO3.from_matrix(P).as_rpy_radians()),
        ),
        "so3.exp": (rj.so3.exp, lambda t: SO3.exp(t).as_matrix()),
        "quat.to_matrix": (rj.quat.to_matrix, lambda q: SO3(wxyz=q).as_matrix()),
        "euler.to_matrix(a, 'xyz')": (
            lambda a: rj.euler.to_matrix(a, "xyz"),
            lambda a: SO3.from_rpy_radians(a[0], a[1], a[2]).as_matrix(),
        ),
    }[name]


def _input(kind: str):
    """The half-turn about n = (1, 2, 2)/3 in the form `kind` (NumPy, float64)."""
    import numpy as np

    n = np.array([1.0, 2.0, 2.0]) / 3
    P = 2 * np.outer(n, n) - np.eye(3)
    return {
        "matrix": P,
        "rotvec": np.pi * n,
        "quat": np.concatenate([[0.0], n]),
        "angles": np.array([0.3, -0.4, 2.5]),  # any angles: no half-turn form in xyz needed
    }[kind]


def worker(lib: str, name: str, derivative: str) -> None:
    """Time the first and second call of `derivative` of map `name` of `lib`; print JSON."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    rj_f, jl_f = _functions(name)
    f = rj_f if lib == "rigidjax" else jl_f
    g = {"value": f, "jacfwd": jax.jacfwd(f), "jacrev": jax.jacrev(f)}[derivative]
    x = jnp.asarray(_input(MAPS[name][0]))
    jax.block_until_ready(jnp.ones(3) + 1)  # the backend is started: not part of the timing
    t0 = time.perf_counter()
    out = jax.block_until_ready(g(x))
    t1 = time.perf_counter()
    jax.block_until_ready(g(x))
    t2 = time.perf_counter()
    print(json.dumps({"first_s": t1 - t0, "second_s": t2 - t1, "shape": list(out.shape)}))


def check_agreement(name: str) -> float | None:
    """Largest difference between rigidjax's and jaxlie's values."""
    import numpy as np

    rj_f, jl_f = _functions(name)
    x = _input(MAPS[name][0])
    a, b = np.asarray(rj_f(x)), np.asarray(jl_f(x))
    if name == "quat.from_matrix":  # q and -q are one rotation
        b = b * np.sign(b @ a)
    if name == "so3.log":  # at a half-turn θ and -θ are one rotation
        b = b * np.sign(b @ a)
    return float(np.max(np.abs(a - b)))


def main(argv=None) -> int:
    p = parser(__doc__, "first_call.json")
    p.add_argument("--maps", nargs="*", default=list(MAPS), help="a subset of the maps")
    p.add_argument(
        "--worker", nargs=3, metavar=("LIB", "MAP", "DERIVATIVE"), help=argparse.SUPPRESS
    )
    args = p.parse_args(argv)
    if args.worker:
        worker(*args.worker)
        return 0

    import jax

    jax.config.update("jax_enable_x64", True)
    t0 = time.perf_counter()
    out = {
        "benchmark": "bench_first_call",
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "parameters": {"repeats": args.repeats, "dtype": "float64", "input": "half-turn"},
        "timing_statistic": "best of the rounds (each a fresh process per measurement)",
        "machine": machine_info(),
        "load_average_start": load_average(),
    }
    results = []
    for name in args.maps:
        entry = {"map": name, "jaxlie": MAPS[name][1], "max_abs_diff": check_agreement(name)}
        for d in DERIVATIVES:
            times = {"rigidjax": [], "jaxlie": []}
            for _ in range(args.repeats):
                for lib in times:
                    res, _, proc = fresh_process(__file__, "--worker", lib, name, d)
                    if res is None:
                        raise RuntimeError(f"{lib} {name} {d} failed:\n{proc.stderr[-3000:]}")
                    times[lib].append(res["first_s"])
            best = {lib: min(t) for lib, t in times.items()}
            entry[d] = {
                **{f"{lib}_seconds": best[lib] for lib in times},
                **{f"{lib}_seconds_median": statistics.median(t) for lib, t in times.items()},
                **{f"{lib}_all_seconds": t for lib, t in times.items()},
                "ratio": best["rigidjax"] / best["jaxlie"],
            }
            print(
                f"{name:28s} {d:7s} rigidjax {best['rigidjax']:6.3f} s  jaxlie "
                f"{best['jaxlie']:6.3f} s  ratio {entry[d]['ratio']:5.2f}",
                flush=True,
            )
        results.append(entry)
    out["results"] = results
    finish(out, args.out, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
