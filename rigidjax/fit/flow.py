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

__all__ = ["Torque", "flow", "substeps_for", "torque_rows"]

Torque = Callable[[Array, Array, Array], Array]


def torque_rows(torque, torque_frame, t, w, q):
    """Body-frame torque of each experiment: `torque(t, Ω, q)` mapped over the rows, or the
    row's own function of a tuple (one per experiment)."""
    if torque is None:
        return jnp.zeros_like(w)
    if isinstance(torque, tuple):

        def one(e, t, w, q):
            return jax.lax.switch(e, torque, t, w, q)

        K = jax.vmap(one)(jnp.arange(w.shape[0]), t, w, q)
    else:
        K = jax.vmap(torque)(t, w, q)
    K = jnp.asarray(K, w.dtype)
    if torque_frame == "space":
        K = quat.rotate(quat.conj(q), K)
    return K


def _rhs(I, I_inv, K, w, q):
    """`Ω̇ = I⁻¹(K − Ω × IΩ)`, `q̇ = ½ q ∘ (0, Ω)` for rows `w (E, 3)`, `q (E, 4)`."""
    dw = (K - jnp.cross(w, w @ I.T)) @ I_inv.T
    s, v = q[:, :1], q[:, 1:]
    dq = 0.5 * jnp.concatenate([-jnp.sum(v * w, -1, keepdims=True), s * w + jnp.cross(v, w)], -1)
    return dw, dq


def flow(
    inertia: Float[Array, "3 3"],
    omega0: Float[Array, "*E 3"],
    q0: Float[Array, "*E 4"],
    ts: Float[Array, "*E T"],
    substeps: int | Int[Array, " T-1"],
    torque: Torque | tuple[Torque, ...] | None = None,
    torque_frame: Frame = "body",
    attitude: bool = True,
) -> tuple[Float[Array, "*E T 3"], Float[Array, "*E T 4"]]:
    """`(Ω (T, 3), q (T, 4))` at `ts` from `(Ω, q) = (omega0, q0)` at `ts[0]`; or of E
    experiments of the same body at once (`omega0 (E, 3)`, `q0 (E, 4)`, `ts (T,)` or
    `(E, T)`, a torque function for all or a tuple of E), integrated as one state.

    `substeps`: steps per output interval, a Python int (the loop is a `lax.scan`: forward and
    reverse differentiable) or an integer array `(T-1,)` (a `while` loop: forward mode only,
    as the fits use it). Stage times are kept inside the open output interval (by √eps of its
    width), so a torque that is piecewise constant between output times is evaluated on the
    right piece. With `attitude=False` (no attitude data and no torque, which may depend on
    it) q is not integrated and stays q0: a smaller program, faster to compile."""
    I = jnp.asarray(inertia)
    I_inv = jnp.linalg.inv(I)
    dtype = I.dtype
    single = jnp.ndim(omega0) == 1
    w0 = jnp.atleast_2d(jnp.asarray(omega0, dtype))
    q0 = jnp.atleast_2d(jnp.asarray(q0, dtype))
    E = w0.shape[0]
    ts = jnp.broadcast_to(ts, (E, ts.shape[-1]))
    squeeze = jnp.sqrt(jnp.finfo(dtype).eps)

    def interval(carry, x):
        t0, t1, n = x  # t0, t1: (E,)
        h = ((t1 - t0) / n)[:, None]
        lo, hi = t0 + squeeze * (t1 - t0), t1 - squeeze * (t1 - t0)

        def f(t, w, q):
            K = torque_rows(torque, torque_frame, jnp.clip(t, lo, hi), w, q)
            if not attitude:
                return (K - jnp.cross(w, w @ I.T)) @ I_inv.T, jnp.zeros_like(q)
            return _rhs(I, I_inv, K, w, q)

        def step(i, y):
            w, q = y
            t = t0 + i * h[:, 0]
            k1 = f(t, w, q)
            k2 = f(t + h[:, 0] / 2, w + h / 2 * k1[0], q + h / 2 * k1[1])
            k3 = f(t + h[:, 0] / 2, w + h / 2 * k2[0], q + h / 2 * k2[1])
            k4 = f(t + h[:, 0], w + h * k3[0], q + h * k3[1])
            w = w + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            q = q + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            if not attitude:
                return w, y[1]
            return w, q * jax.lax.rsqrt(jnp.sum(q * q, -1, keepdims=True))

        y = jax.lax.fori_loop(0, n, step, carry)  # int n: a scan; traced n: a while loop
        return y, y

    if isinstance(substeps, int):
        xs = (ts[:, :-1].T, ts[:, 1:].T, None)

        def body(carry, x):
            return interval(carry, (x[0], x[1], substeps))

    else:
        xs = (ts[:, :-1].T, ts[:, 1:].T, jnp.asarray(substeps))
        body = interval
    _, (ws, qs) = jax.lax.scan(body, (w0, q0), xs)  # (T-1, E, ...)
    ws = jnp.concatenate([w0[None], ws]).swapaxes(0, 1)
    qs = jnp.concatenate([q0[None], qs]).swapaxes(0, 1)
    return (ws[0], qs[0]) if single else (ws, qs)


def substeps_for(
    ts: Float[Array, "*E T"], rate: Float[Array, "*E"], step_angle: float, max_steps: int
) -> Int[Array, " T-1"]:
    """Steps per output interval so that each turns the body by at most `step_angle` at the
    angular speed `rate` (an upper estimate from the data): `n_k = ⌈(t_{k+1} − t_k) rate / h⌉`,
    between 1 and `max_steps` (the most over the experiments)."""
    n = jnp.ceil(jnp.diff(ts, axis=-1) * rate[..., None] / step_angle * (1 - 1e-9))  # rounding
    n = jnp.clip(jnp.where(jnp.isfinite(n), n, max_steps), 1, max_steps).astype(jnp.int32)
    return n.reshape(-1, n.shape[-1]).max(axis=0)
