"""Adaptive steps at a tolerance against a per-body adaptive C reference (issue 35).

Problem
    B bodies (default 1e4), physical principal moments I = (b + c, a + c, a + b) with a, b, c ~
    U(0.2, 1.2) (the triangle inequality holds), Ω0 in a random direction with |Ω0| log-uniform
    in 0.1–3 rad/s (spread rates: the fast bodies need ~30× the steps of the slow ones), random
    unit q0; t ∈ [0, 20] with 21 output times, rtol = atol = 1e-8, float64. Two models:

    free_body  ``simulate(RigidBody(I), w0s, q0s, ts, rtol=1e-8, atol=1e-8)``
    attitude   the same with ``torque = s * cross(c, I0 * c)``, ``c = quat.to_matrix(q).T @ e_Z``,
               I0 = (1, 2, 3), s = 0.1: the gravity-gradient torque of bench_models.py with a
               gain that changes the motion (the C field is reference/models.c's, P(q/|q|))

Rows of the main table (per model)
    C Dopri5, C Tsit5  ``reference/adaptive.c``: each body its own steps (OpenMP over bodies),
               Diffrax's PIDController rule and initial step, steps ending at every output time,
               the quaternion renormalised after each step, first-same-as-last (6 evaluations a
               step). C Tsit5 is the baseline of the ratios (Tsit5 is simulate's default).
    C Tsit5 no FSAL  the first stage evaluated at the renormalised state: the same steps and
               numbers as rigidjax per body, but for an error estimate within rounding of 1
               (its sums are in another order); checked against ``jax.vmap(simulate)``:
               ``bodies_with_vmap_steps`` (the fraction with the same step counts) and
               ``max_diff_vs_vmap`` (on 1000 bodies, both tableaux also matched the Diffrax
               path, ``solver=ExplicitRK(Tsit5())`` / ``Dopri5()``: every body's steps, ≤ 1e-12).
    simulate   the default call on the batch (whatever path it takes today: the batch as one
               state stepped by its worst member on the Diffrax path, or a per-body kernel).
    vmap       ``jax.vmap(simulate)`` over bodies (per-body steps).
    Columns: best wall seconds (interleaved rounds), ×C = seconds / C Tsit5's (≤ 1.25 wanted),
    accepted and rejected steps per body (mean; the batch call: its own count), and the errors
    against a tight reference (C Dopri5 at rtol = atol = 1e-13; itself checked against SciPy's
    DOP853 at 1e-13 on a few bodies): max over bodies and times of |ΔΩ| (rad/s) and of the
    angle between the quaternions (rad). "err ≤ C" (wanted): rigidjax's errors no larger than
    C Tsit5's (within 5 %: C's first-same-as-last stage, taken before the renormalisation,
    moves its errors by a few per cent either way; ``error_ratio`` is rigidjax's over C's).

Other parts
    scipy      C Dopri5 and Tsit5 at 1e-8 and the tight reference against ``solve_ivp(method=
               "DOP853", rtol=atol=1e-13)`` on 4 bodies per model (the max errors above).
    full_tensor  fixed steps (Tsit5, ``ConstantStepSize``, dt0 = 0.01): ``RigidBody(R diag(I)
               Rᵀ)`` with Ω0' = R Ω0 and q0' = q0 ∘ r⁻¹ (R random per body) against the principal
               axes free body on the same 200 steps (t ∈ [0, 2]: a rate needs no more; each
               ``RigidBody`` built and checked once, outside the timed solve):
               ``rate_ratio`` = t_principal / t_full (≥ 0.6 wanted) and ``max_diff`` (the same
               motion: |Ω' − R Ω|, |P' − P Rᵀ|).
    gradient   ``jax.grad`` of ``sum |Ω(20)|² + sum |q_vec(20)|²`` w.r.t. (moments, Ω0) over the
               same loss's forward time (≤ 4 wanted), for the adaptive default call and for fixed
               steps (Tsit5, dt0 = 0.01), per model.

Usage
    python benchmarks/bench_adaptive.py [--bodies 10000] [--repeats 3] [--quick]
        [--out benchmarks/results/adaptive.json]
    (--quick: 1000 bodies unless --bodies is given, one timed round; for development)
"""

from __future__ import annotations

import argparse
import ctypes
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _c_reference import build_library  # noqa: E402
from _harness import interleaved, load_average, machine_info, measure, write_json  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "adaptive.json"
T_END, N_OUT, TOL, TIGHT = 20.0, 21, 1e-8, 1e-13
I0, GAIN = (1.0, 2.0, 3.0), 0.1
DT_FIXED, FIXED_SPAN = 0.01, 2.0  # the full tensor: 200 fixed steps (its rate, not its span)
MODELS = ("free_body", "attitude")
METHODS = {"dopri5": 0, "tsit5": 1}


def inputs(B: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    a, b, c = rng.uniform(0.2, 1.2, size=(3, B))
    d = rng.normal(size=(B, 3))
    rate = np.exp(rng.uniform(np.log(0.1), np.log(3.0), size=B))
    q = rng.normal(size=(B, 4))
    return dict(
        I=np.stack([b + c, a + c, a + b], -1),
        w=d / np.linalg.norm(d, axis=1, keepdims=True) * rate[:, None],
        q=q / np.linalg.norm(q, axis=1, keepdims=True),
    )


def c_params(model: str, I: np.ndarray) -> np.ndarray:
    """The reference's parameters (B, P): c, or (c, J, I0, s)."""
    I1, I2, I3 = I.T
    c = np.stack([(I2 - I3) / I1, (I3 - I1) / I2, (I1 - I2) / I3], -1)
    if model == "free_body":
        return np.ascontiguousarray(c)
    ones = np.ones((I.shape[0], 1))
    return np.ascontiguousarray(np.hstack([c, 1 / I, ones * I0, ones * GAIN]))


class AdaptiveC:
    """``reference/adaptive.c`` built and loaded (`build()`: None with `.note` if no compiler)."""

    note: str | None = None

    def __init__(self, lib: ctypes.CDLL, command: str):
        self.fn = lib.adaptive_solve
        self.fn.restype = ctypes.c_long
        p, i, L, d = ctypes.c_void_p, ctypes.c_int, ctypes.c_long, ctypes.c_double
        self.fn.argtypes = [i, i, i, L, L, p, p, p, d, d, L, p, p]
        self.command = command

    @classmethod
    def build(cls) -> AdaptiveC | None:
        built = build_library(HERE / "reference" / "adaptive.c")
        if isinstance(built, str):
            cls.note = built
            return None
        return cls(built[0], built[2])

    def solve(self, model, method, y0, par, ts, tol, fsal=True, max_steps=100_000):
        """`(ys (B, T, 7), counts (B, 2) accepted/rejected, failed bodies)`."""
        B, T = y0.shape[0], ts.shape[0]
        ys, counts = np.empty((B, T, 7)), np.empty((B, 2), dtype=np.int64)
        failed = self.fn(
            MODELS.index(model),
            METHODS[method],
            int(fsal),
            B,
            T,
            ts.ctypes.data,
            y0.ctypes.data,
            par.ctypes.data,
            tol,
            tol,
            max_steps,
            ys.ctypes.data,
            counts.ctypes.data,
        )
        return ys, counts, failed


def errors(ys: np.ndarray, ref: np.ndarray) -> dict:
    """Max over bodies and times of |ΔΩ| and of the angle of the rotation between the
    attitudes."""
    dw = np.linalg.norm(ys[..., :3] - ref[..., :3], axis=-1)
    q, r = ys[..., 3:], ref[..., 3:]
    s = np.sign(np.sum(q * r, -1, keepdims=True))
    s[s == 0] = 1
    # the rotation angle of q r⁻¹: |q ∓ r| = 2 sin, 2 cos of a quarter of it
    angle = 4 * np.arctan2(np.linalg.norm(q - s * r, axis=-1), np.linalg.norm(q + s * r, axis=-1))
    return dict(omega=float(np.max(dw)), quat_angle=float(np.max(angle)))


def jax_calls(model: str, ts, solver=None):
    """(batch, vmapped) forwards of (I, w, q) → (ys (B, T, 7), accepted, rejected) at TOL
    (`solver`: simulate's default, Tsit5, where None)."""
    import jax
    import jax.numpy as jnp

    import rigidjax as rj

    torque = None if model == "free_body" else attitude_torque()

    def call(I, w, q):  # a batch (I (B, 3), ...), or one body under `jax.vmap`
        tr = rj.simulate(
            rj.RigidBody(I), w, q, ts, torque=torque, solver=solver, rtol=TOL, atol=TOL
        )
        st = tr.stats
        return (
            jnp.concatenate([tr.omega, tr.quat], -1),
            st["num_accepted_steps"],
            st["num_rejected_steps"],
        )

    return call, jax.vmap(call)


def attitude_torque():
    import jax.numpy as jnp

    import rigidjax as rj

    e_z, inertia0 = jnp.array([0.0, 0.0, 1.0]), jnp.array(I0)

    def torque(t, w, q):
        c = rj.quat.to_matrix(q).T @ e_z
        return GAIN * jnp.cross(c, inertia0 * c)

    return torque


def scipy_check(lib: AdaptiveC, x: dict, ts: np.ndarray, log, n: int = 4) -> dict:
    """The C reference (both tableaux at TOL, and the tight reference) against DOP853."""
    from scipy.integrate import solve_ivp

    out = {}
    for model in MODELS:
        par = c_params(model, x["I"][:n])
        y0 = np.ascontiguousarray(np.hstack([x["w"][:n], x["q"][:n]]))
        sols = []
        for b in range(n):
            p = par[b]

            def f(t, y, p=p, torque=model == "attitude"):
                w, q = y[:3], y[3:]
                dw = p[:3] * np.array([w[1] * w[2], w[2] * w[0], w[0] * w[1]])
                if torque:
                    r = 2 / (q @ q)
                    c = np.array(
                        [
                            r * (q[1] * q[3] - q[0] * q[2]),
                            r * (q[2] * q[3] + q[0] * q[1]),
                            1 - r * (q[1] ** 2 + q[2] ** 2),
                        ]
                    )
                    dw = dw + p[3:6] * p[9] * np.cross(c, p[6:9] * c)
                dq = 0.5 * np.array(
                    [
                        -q[1:] @ w,
                        q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                        q[0] * w[1] + q[3] * w[0] - q[1] * w[2],
                        q[0] * w[2] + q[1] * w[1] - q[2] * w[0],
                    ]
                )
                return np.concatenate([dw, dq])

            s = solve_ivp(f, (ts[0], ts[-1]), y0[b], "DOP853", ts, rtol=TIGHT, atol=TIGHT)
            y = s.y.T
            sols.append(np.hstack([y[:, :3], y[:, 3:] / np.linalg.norm(y[:, 3:], axis=1)[:, None]]))
        ref = np.stack(sols)
        row = {}
        for label, method, tol in (
            ("dopri5", "dopri5", TOL),
            ("tsit5", "tsit5", TOL),
            ("tight_reference", "dopri5", TIGHT),
        ):
            row[label] = errors(lib.solve(model, method, y0, par, ts, tol)[0], ref)
        out[model] = row
        log(
            f"C vs SciPy DOP853 ({model}, {n} bodies): "
            + ", ".join(
                f"{k} |ΔΩ| {v['omega']:.1e} angle {v['quat_angle']:.1e}" for k, v in row.items()
            )
        )
    return out


def adaptive(lib: AdaptiveC | None, x: dict, ts_np: np.ndarray, repeats: int, log) -> dict:
    import jax.numpy as jnp

    ts = jnp.asarray(ts_np)
    args = (jnp.asarray(x["I"]), jnp.asarray(x["w"]), jnp.asarray(x["q"]))
    y0 = np.ascontiguousarray(np.hstack([x["w"], x["q"]]))
    out = {}
    for model in MODELS:
        par = c_params(model, x["I"])
        timings, rows = {}, {}
        if lib is not None:
            for name, method, fsal in (
                ("c_dopri5", "dopri5", True),
                ("c_tsit5", "tsit5", True),
                ("c_tsit5_no_fsal", "tsit5", False),
            ):

                def run(model=model, method=method, fsal=fsal, par=par):
                    return lib.solve(model, method, y0, par, ts_np, TOL, fsal)

                timings[name] = measure(run, repeats=1, aot=False)
            ref = lib.solve(model, "dopri5", y0, par, ts_np, TIGHT)[0]
        else:
            ref = None
        batch, vmapped = jax_calls(model, ts)
        timings["simulate"] = measure(batch, *args, repeats=1)
        timings["vmap_simulate"] = measure(vmapped, *args, repeats=1)
        interleaved(timings.values(), repeats - 1)
        for name, t in timings.items():
            o = t.output
            ys, acc, rej = (
                (np.asarray(o[0]), np.asarray(o[1]), np.asarray(o[2]))
                if (name in ("simulate", "vmap_simulate"))
                else (o[0], o[1][:, 0], o[1][:, 1])
            )
            rows[name] = dict(
                seconds=t.best,
                all_seconds=t.times,
                accepted_steps_mean=float(np.mean(acc)),
                accepted_steps_max=int(np.max(acc)),
                rejected_steps_mean=float(np.mean(rej)),
                **({} if ref is None else {"error": errors(ys, ref)}),
                **({"trace_compile_s": t.trace_lower_compile_s} if t.trace_lower_s else {}),
            )
            if name not in ("simulate", "vmap_simulate") and o[2]:
                rows[name]["failed_bodies"] = int(o[2])
        if "c_tsit5" in rows:
            base = rows["c_tsit5"]
            for name in ("simulate", "vmap_simulate"):
                r = rows[name]
                r["ratio_over_c_tsit5"] = r["seconds"] / base["seconds"]
                ratio = {k: r["error"][k] / base["error"][k] for k in ("omega", "quat_angle")}
                r["error_ratio"] = ratio
                r["error_no_larger_than_c"] = max(ratio.values()) <= 1.05
            nf = timings["c_tsit5_no_fsal"].output
            vm = timings["vmap_simulate"].output
            rows["c_tsit5_no_fsal"]["bodies_with_vmap_steps"] = float(
                np.mean((nf[1][:, 0] == np.asarray(vm[1])) & (nf[1][:, 1] == np.asarray(vm[2])))
            )
            rows["c_tsit5_no_fsal"]["max_diff_vs_vmap"] = float(
                np.max(np.abs(nf[0] - np.asarray(vm[0])))
            )
        out[model] = rows
        log(f"{model}: " + ", ".join(f"{k} {v['seconds']:.3f} s" for k, v in rows.items()))
    return out


def full_tensor(x: dict, repeats: int, log) -> dict:
    """Fixed steps: a full inertia tensor against the principal-axes free body."""
    import diffrax
    import jax
    import jax.numpy as jnp

    import rigidjax as rj

    B = x["I"].shape[0]
    rng = np.random.default_rng(1)
    r = rng.normal(size=(B, 4))
    r = jnp.asarray(r / np.linalg.norm(r, axis=1, keepdims=True))
    R = jax.vmap(rj.quat.to_matrix)(r)
    I, w, q = (jnp.asarray(x[k]) for k in ("I", "w", "q"))
    I_full = jnp.einsum("bij,bj,bkj->bik", R, I, R)
    w_full = jnp.einsum("bij,bj->bi", R, w)
    q_full = jax.vmap(rj.quat.mul)(q, rj.quat.conj(r))
    ts = jnp.linspace(0.0, FIXED_SPAN, 3)
    fixed = rj.SolveOptions(stepsize_controller=diffrax.ConstantStepSize(), dt0=DT_FIXED)

    def run(body, w, q):  # (the bodies built and checked once, outside the timed solve)
        tr = rj.simulate(body, w, q, ts, options=fixed)
        return tr.omega, tr.quat

    principal = measure(run, rj.RigidBody(I), w, q, repeats=1)
    full = measure(run, rj.RigidBody(I_full), w_full, q_full, repeats=1)
    interleaved([principal, full], repeats - 1)
    (wp, qp), (wf, qf) = principal.output, full.output
    dw = jnp.max(jnp.abs(wf - jnp.einsum("bij,btj->bti", R, wp)))
    Pp, Pf = rj.quat.to_matrix(qp), rj.quat.to_matrix(qf)
    dP = jnp.max(jnp.abs(Pf - jnp.einsum("btij,bkj->btik", Pp, R)))
    steps = B * round(FIXED_SPAN / DT_FIXED)
    out = dict(
        solver="Tsit5",
        dt0=DT_FIXED,
        t=[0.0, FIXED_SPAN],
        principal_s=principal.best,
        full_tensor_s=full.best,
        principal_body_steps_per_s=steps / principal.best,
        full_tensor_body_steps_per_s=steps / full.best,
        rate_ratio=principal.best / full.best,
        max_diff=dict(omega=float(dw), matrix=float(dP)),
    )
    log(f"full tensor: {out['rate_ratio']:.2f}× the principal-axes rate, max diff {float(dw):.1e}")
    return out


def final_state_loss(ts, torque, **options):
    """The gradients' loss of (moments, Ω0, q0): Σ |Ω(T)|² + |q(T)'s vector part|² over the
    bodies, of ``simulate`` with ``options``."""
    import jax.numpy as jnp

    import rigidjax as rj

    def loss(I, w, q):
        tr = rj.simulate(rj.RigidBody(I), w, q, ts, torque=torque, **options)
        return jnp.sum(tr.omega[:, -1] ** 2) + jnp.sum(tr.quat[:, -1, 1:] ** 2)

    return loss


def gradient(x: dict, ts_np: np.ndarray, repeats: int, log) -> dict:
    import diffrax
    import jax
    import jax.numpy as jnp

    import rigidjax as rj

    ts = jnp.asarray(ts_np)
    args = (jnp.asarray(x["I"]), jnp.asarray(x["w"]), jnp.asarray(x["q"]))
    modes = {
        "adaptive": rj.SolveOptions(rtol=TOL, atol=TOL),
        "fixed": rj.SolveOptions(stepsize_controller=diffrax.ConstantStepSize(), dt0=DT_FIXED),
    }
    out = {}
    for model in MODELS:
        torque = None if model == "free_body" else attitude_torque()
        for mode, options in modes.items():
            loss = final_state_loss(ts, torque, options=options)
            fwd = measure(loss, *args, repeats=1)
            grad = measure(jax.grad(loss, argnums=(0, 1)), *args, repeats=1)
            interleaved([fwd, grad], repeats - 1)
            ratio = grad.best / fwd.best
            out[f"{model}_{mode}"] = dict(
                wrt="moments, omega0", forward_s=fwd.best, grad_s=grad.best, ratio=ratio
            )
            log(f"gradient {model} {mode}: {ratio:.2f}× forward ({fwd.best:.3f} s)")
    return out


def table(res: dict) -> str:
    lines = [
        f"{'model':10} {'call':16} {'seconds':>8} {'×C':>6} {'acc/body':>9} {'rej/body':>9} "
        f"{'|ΔΩ| max':>9} {'angle max':>9}  err≤C"
    ]
    for model, rows in res["adaptive"].items():
        for name, r in rows.items():
            e = r.get("error", {})
            ratio = r.get("ratio_over_c_tsit5")
            lines.append(
                f"{model:10} {name:16} {r['seconds']:8.3f} "
                f"{'' if ratio is None else f'{ratio:.2f}':>6} {r['accepted_steps_mean']:9.1f} "
                f"{r['rejected_steps_mean']:9.1f} {e.get('omega', np.nan):9.1e} "
                f"{e.get('quat_angle', np.nan):9.1e}  {r.get('error_no_larger_than_c', '')}"
            )
    ft = res["full_tensor"]
    lines.append(f"full tensor at fixed steps: {ft['rate_ratio']:.2f}× the principal-axes rate")
    for name, g in res["gradient"].items():
        lines.append(f"gradient {name}: {g['ratio']:.2f}× forward")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--bodies", type=int, default=None, help="default 10000 (quick: 1000)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    B = args.bodies or (1000 if args.quick else 10_000)
    repeats = 1 if args.quick else args.repeats
    import jax

    jax.config.update("jax_enable_x64", True)
    start, load_start = time.perf_counter(), load_average()

    def log(msg):
        print(f"[{time.perf_counter() - start:6.1f} s] {msg}", flush=True)

    x = inputs(B)
    ts = np.linspace(0.0, T_END, N_OUT)
    lib = AdaptiveC.build()
    if lib is None:
        log(f"no C reference: {AdaptiveC.note}")
    res = dict(
        scipy=scipy_check(lib, x, ts, log) if lib is not None else {},
        adaptive=adaptive(lib, x, ts, repeats, log),
        full_tensor=full_tensor(x, repeats, log),
        gradient=gradient(x, ts, repeats, log),
    )
    print(table(res))
    out = dict(
        machine=machine_info(),
        problem=dict(
            bodies=B,
            t=[0.0, T_END],
            output_times=N_OUT,
            rtol=TOL,
            atol=TOL,
            tight_reference=f"C Dopri5 at rtol = atol = {TIGHT}",
            rates="|Ω0| log-uniform in 0.1–3 rad/s",
            attitude_torque=f"{GAIN} * cross(c, {I0} * c), c = P(q)ᵀ e_Z",
            dtype="float64",
            repeats=repeats,
        ),
        c_command=None if lib is None else lib.command,
        c_note=AdaptiveC.note,
        **res,
        load_average_start=load_start,
        load_average_end=load_average(),
        total_wall_s=time.perf_counter() - start,
    )
    write_json(args.out, out)
    log(f"wrote {args.out}")


if __name__ == "__main__":
    main()
