"""Every model on a GPU: rigidjax's Pallas kernel (the JAX field evaluated on register vectors,
`rigidjax.kernels.model_pallas`) against hand-written CUDA kernels of the same models and against
the Diffrax path on the same GPU, with gradients and first calls.

Problem
    As bench_models.py (its `models`): B bodies with their own principal moments, random Ω0 and
    q0, N RK4 steps of dt (1e-3; the satellite 1 s), the quaternion renormalised after each,
    float64. Models: free_body, damping, gravity_gradient, heavy_top, sixdof, satellite,
    gyrostat.

Parts (one run, on the default JAX backend: a GPU)
    speed     Each model's fast path (``solver=RK4()``: on a GPU, the Pallas kernel), its CUDA C
              reference (``benchmarks/reference/models.cu``, the right-hand sides of models.c,
              one body per thread, built by NVRTC through CuPy) and its Diffrax path
              (``solver=ExplicitRK(RK4())``: XLA's loop over the whole batch), timed in
              interleaved rounds (best of --repeats) after checking that their final states
              agree. Recorded: rates, ratios (Pallas / CUDA ≥ 0.8 wanted).
    gradient  ``jax.value_and_grad`` of a loss of the final states w.r.t. the moments (the heavy
              top: its centre of mass), over the forward run: the Pallas kernel's own adjoint,
              and the same steps through Diffrax, whose gradients it must equal.
    first     The first forward call of the gravity-gradient model (trace, the kernel's one-time
              check against Pallas' interpreter, Triton compile, run), in this process.
    adaptive  At a tolerance, bench_adaptive.py's problem (|Ω0| log-uniform in 0.1–3 rad/s,
              t ∈ [0, 20], 21 output times, rtol = atol = 1e-8; free body and attitude torque)
              on --adaptive-bodies bodies: ``simulate`` (on a GPU the adaptive Pallas kernel,
              each body its own steps; ``pallas`` records whether it was served) and
              ``jax.vmap(simulate)`` against the Diffrax path (``solver=ExplicitRK(Tsit5())``,
              each body its own steps through XLA): ``speedup_over_diffrax_path`` (≥ 2 wanted
              at 1e6 bodies) and ``max_diff_vs_diffrax_path`` (the same steps: ~1e-12); and
              ``jax.grad`` of ``sum |Ω(20)|² + sum |q_vec(20)|²`` w.r.t. (moments, Ω0) over
              its forward (the Pallas reverse kernel; ≤ 4 wanted) and through the Diffrax path.

Usage
    python benchmarks/bench_gpu.py [--bodies 1000000] [--steps 1000] [--repeats 5]
        [--parts first,speed,gradient,adaptive] [--models all] [--adaptive-bodies 1000000]
        [--out benchmarks/results/gpu.json]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _c_reference import CudaReference  # noqa: E402
from _harness import Log, finish, interleaved, machine_info, measure, parser  # noqa: E402
from bench_adaptive import (  # noqa: E402
    MODELS,
    N_OUT,
    T_END,
    TOL,
    attitude_torque,
    final_state_loss,
    inputs,
    jax_calls,
)
from bench_models import models  # noqa: E402

CUDA_MODELS = ("free_body", "damping", "gravity_gradient", "heavy_top", "sixdof", "satellite",
               "gyrostat", "darboux_quat", "darboux_rotvec")  # fmt: skip
"""The models with a CUDA reference (models.cu); the closed loop has none (its Pallas kernel, with
the sampled command's jump map, is timed against the Diffrax path only)."""


def speed(B: int, steps: int, repeats: int, log, names: str = "all") -> tuple[dict, dict]:
    import jax

    import rigidjax as rj

    table, _ = models(B, steps)
    if names != "all":  # a comma-separated subset
        table = {k: v for k, v in table.items() if k in names.split(",")}
    slow, _ = models(B, steps, rj.ExplicitRK(rj.RK4()))
    try:
        cuda, note = CudaReference(), None
    except Exception as e:  # no CuPy, no NVRTC: the CUDA rows are skipped
        cuda, note = None, f"{type(e).__name__}: {e}"
    rows = {}
    for name, (fn, args, state0, par, dt) in table.items():
        row: dict = {}
        try:
            t_fast = measure(jax.jit(fn), *args, repeats=1)
            t_slow = measure(jax.jit(slow[name][0]), *args, repeats=1)
            fast = np.asarray(t_fast.output)
            row["max_abs_difference_diffrax"] = float(np.max(np.abs(fast - t_slow.output)))
            row["pallas_served"] = "pallas_call" in str(jax.make_jaxpr(fn)(*args))
            timings, t_cuda = [t_fast, t_slow], None
            if cuda is not None and name in CUDA_MODELS:
                run = cuda.runner(name, np.asarray(state0, np.float64), par, steps, dt)
                ref = run(fetch=True)
                row["max_abs_difference_cuda"] = float(np.max(np.abs(fast - ref.T)))
                t_cuda = measure(run, repeats=1, aot=False)
                timings.append(t_cuda)
            interleaved(timings, repeats)
            row.update(
                pallas_body_steps_per_s=B * steps / t_fast.best,
                diffrax_body_steps_per_s=B * steps / t_slow.best,
                pallas_over_diffrax=t_slow.best / t_fast.best,
                pallas=t_fast.summary(),
                diffrax=t_slow.summary(),
                pallas_trace_compile_s=t_fast.trace_lower_compile_s,
            )
            if t_cuda is not None:
                row.update(
                    cuda_body_steps_per_s=B * steps / t_cuda.best,
                    ratio_pallas_over_cuda=t_cuda.best / t_fast.best,
                    cuda=t_cuda.summary(),
                )
            log(
                f"{name}: pallas {row['pallas_body_steps_per_s']:.3g}/s, diffrax "
                f"{row['diffrax_body_steps_per_s']:.3g}/s, cuda "
                f"{row.get('cuda_body_steps_per_s', float('nan')):.3g}/s, pallas/cuda "
                f"{row.get('ratio_pallas_over_cuda', float('nan')):.2f}"
            )
        except Exception as e:  # recorded, and the other models still run
            row["error"] = f"{type(e).__name__}: {str(e)[:2000]}"
            log(f"{name}: {row['error'][:300]}")
        rows[name] = row
    return dict(models=rows, cuda_note=note), table


def gradient(B: int, steps: int, repeats: int, log, only: str = "all") -> dict:
    """value-and-grad over forward w.r.t. the moments: the Pallas kernel's own adjoint, and the
    same steps through Diffrax (``ExplicitRK(RK4())``), whose gradients it must equal."""
    import jax
    import jax.numpy as jnp

    import rigidjax as rj

    names = [
        n
        for n in ("damping", "gravity_gradient", "heavy_top")
        if only == "all" or n in only.split(",")
    ]
    table = {k: v for k, v in models(B, steps)[0].items() if k in names}
    slow = models(B, steps, rj.ExplicitRK(rj.RK4()))[0]
    out = {}
    for name in table:
        fn, args = table[name][0], table[name][1]
        argnum = 1 if name == "heavy_top" else 0  # the centre of mass; else the moments

        def loss(*a, fn=fn):
            return jnp.sum(fn(*a) ** 2)

        def loss_slow(*a, fn=slow[name][0]):
            return jnp.sum(fn(*a) ** 2)

        try:
            fwd = measure(jax.jit(loss), *args, repeats=1)
            vg = measure(jax.jit(jax.value_and_grad(loss, argnums=argnum)), *args, repeats=1)
            vg_slow = measure(
                jax.jit(jax.value_and_grad(loss_slow, argnums=argnum)), *args, repeats=1
            )
            interleaved([fwd, vg, vg_slow], repeats)
            g, g_slow = np.asarray(vg.output[1]), np.asarray(vg_slow.output[1])
            out[name] = dict(
                forward_s=fwd.best,
                value_and_grad_s=vg.best,
                ratio=vg.best / fwd.best,
                diffrax_value_and_grad_s=vg_slow.best,
                diffrax_ratio=vg_slow.best / fwd.best,
                max_rel_difference_diffrax=float(
                    np.max(np.abs(g - g_slow)) / np.max(np.abs(g_slow))
                ),
            )
            log(
                f"gradient {name}: {vg.best / fwd.best:.2f}x forward (through Diffrax "
                f"{vg_slow.best / fwd.best:.1f}x), max rel diff "
                f"{out[name]['max_rel_difference_diffrax']:.1e}"
            )
        except Exception as e:
            out[name] = dict(error=f"{type(e).__name__}: {str(e)[:2000]}")
            log(f"gradient {name}: {out[name]['error'][:300]}")
    return out


def first_call(log) -> dict:
    """The first call of a new model (a torque not seen before in this process)."""
    import diffrax
    import jax
    import jax.numpy as jnp

    import rigidjax as rj

    e_z, I0 = jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 2.0, 3.0])

    def torque(t, w, q):
        c = rj.quat.to_matrix(q).T @ e_z
        return 2e-4 * jnp.cross(c, I0 * c) - 1e-3 * w

    B = 1000
    rng = np.random.default_rng(3)
    q = rng.normal(size=(B, 4))
    w, q = rng.normal(size=(B, 3)), q / np.linalg.norm(q, axis=1, keepdims=True)
    t0 = time.perf_counter()
    tr = rj.simulate(
        rj.RigidBody(jnp.array([1.5, 2.0, 2.5])),
        w,
        q,
        jnp.array([0.0, 0.2]),
        torque=torque,
        solver=rj.RK4(),
        stepsize_controller=diffrax.ConstantStepSize(),
        dt0=1e-3,
    )
    jax.block_until_ready(tr.omega)
    first = time.perf_counter() - t0
    log(f"first call {first:.2f} s")
    return dict(first_forward_s=first, bodies=B, steps=200)


def adaptive(B: int, repeats: int, log) -> dict:
    """The adaptive part (module docstring): per model, seconds, steps per body and the
    difference from the Diffrax path's states."""
    import diffrax
    import jax
    import jax.numpy as jnp

    import rigidjax as rj

    x = inputs(B)
    ts = jnp.linspace(0.0, T_END, N_OUT)
    args = tuple(jnp.asarray(x[k]) for k in ("I", "w", "q"))
    out: dict = dict(bodies=B, rtol=TOL, atol=TOL, output_times=N_OUT, t_end=T_END)
    for model in MODELS:
        batch, vmapped = jax_calls(model, ts)
        path_solver = rj.ExplicitRK(diffrax.Tsit5())
        path = jax_calls(model, ts, path_solver)[0]
        served = "pallas_call" in str(jax.make_jaxpr(batch)(*args))
        runs = {"simulate": batch, "vmap_simulate": vmapped, "diffrax_path": path}
        timings = {name: measure(fn, *args, repeats=1) for name, fn in runs.items()}
        interleaved(timings.values(), repeats - 1)
        base = timings["diffrax_path"]
        ref = np.asarray(base.output[0])
        rows: dict = {}
        for name, t in timings.items():
            ys, acc, rej = (np.asarray(a) for a in t.output)
            rows[name] = dict(
                seconds=t.best,
                all_seconds=t.times,
                accepted_steps_mean=float(np.mean(acc)),
                accepted_steps_max=int(np.max(acc)),
                rejected_steps_mean=float(np.mean(rej)),
                speedup_over_diffrax_path=base.best / t.best,
                max_diff_vs_diffrax_path=float(np.max(np.abs(ys - ref))),
            )
        torque = None if model == "free_body" else attitude_torque()

        loss = final_state_loss(ts, torque, rtol=TOL, atol=TOL)
        path_loss = final_state_loss(ts, torque, solver=path_solver, rtol=TOL, atol=TOL)
        grads = {
            "forward": measure(jax.jit(loss), *args, repeats=1),
            "grad": measure(jax.jit(jax.grad(loss, argnums=(0, 1))), *args, repeats=1),
            "diffrax_grad": measure(jax.jit(jax.grad(path_loss, argnums=(0, 1))), *args, repeats=1),
        }
        interleaved(grads.values(), repeats - 1)
        g, g_ref = (
            np.concatenate([np.ravel(a) for a in grads[k].output]) for k in grads if k != "forward"
        )
        gradient = dict(
            wrt="moments, omega0",
            forward_s=grads["forward"].best,
            grad_over_forward=grads["grad"].best / grads["forward"].best,
            diffrax_grad_over_forward=grads["diffrax_grad"].best / grads["forward"].best,
            max_rel_difference_diffrax=float(np.max(np.abs(g - g_ref)) / np.max(np.abs(g_ref))),
        )
        out[model] = dict(pallas=served, **rows, gradient=gradient)
        log(
            f"adaptive {model} (Pallas served: {served}): "
            + ", ".join(f"{k} {v['seconds']:.3f} s" for k, v in rows.items())
        )
    return out


def main(argv=None) -> None:
    p = parser(__doc__, "gpu.json", repeats=5)
    p.add_argument("--bodies", type=int, default=1_000_000)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--parts", default="first,speed,gradient,adaptive", help="comma-separated")
    p.add_argument("--adaptive-bodies", type=int, default=1_000_000)
    p.add_argument("--models", default="all", help="comma-separated (speed, gradient)")
    args = p.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)  # the benchmark's choice; rigidjax never sets it
    log = Log()
    parts = set(args.parts.split(","))
    out: dict = dict(
        machine=dict(machine_info(), device_kind=jax.devices()[0].device_kind),
        problem=dict(bodies=args.bodies, steps=args.steps, method="RK4", dtype="float64"),
    )
    if "first" in parts:
        out["first_call"] = first_call(log)
    if "speed" in parts:
        out["speed"] = speed(args.bodies, args.steps, args.repeats, log, args.models)[0]
    if "gradient" in parts:
        out["gradient"] = gradient(args.bodies, args.steps, args.repeats, log, args.models)
    if "adaptive" in parts:
        out["adaptive"] = adaptive(args.adaptive_bodies, args.repeats, log)
    out["load_average_start"] = log.load_start
    finish(out, args.out, log.t0)


if __name__ == "__main__":
    main()
