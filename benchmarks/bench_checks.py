"""What the input checks of `simulate` cost: the validated call against the same program run
without its argument checks.

Problem: B torque-free bodies, principal moments (1, 2, 2.5), Ω0 ~ N(0, 1)³ and random unit
quaternions, float64, RK4 at fixed dt = 1e-3 with an output at each of the N steps (the worst
case for the per-interval finiteness check of the driver: one step per interval).

Contenders (timed in interleaved rounds, best of `--repeats`):
    ``validated``  `rigidjax.simulate(...)` called as users call it: every argument checked in
                   NumPy on the host (shapes, finite values, unit q0, increasing finite ts,
                   batch not empty), then the compiled solve, which also checks after each
                   output interval that the state is finite;
    ``traced``     the same `simulate` inside `jax.jit`, compiled ahead of time: the host
                   checks are not run (the arguments are tracers; `eqx.error_if` checks of the
                   arguments are compiled in), the in-loop finiteness check is.
    ``checks``     the host checks alone (the `rigidjax._checks` calls `simulate` makes).
    ``loop_check`` the driver's in-loop check alone: N finiteness reductions over a state of
                   the same shape in a compiled `lax.scan` (what the driver adds per interval).
`checks_share = checks / validated` and `loop_check_share = loop_check / traced` are the costs
of the checks (target < 5 % at realistic sizes, B ≥ 1000); `dispatch = validated / traced − 1`
is everything the eager call adds to the compiled program (the checks plus Python dispatch:
building the solver modules, Equinox's jit cache lookup), for reference.

Usage
    python benchmarks/bench_checks.py [--quick] [--repeats 5] [--seed 0]
        [--out benchmarks/results/checks.json]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import diffrax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _harness import Timing, finish, interleaved, load_average, machine_info, parser, timestamp  # noqa: E402

import rigidjax as rj  # noqa: E402
from rigidjax._checks import as_float, check_finite, check_times, check_unit_norm, vector  # noqa: E402

DT = 1e-3
MOMENTS = (1.0, 2.0, 2.5)


def inputs(B: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(B, 3))
    q = rng.normal(size=(B, 4))
    return w, q / np.linalg.norm(q, axis=-1, keepdims=True)


def simulate_fn(ts: np.ndarray):
    body = rj.RigidBody(jnp.array(MOMENTS))
    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=DT)

    def run(w, q):
        tr = rj.simulate(body, w, q, ts, **fixed)
        return tr.omega, tr.quat

    return run


def host_checks(w, q, ts):
    """The argument checks `simulate` makes on the host (rigidjax/mechanics/dynamics.py)."""
    ts = check_times(as_float(ts, "ts"))
    w = check_finite(vector(w, 3, "omega0").astype(ts.dtype), "omega0")
    q = check_unit_norm(vector(q, 4, "q0").astype(ts.dtype), "q0")
    return ts, w, q


def finiteness_scan(N: int):
    """N checks `all(isfinite(state))` on a state of simulate's fast-path layout (seven (B,)
    arrays), each depending on the previous so XLA cannot drop or merge them."""

    def run(w, q):
        y = (tuple(w.T), tuple(q.T))

        def body(carry, _):
            ok = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(carry)]))
            carry = jax.tree.map(lambda a: jnp.where(ok, a, a + 1), carry)
            return carry, ok

        return jax.lax.scan(body, y, None, length=N)[1]

    return run


def one_size(B: int, N: int, repeats: int, seed: int, log) -> dict:
    w, q = inputs(B, seed)
    ts_every = np.linspace(0.0, N * DT, N + 1)
    validated = Timing(simulate_fn(ts_every), w, q, aot=False)
    traced = Timing(simulate_fn(ts_every), w, q)
    checks = Timing(host_checks, w, q, ts_every, aot=False)
    loop = Timing(finiteness_scan(N), w, q)
    timings = {"validated": validated, "traced": traced, "checks": checks, "loop_check": loop}
    for t in timings.values():
        t.warm_up()
    interleaved(timings.values(), repeats)
    np.testing.assert_array_equal(validated.output[0], traced.output[0])  # the same program
    out = {name: t.summary() for name, t in timings.items()}
    out["B"], out["N"] = B, N
    out["checks_share"] = checks.best / validated.best
    out["loop_check_share"] = loop.best / traced.best
    out["dispatch"] = validated.best / traced.best - 1
    log(
        f"B={B:>6} N={N}: validated {validated.best * 1e3:9.3f} ms, traced "
        f"{traced.best * 1e3:9.3f} ms; host checks {checks.best * 1e3:7.3f} ms "
        f"({out['checks_share']:.1%}), in-loop checks {loop.best * 1e3:7.3f} ms "
        f"({out['loop_check_share']:.1%}); eager call vs compiled {out['dispatch']:+.1%}"
    )
    return out


def main(argv=None) -> int:
    quick = "B in (1, 1000), N = 200: smoke run"
    args = parser(__doc__, "checks.json", quick=quick, repeats=5, seed=True).parse_args(argv)
    sizes = [(1, 200), (1000, 200)] if args.quick else [(1, 1000), (1000, 1000), (100_000, 200)]
    t0 = time.perf_counter()
    out = {
        "benchmark": "bench_checks",
        "timestamp": timestamp(),
        "quick": args.quick,
        "parameters": {"dt": DT, "moments": MOMENTS, "seed": args.seed, "repeats": args.repeats},
        "machine": machine_info(),
        "load_average_start": load_average(),
    }
    out["results"] = [one_size(B, N, args.repeats, args.seed, print) for B, N in sizes]
    finish(out, args.out, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
