"""The forward model of the fits: Euler's equations and quaternion kinematics with fixed RK4 steps.

`I Ω̇ + Ω × IΩ = K` (body frame, general tensor; Zegrya–Parshin 004) and `q̇ = ½ q ∘ (0, Ω)`
(Borisov–Mamaev 001), the same equations as `rigidjax.simulate`, integrated by the classical
fourth-order Runge–Kutta method with the quaternion normalised after every step. Each output
interval `[t_k, t_{k+1}]` is divided into `n_k` equal steps.

Why not `simulate`: a fit differentiates the flow inside a Levenberg–Marquardt loop, and the
adaptive Diffrax solve inside it took 11–30 s to compile (benchmarks/results/identify.json);
this written-out loop compiles in about 2 s. Its accuracy is set by the rotation angle per step
`h |Ω|` (RK4: local error O((h|Ω|)⁵)); `substeps` picks `n_k` from the data so that the angle
stays below a bound (`tests/fit/test_flow.py` checks it against SciPy's DOP853).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._custom_types import Frame
from ..rotations import quat

Torque = Callable[[Array, Array, Array], Array]


def _rhs(I, I_inv, torque, torque_frame, t, w, q):
    if torque is None:
        K = jnp.zeros_like(w)
    else:
        K = jnp.asarray(torque(t, w, q), w.dtype)
        if torque_frame == "space":
            K = quat.rotate(quat.conj(q), K)
    dw = I_inv @ (K - jnp.cross(w, I @ w))
    dq = 0.5 * jnp.concatenate([-(q[1:] @ w)[None], q[0] * w + jnp.cross(q[1:], w)])
    return dw, dq


def flow(
    inertia: Float[Array, "3 3"],
    omega0: Float[Array, "3"],
    q0: Float[Array, "4"],
    ts: Float[Array, " T"],
    substeps: int | Int[Array, " T-1"],
    torque: Torque | None = None,
    torque_frame: Frame = "body",
) -> tuple[Float[Array, "T 3"], Float[Array, "T 4"]]:
    """`(Ω (T, 3), q (T, 4))` at `ts` from `(Ω, q) = (omega0, q0)` at `ts[0]`.

    `substeps`: steps per output interval, a Python int (the loop is a `lax.scan`: forward and
    reverse differentiable) or an integer array `(T-1,)` (a `while` loop: forward mode only,
    as the fits use it). Stage times are kept inside the open output interval (by √eps of its
    width), so a torque that is piecewise constant between output times is evaluated on the
    right piece."""
    I = jnp.asarray(inertia)
    I_inv = jnp.linalg.inv(I)
    dtype = I.dtype
    squeeze = jnp.sqrt(jnp.finfo(dtype).eps)

    def interval(carry, x):
        t0, t1, n = x
        h = (t1 - t0) / n
        lo, hi = t0 + squeeze * (t1 - t0), t1 - squeeze * (t1 - t0)

        def f(t, w, q):
            return _rhs(I, I_inv, torque, torque_frame, jnp.clip(t, lo, hi), w, q)

        def step(i, y):
            w, q = y
            t = t0 + i * h
            k1 = f(t, w, q)
            k2 = f(t + h / 2, w + h / 2 * k1[0], q + h / 2 * k1[1])
            k3 = f(t + h / 2, w + h / 2 * k2[0], q + h / 2 * k2[1])
            k4 = f(t + h, w + h * k3[0], q + h * k3[1])
            w = w + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            q = q + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            return w, q * jax.lax.rsqrt(q @ q)

        y = jax.lax.fori_loop(0, n, step, carry)  # int n: a scan; traced n: a while loop
        return y, y

    if isinstance(substeps, int):
        xs = (ts[:-1], ts[1:], None)

        def body(carry, x):
            return interval(carry, (x[0], x[1], substeps))

    else:
        xs = (ts[:-1], ts[1:], jnp.asarray(substeps))
        body = interval
    y0 = (jnp.asarray(omega0, dtype), jnp.asarray(q0, dtype))
    _, (ws, qs) = jax.lax.scan(body, y0, xs)
    return jnp.concatenate([y0[0][None], ws]), jnp.concatenate([y0[1][None], qs])


def substeps_for(
    ts: Float[Array, "*E T"], rate: Float[Array, "*E"], step_angle: float, max_steps: int
) -> Int[Array, "*E T-1"]:
    """Steps per output interval so that each turns the body by at most `step_angle` at the
    angular speed `rate` (an upper estimate from the data): `n_k = ⌈(t_{k+1} − t_k) rate / h⌉`,
    between 1 and `max_steps`."""
    n = jnp.ceil(jnp.diff(ts, axis=-1) * rate[..., None] / step_angle)
    return jnp.clip(jnp.where(jnp.isfinite(n), n, max_steps), 1, max_steps).astype(jnp.int32)
