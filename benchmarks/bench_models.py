"""Every model at kernel speed: rigidjax's fixed-step models with torques against hand-written C
kernels of the same models, their gradients, the Diffrax path, and first calls.

Problem
    B bodies (default 1e5) with principal moments I = (1.5, 2, 2.5)·(1 + 0.1 u), u ~ U(0, 1)³ per
    body, Ω0 ~ N(0, 1)³, random unit q0; N = 200 RK4 steps of dt = 1e-3 (the satellite: dt = 1
    s on a 7000 km circular orbit), the quaternion renormalised after each, float64. Models:

    free_body         ``simulate(...)`` without a torque
    damping           ``simulate(..., torque=lambda t, w, q: -k * w)``, k = (0.3, 0.2, 0.1)
    gravity_gradient  ``torque = 3e-4 * cross(c, I0 * c)``, ``c = quat.to_matrix(q).T @ e_Z``,
                      I0 = (1, 2, 3) (the attitude torque of issue 25, written as a user would)
    heavy_top         ``jax.vmap(simulate_heavy_top)`` over tops (mass 1, r_c per body) with
                      the attitude q integrated too: state (Ω, γ, q)
    sixdof            ``jax.vmap(simulate_6dof)`` with the force F = (0.1, 0, −9.81 m) (space)
                      at the body point a = (0.1, 0.2, 0): state (R, V, q, Ω)
    satellite         ``jax.vmap(satellite.simulate_satellite)``: orbit + gravity gradient
    closed_loop       ``jax.vmap(simulate)`` of a ``Gyrostat`` with four wheels in a pyramid under
                      the quaternion PD law sampled every 10 steps and held (motor torques
                      bounded at 0.1 N m): a rest-to-rest slew towards 90° about z
    gyrostat          ``jax.vmap(simulate)`` of a ``Gyrostat`` with constant rotor momentum
                      h = (0.1, 0.2, 0.3) (Zhukovsky–Volterra), a batch of bodies each
    darboux_quat      ``jax.vmap(darboux)`` (frame "body", method "quat"): the attitude from
                      the body angular velocity Ω(t) = (a sin t, 4 cos 2t, 3 + a t / 2) written
                      in JAX, a ~ U(0.5, 1.5) per body (traced), from P0 = P(q0)
    darboux_rotvec    the same with method "rotvec" (the default: θ̇ = Zᵀ(θ) Ω and the
                      shadow switch after each step; bodies with |θ| near π switch)

Parts (one run)
    speed     Each model on rigidjax's fast path (the kernel written from the JAX field) and its
              C reference (``benchmarks/reference/models.c``, built here with the system
              compiler, called through ctypes on its packed state; packing not timed), timed in
              interleaved rounds (best of --repeats) after checking that their final states
              agree (RK4 on the same steps; the references compute P(q) of a unit q, rigidjax
              of q/|q|: rounding-level differences; the 6-DOF load sees the normalised q in
              both, as ``simulate_6dof`` defines it). Recorded: rates, ratio (≥ 0.8 wanted).
    diffrax   damping and gravity_gradient on the Diffrax path on the same steps
              (``solver=ExplicitRK(RK4())``), which adaptive and implicit solvers use: its rate
              and its ratio to the fast path.
    gradient  ``jax.value_and_grad`` of a loss of the final states w.r.t. the moments and the
              torque's gain (damping) or the centre of mass (heavy top), over the forward run
              alone (≤ 5× wanted).
    first     A fresh process (empty kernel and JAX caches in a temporary folder) times the first
              forward call of the damping and gravity-gradient models (trace, kernel build, XLA
              compile, run; B = 1000) and then the first gradient; a second fresh process with the
              same caches (JAX's persistent compilation cache on) times the same calls.

Usage
    python benchmarks/bench_models.py [--bodies 100000] [--steps 200] [--repeats 3]
        [--out benchmarks/results/models.json]
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _c_reference import REFERENCE, bind, build_library  # noqa: E402
from _harness import Log, finish, fresh_process, interleaved, machine_info, measure, parser  # noqa: E402

GAIN = (0.3, 0.2, 0.1)
MU, RADIUS = 398600.4418, 7000.0
F_SPACE, POINT = (0.1, 0.0, -9.81), (0.1, 0.2, 0.0)
H_ROTOR = (0.1, 0.2, 0.3)
B3 = 1 / np.sqrt(3)
WHEELS = ((B3, B3, B3), (-B3, B3, B3), (-B3, -B3, B3), (B3, -B3, B3))  # a pyramid (rows)
J_WHEEL, U_MAX, KP, KD, EVERY = 0.05, 0.1, 0.6, 3.0, 10
Q_TARGET = (np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4))  # 90° about z


def inputs(B: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(B, 4))
    return dict(
        I=np.array([1.5, 2.0, 2.5]) * (1 + 0.1 * rng.uniform(size=(B, 3))),
        w=rng.normal(size=(B, 3)),
        q=q / np.linalg.norm(q, axis=1, keepdims=True),
        com=0.1 * rng.normal(size=(B, 3)),
        a=rng.uniform(0.5, 1.5, size=B),
    )


def _cj(I: np.ndarray) -> np.ndarray:
    """(c, J) rows (6, B) of the references."""
    I1, I2, I3 = I.T
    return np.stack([(I2 - I3) / I1, (I3 - I1) / I2, (I1 - I2) / I3, 1 / I1, 1 / I2, 1 / I3])


def _gamma(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)


def _closed_loop_params(I: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The closed-loop reference's parameters (28, B) but the held torques: I, (I − A J Aᵀ)⁻¹,
    A (row-major) and J."""
    B = I.shape[0]
    M = np.linalg.inv(np.einsum("bi,ij->bij", I, np.eye(3)) - (A * J_WHEEL) @ A.T)
    return np.vstack([I.T, M.reshape(B, 9).T, np.outer(A.ravel(), np.ones(B)),
                      np.full((4, B), J_WHEEL)])  # fmt: skip


def closed_loop_constants(A: np.ndarray) -> np.ndarray:
    """The law's constants of the reference: kp, kd, q_t, G = −A⁺ (row-major), umax."""
    return np.concatenate([[KP, KD], Q_TARGET, (-np.linalg.pinv(A)).ravel(), [U_MAX]])


def models(B: int, steps: int, solver=None):
    """Per model: (rigidjax forward (jit-able, of the inputs) returning the final state (B, N) in
    the reference's order, its arguments, the reference's packed state and parameters, dt);
    `solver` (default `RK4()`, the fast path) for every model, and the Diffrax path of the
    damping and gravity-gradient models."""
    import diffrax
    import jax
    import jax.numpy as jnp

    import rigidjax as rj
    from rigidjax.mechanics import heavy_top as ht
    from rigidjax.mechanics import satellite, sixdof

    x = inputs(B)
    dt, dt_sat = 1e-3, 1.0
    fixed = dict(stepsize_controller=diffrax.ConstantStepSize(), solver=solver or rj.RK4())
    gain, e_z, I0 = jnp.array(GAIN), jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 2.0, 3.0])
    ts = jnp.array([0.0, steps * dt])

    def damping(t, w, q):
        return -gain * w

    def gravity_gradient(t, w, q):
        c = rj.quat.to_matrix(q).T @ e_z
        return 3e-4 * jnp.cross(c, I0 * c)

    def rigid(torque, solver=None):
        kw = fixed if solver is None else dict(fixed, solver=solver)

        def run(I, w, q):
            tr = rj.simulate(rj.RigidBody(I), w, q, ts, torque=torque, dt0=dt, **kw)
            return jnp.concatenate([tr.omega[:, -1], tr.quat[:, -1]], -1)

        return run

    def heavy(I, com, w, q):
        def one(I, com, w, q):
            tr = ht.simulate_heavy_top(ht.HeavyTop(I, 1.0, com), w, ts=ts, q0=q, dt0=dt, **fixed)
            return jnp.concatenate([tr.omega[-1], tr.gamma[-1], tr.quat[-1]])

        return jax.vmap(one)(I, com, w, q)

    def six(I, w, q):
        def one(I, w, q):
            def wrench(t, s):
                return sixdof.wrench_at_point(jnp.array(F_SPACE), jnp.array(POINT), s.q)

            tr = sixdof.simulate_6dof(
                rj.RigidBody(I), jnp.zeros(3), jnp.zeros(3), q, w, ts, wrench, dt0=dt, **fixed
            )
            return jnp.concatenate([tr.R[-1], tr.V[-1], tr.quat[-1], tr.omega[-1]])

        return jax.vmap(one)(I, w, q)

    R0, V0 = (np.asarray(a) for a in satellite.circular_orbit(MU, RADIUS))
    ts_sat = jnp.array([0.0, steps * dt_sat])

    def sat(I, w, q):
        def one(I, w, q):
            tr = satellite.simulate_satellite(
                rj.RigidBody(I), R0, V0, q, w, ts_sat, MU, dt0=dt_sat, **fixed
            )
            return jnp.concatenate([tr.R[-1], tr.V[-1], tr.quat[-1], tr.omega[-1]])

        return jax.vmap(one)(I, w, q)

    h_rotor = jnp.array(H_ROTOR)
    A_w = np.array(WHEELS).T / np.linalg.norm(np.array(WHEELS), axis=1)  # (3, 4) unit columns
    law = rj.control.quaternion_pd(KP, KD, np.array(Q_TARGET), wheel_axes=A_w)

    def closed(I, w, q):
        def one(I, w, q):
            sc = rj.Gyrostat(I, wheel_axes=A_w, wheel_inertia=jnp.full(4, J_WHEEL),
                             wheel_torque_max=U_MAX)  # fmt: skip
            tr = rj.simulate(sc, w, q, ts, controller=law, control_period=EVERY * dt, dt0=dt,
                             **fixed)  # fmt: skip
            return jnp.concatenate([tr.omega[-1], tr.quat[-1], tr.wheel_speed[-1]])

        return jax.vmap(one)(I, w, q)

    def gyro(I, w, q):
        def one(I, w, q):
            tr = rj.simulate(rj.Gyrostat(I, h=h_rotor), w, q, ts, dt0=dt, **fixed)
            return jnp.concatenate([tr.omega[-1], tr.quat[-1]])

        return jax.vmap(one)(I, w, q)

    def darboux(method):
        def run(a, P0):
            def one(a, P0):
                def omega(t):
                    return jnp.stack([a * jnp.sin(t), 4 * jnp.cos(2 * t), 3 + 0.5 * a * t])

                _, y = rj.darboux(omega, ts, P0, "body", method, return_state=True, dt0=dt,
                                  **fixed)  # fmt: skip
                return y[-1]

            return jax.vmap(one)(a, P0)

        return run

    I, w, q, com = x["I"], x["w"], x["q"], x["com"]
    P0 = np.asarray(jax.vmap(rj.quat.to_matrix)(q))
    ones = np.ones(B)
    wq = np.concatenate([w.T, q.T])
    small_w = 1e-3 * w
    out = {
        "free_body": (rigid(None), (I, w, q), wq, _cj(I), dt),
        "damping": (
            rigid(damping),
            (I, w, q),
            wq,
            np.vstack([_cj(I), np.outer(GAIN, ones)]),
            dt,
        ),
        "gravity_gradient": (
            rigid(gravity_gradient),
            (I, w, q),
            wq,
            np.vstack([_cj(I), np.outer([1.0, 2.0, 3.0], ones), 3e-4 * ones[None]]),
            dt,
        ),
        "heavy_top": (
            heavy,
            (I, com, w, q),
            np.concatenate([w.T, _gamma(q).T, q.T]),
            np.vstack([_cj(I), 9.81 * com.T]),
            dt,
        ),
        "sixdof": (
            six,
            (I, w, q),
            np.concatenate([np.zeros((6, B)), q.T, w.T]),
            np.vstack([_cj(I), ones[None], np.outer(F_SPACE, ones), np.outer(POINT, ones)]),
            dt,
        ),
        "satellite": (
            sat,
            (I, small_w, q),
            np.concatenate([np.outer(R0, ones), np.outer(V0, ones), q.T, small_w.T]),
            np.vstack([_cj(I), I.T, MU * ones[None]]),
            dt_sat,
        ),
        "closed_loop": (
            closed,
            (I, small_w, q),
            np.concatenate([small_w.T, q.T, np.zeros((4, B))]),
            np.vstack([_closed_loop_params(I, A_w), np.zeros((4, B))]),
            dt,
        ),
        "gyrostat": (
            gyro,
            (I, w, q),
            wq,
            np.vstack([_cj(I), np.outer(H_ROTOR, ones)]),
            dt,
        ),
    }
    for method, to_state in (("quat", rj.quat.from_matrix), ("rotvec", rj.so3.log)):
        state0 = np.asarray(jax.vmap(to_state)(P0)).T  # the kinematics' own initial states
        out[f"darboux_{method}"] = (darboux(method), (x["a"], P0), state0, x["a"][None], dt)
    diffrax_path = {
        name: rigid(torque, rj.ExplicitRK(rj.RK4()))
        for name, torque in (("damping", damping), ("gravity_gradient", gravity_gradient))
    }
    return out, diffrax_path


def speed(B: int, steps: int, repeats: int, log) -> tuple[dict, dict]:
    import jax

    built = build_library(REFERENCE / "models.c")
    if isinstance(built, str):
        return {"c_note": built}, {}
    lib, report, command = built
    table, diffrax_path = models(B, steps)
    rows = {}
    for name, (fn, args, state0, par, dt) in table.items():
        par = np.ascontiguousarray(par, dtype=np.float64)
        state0 = np.array(state0, dtype=np.float64)  # a copy: the run works in place
        work = state0.copy()
        pointers = [work.ctypes.data, par.ctypes.data]
        tail = []
        if name == "closed_loop":  # the law's constants, and the steps between samples
            ctl = closed_loop_constants(np.array(WHEELS).T)
            pointers.append(ctl.ctypes.data)
            tail = [EVERY]
        func = bind(lib, f"{name}_rk4", len(pointers), len(tail))

        def c_run(work=work, state0=state0, func=func, pointers=pointers, tail=tail, dt=dt):
            work[...] = state0  # in place: reset (a copy of (N, B) doubles, ~1% of a call)
            func(*pointers, B, steps, dt, *tail)
            return work

        t_rj = measure(jax.jit(fn), *args, repeats=1)
        t_c = measure(c_run, repeats=1, aot=False)
        diff = float(np.max(np.abs(np.asarray(t_rj.output) - t_c.output.T)))
        interleaved([t_rj, t_c], repeats)
        rows[name] = dict(
            rigidjax_body_steps_per_s=B * steps / t_rj.best,
            c_body_steps_per_s=B * steps / t_c.best,
            ratio_rigidjax_over_c=t_c.best / t_rj.best,
            max_abs_difference=diff,
            rigidjax=t_rj.summary(),
            c=t_c.summary(),
            rigidjax_trace_compile_s=t_rj.trace_lower_compile_s,
        )
        log(
            f"{name}: rigidjax {B * steps / t_rj.best:.3g}/s, C {B * steps / t_c.best:.3g}/s, "
            f"ratio {t_c.best / t_rj.best:.2f}, max |diff| {diff:.1e}"
        )
    info = dict(c_command=command, c_vectorized=report.count("loop vectorized"))
    rows_d = {}
    for name, fn in diffrax_path.items():
        fn_args = table[name][1]
        t = measure(jax.jit(fn), *fn_args, repeats=repeats)
        rows_d[name] = dict(
            body_steps_per_s=B * steps / t.best,
            vs_fast_path=(B * steps / t.best) / rows[name]["rigidjax_body_steps_per_s"],
            seconds=t.best,
        )
        log(f"diffrax path {name}: {B * steps / t.best:.3g}/s")
    return dict(models=rows, diffrax_path=rows_d, **info), table


def gradient(table: dict, repeats: int, log) -> dict:
    import jax
    import jax.numpy as jnp

    out = {}
    for name, argnum in (("damping", 0), ("gravity_gradient", 0), ("heavy_top", 1)):
        fn, args = table[name][0], table[name][1]

        def loss(*a, fn=fn):
            return jnp.sum(fn(*a) ** 2)

        fwd = measure(jax.jit(loss), *args, repeats=1)
        vg = measure(jax.jit(jax.value_and_grad(loss, argnums=argnum)), *args, repeats=1)
        interleaved([fwd, vg], repeats)
        out[name] = dict(
            wrt="moments" if argnum == 0 else "centre of mass",
            forward_s=fwd.best,
            value_and_grad_s=vg.best,
            ratio=vg.best / fwd.best,
        )
        log(f"gradient {name}: {vg.best / fwd.best:.2f}x forward")
    return out


WORKER = """
import json, os, sys, time
import jax
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", os.path.join(os.environ["XDG_CACHE_HOME"], "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
import diffrax, jax.numpy as jnp, numpy as np
import rigidjax as rj
B = 1000
rng = np.random.default_rng(0)
w = jnp.asarray(rng.normal(size=(B, 3)))
q = jnp.asarray(rng.normal(size=(B, 4)))
q = q / jnp.linalg.norm(q, axis=1, keepdims=True)
ts = jnp.array([0.0, 0.2])
kw = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=1e-3)
gain, e_z = jnp.array([0.3, 0.2, 0.1]), jnp.array([0.0, 0.0, 1.0])
torques = dict(
    damping=lambda t, w, q: -gain * w,
    gravity_gradient=lambda t, w, q: 3e-4 * jnp.cross(
        rj.quat.to_matrix(q).T @ e_z, jnp.array([1.0, 2.0, 3.0]) * (rj.quat.to_matrix(q).T @ e_z)
    ),
)
out = {}
for name, torque in torques.items():
    def loss(I, torque=torque):
        tr = rj.simulate(rj.RigidBody(I), w, q, ts, torque=torque, **kw)
        return jnp.sum(tr.omega[:, -1] ** 2)
    I = jnp.array([1.0, 2.0, 3.0])
    t0 = time.perf_counter(); jax.block_until_ready(jax.jit(loss)(I)); t1 = time.perf_counter()
    jax.block_until_ready(jax.jit(jax.grad(loss))(I)); t2 = time.perf_counter()
    out[name] = dict(forward_s=t1 - t0, gradient_s=t2 - t1)
print(json.dumps(out))
"""


def first_calls(log) -> dict:
    # the worker's folder comes first on its sys.path: not the cache (it holds a rigidjax/)
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as here:
        script = Path(here) / "worker.py"
        script.write_text(WORKER)
        env = {**os.environ, "XDG_CACHE_HOME": cache}
        out = {}
        for label in ("cold", "warm_caches"):
            res, wall, proc = fresh_process(script, env=env)
            if res is None:
                out[label] = dict(error=proc.stderr[-2000:])
                continue
            out[label] = dict(res, process_wall_s=wall)
            log(f"first calls ({label}): {json.dumps(res)}")
    return out


def main(argv=None) -> None:
    p = parser(__doc__, "models.json")
    p.add_argument("--bodies", type=int, default=100_000)
    p.add_argument("--steps", type=int, default=200)
    args = p.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    log = Log()
    res, table = speed(args.bodies, args.steps, args.repeats, log)
    out = dict(
        machine=machine_info(),
        problem=dict(bodies=args.bodies, steps=args.steps, method="RK4", dtype="float64"),
        speed=res,
        gradient=gradient(table, args.repeats, log) if table else {},
        first_calls=first_calls(log),
        load_average_start=log.load_start,
    )
    finish(out, args.out, log.t0)


if __name__ == "__main__":
    main()
