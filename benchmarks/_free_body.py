"""The free rigid body of bench_dynamics.py (and its lean, NumPy, SciPy and extended-precision
references): B bodies, principal moments I = (1, 2, 3), Ω0 ~ N(0, 1)³, random unit q0, RK4 with
the quaternion renormalised after every step. The benchmark enables float64 before importing."""

from __future__ import annotations

from collections.abc import Callable

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from rigidjax import RK4, ExplicitRK, StepEndMap

MOMENTS = (1.0, 2.0, 3.0)


def make_inputs(B: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Body angular velocities Ω0 ~ N(0, 1)³ and uniform random unit quaternions (w ≥ 0)."""
    rng = np.random.default_rng(seed)
    w0 = rng.normal(size=(B, 3))
    q0 = rng.normal(size=(B, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    q0 *= np.where(q0[:, :1] < 0, -1.0, 1.0)
    return w0, q0


def rhs_components(s):
    """Euler's equations (principal axes) and q̇ = ½ q ∘ (0, Ω) on the seven components
    (Ω1, Ω2, Ω3, q0, q1, q2, q3); works on scalars, (B,) arrays, NumPy and JAX alike."""
    I1, I2, I3 = MOMENTS
    w1, w2, w3, a, b, c, d = s
    return (
        (I2 - I3) / I1 * w2 * w3,
        (I3 - I1) / I2 * w3 * w1,
        (I1 - I2) / I3 * w1 * w2,
        0.5 * (-b * w1 - c * w2 - d * w3),
        0.5 * (a * w1 + c * w3 - d * w2),
        0.5 * (a * w2 + d * w1 - b * w3),
        0.5 * (a * w3 + b * w2 - c * w1),
    )


def rk4_step_components(s, h):
    """One classical RK4 step on the component tuple, then quaternion renormalisation; `rsqrt`
    is 1/sqrt (lax.rsqrt in JAX, plain in NumPy)."""

    def axpy(x, k, c):
        return tuple(xi + c * ki for xi, ki in zip(x, k, strict=True))

    k1 = rhs_components(s)
    k2 = rhs_components(axpy(s, k1, 0.5 * h))
    k3 = rhs_components(axpy(s, k2, 0.5 * h))
    k4 = rhs_components(axpy(s, k3, h))
    s = tuple(
        x + (h / 6) * (p + 2 * q + 2 * r + u)
        for x, p, q, r, u in zip(s, k1, k2, k3, k4, strict=True)
    )
    w1, w2, w3, a, b, c, d = s
    n2 = a * a + b * b + c * c + d * d
    r = jax.lax.rsqrt(n2) if isinstance(n2, jax.Array) else 1 / np.sqrt(n2)
    return (w1, w2, w3, a * r, b * r, c * r, d * r)


# --------------------------------------------------------------------------- lean kernels


def _lean_rhs_arrays(w, q):
    """The same right-hand side on component-last arrays: (..., 3) and (..., 4)."""
    d = rhs_components([w[..., i] for i in range(3)] + [q[..., i] for i in range(4)])
    return jnp.stack(d[:3], axis=-1), jnp.stack(d[3:], axis=-1)


def lean_arrays_fn(N: int, dt: float) -> Callable:
    """Hand-written RK4 in lax.scan on (..., 3)/(..., 4) arrays: a batch (B, 3)/(B, 4) or, under
    vmap, a single body (3,)/(4,)."""
    h = dt

    def step(carry, _):
        w, q = carry
        k1w, k1q = _lean_rhs_arrays(w, q)
        k2w, k2q = _lean_rhs_arrays(w + 0.5 * h * k1w, q + 0.5 * h * k1q)
        k3w, k3q = _lean_rhs_arrays(w + 0.5 * h * k2w, q + 0.5 * h * k2q)
        k4w, k4q = _lean_rhs_arrays(w + h * k3w, q + h * k3q)
        w = w + (h / 6) * (k1w + 2 * k2w + 2 * k3w + k4w)
        q = q + (h / 6) * (k1q + 2 * k2q + 2 * k3q + k4q)
        q = q * jax.lax.rsqrt(jnp.sum(q * q, axis=-1, keepdims=True))
        return (w, q), None

    def run(w, q):
        return jax.lax.scan(step, (w, q), None, length=N)[0]

    return run


def lean_soa_fn(N: int, dt: float) -> Callable:
    """Hand-written RK4 in lax.scan on seven (B,) component arrays."""

    def run(w, q):
        s = tuple(w[:, i] for i in range(3)) + tuple(q[:, i] for i in range(4))
        s = jax.lax.scan(lambda c, _: (rk4_step_components(c, dt), None), s, None, length=N)[0]
        return jnp.stack(s[:3], axis=-1), jnp.stack(s[3:], axis=-1)

    return run


def diag_diffeqsolve_soa_fn(N: int, dt: float) -> Callable:
    """diffrax.diffeqsolve + rigidjax's ExplicitRK(RK4()) + StepEndMap renormalisation, on the
    lean SoA vector field."""

    def normalise(s):
        w1, w2, w3, a, b, c, d = s
        r = jax.lax.rsqrt(a * a + b * b + c * c + d * d)
        return (w1, w2, w3, a * r, b * r, c * r, d * r), jnp.array(False)

    adjoint = diffrax.RecursiveCheckpointAdjoint()
    solver = StepEndMap.wrap(ExplicitRK(RK4()), normalise, adjoint)
    term = diffrax.ODETerm(lambda t, s, args: rhs_components(s))

    def run(w, q):
        s = tuple(w[:, i] for i in range(3)) + tuple(q[:, i] for i in range(4))
        sol = diffrax.diffeqsolve(
            term,
            solver,
            0.0,
            N * dt,
            dt,
            s,
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=diffrax.ConstantStepSize(),
            max_steps=N + 1,
            adjoint=adjoint,
        )
        ys = [y[-1] for y in sol.ys or ()]
        return jnp.stack(ys[:3], axis=-1), jnp.stack(ys[3:], axis=-1)

    return run


# ------------------------------------------------------------------ NumPy, SciPy, reference


def numpy_rk4(w0: np.ndarray, q0: np.ndarray, N: int, dt: float, dtype=np.float64):
    s = tuple(np.asarray(w0[:, i], dtype=dtype) for i in range(3)) + tuple(
        np.asarray(q0[:, i], dtype=dtype) for i in range(4)
    )
    h = dtype(dt)
    for _ in range(N):
        s = rk4_step_components(s, h)
    return np.stack(s[:3], axis=-1), np.stack(s[3:], axis=-1)


def reference(w0, q0, N: int, dt: float, refine: int) -> tuple[np.ndarray, np.ndarray]:
    """RK4 at dt/refine in extended precision (np.longdouble), rounded to float64."""
    h = np.longdouble(dt) / refine
    w, q = numpy_rk4(w0, q0, N * refine, h, dtype=np.longdouble)
    return w.astype(np.float64), q.astype(np.float64)


def _scipy_rhs(t, s):
    return np.array(rhs_components(s))


def scipy_solve(w0, q0, T: float, method: str, rtol: float, atol: float):
    from scipy.integrate import solve_ivp

    ws, qs, nfev = [], [], 0
    for i in range(w0.shape[0]):
        y0 = np.concatenate([w0[i], q0[i]])
        sol = solve_ivp(_scipy_rhs, (0.0, T), y0, method=method, rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"solve_ivp {method} rtol={rtol}: {sol.message}")
        ws.append(sol.y[:3, -1])
        qs.append(sol.y[3:, -1])
        nfev += sol.nfev
    return np.array(ws), np.array(qs), nfev


def errors(w, q, w_ref, q_ref) -> dict:
    """Max abs error of Ω and of q (up to sign) over the trajectories, at t = T."""
    w, q = np.asarray(w, np.float64), np.asarray(q, np.float64)
    ew = float(np.max(np.abs(w - w_ref)))
    dq = np.minimum(np.max(np.abs(q - q_ref), axis=-1), np.max(np.abs(q + q_ref), axis=-1))
    eq = float(np.max(dq))
    return dict(omega=ew, quat=eq, max=max(ew, eq))


def norm_drift(q) -> float:
    q = np.asarray(q, np.float64)
    return float(np.max(np.abs(np.linalg.norm(q, axis=-1) - 1.0)))
