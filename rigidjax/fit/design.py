"""Experiment design: the torque profile that makes the inertia best identifiable.

A piecewise-constant body-frame torque `u(t) = u_k` on `S` equal segments of `[0, duration]`,
bounded `|u_k,i| ≤ u_max` through `u = u_max tanh(z)`, is chosen to maximise the D-optimality
criterion of the inertia parameters

    φ(u) = log det F_II − F_Iν F_νν⁻¹ F_νI = log det F − log det F_νν,

the information about the six entries of I (`θ_I = (I11, I22, I33, I12, I13, I23)`) left after
the nuisance parameters ν (the initial angular velocity; with attitude data also the initial
attitude) are fitted too, with `F = JᵀJ`, `J = ∂(Ω(t_j)/σ_ω, δq(t_j)/σ_q)/∂(θ_I, ν)` the
sensitivities of the sampled motion (Fedorov, Theory of Optimal Experiments, 1972; Pronzato &
Pázman, Design of Experiments in Nonlinear Models, 2013, ch. 5). `F⁻¹` is the Cramér–Rao bound
of the covariance of any unbiased estimate: a larger `φ` means a smaller confidence ellipsoid.

`φ` is differentiated through the simulated motion (`rigidjax.fit.flow`: forward-mode
sensitivities inside, reverse mode over them) and increased by normalised gradient ascent
`z ← z + η_k ∇φ / rms(∇φ)` with a step `η_k` decaying linearly to 0; the best profile met is
returned. The start is a pseudo-random binary sequence (PRBS) at 90% of the bound — the usual
excitation for spacecraft inertia identification (e.g. El Hariry et al., 2024) — so the design
is never worse than its start.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._checks import as_float, check_finite, concrete_value, integer, vector
from .._compile import quick_compile_jit
from .._custom_types import RealLike
from ..mechanics.inertia import as_tensor, check_inertia
from ..rotations import quat
from ..rotations._quat_core import _unit
from .flow import flow

__all__ = [
    "ExcitationDesign",
    "PiecewiseConstantTorque",
    "design_excitation",
    "fisher_information",
    "log_det_criterion",
    "piecewise_constant",
    "prbs",
]

_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


class ExcitationDesign(eqx.Module):
    """Result of `design_excitation`: the torque `torques[k]` (body frame) on
    `[edges[k], edges[k+1])`; `ts`, the sample times it was designed for (segment edges among
    them); `log_det` (the criterion φ at the design) and `history` (φ per ascent step);
    `inertia_std`: the Cramér–Rao standard deviation of each inertia entry (3×3).
    `design.torque` is a torque function `torque(t, omega, q)` for `simulate` and
    `identify_inertia`."""

    torques: Float[Array, "S 3"]
    edges: Float[Array, " S+1"]
    ts: Float[Array, " T"]
    log_det: Float[Array, ""]
    history: Float[Array, " steps"]
    inertia_std: Float[Array, "3 3"]

    def torque(self, t: RealLike, omega: Array, q: Array) -> Float[Array, "3"]:
        del omega, q
        return piecewise_constant(self.torques, self.edges, t)


class PiecewiseConstantTorque(eqx.Module):
    """`torque(t, omega, q) = torques[k]` on `[edges[k], edges[k+1])`: a torque function whose
    values are arrays (a new profile of the same shape reuses the compiled fit)."""

    torques: Float[Array, "S 3"]
    edges: Float[Array, " S+1"]

    def __call__(self, t: RealLike, omega: Array, q: Array) -> Float[Array, "3"]:
        del omega, q
        return piecewise_constant(self.torques, self.edges, t)


def piecewise_constant(
    torques: Float[Array, "S 3"], edges: Float[Array, " S+1"], t: RealLike
) -> Float[Array, "3"]:
    """`torques[k]` for `edges[k] ≤ t < edges[k+1]` (clamped to the first and last segment)."""
    k = jnp.searchsorted(edges, jnp.asarray(t, edges.dtype), side="right") - 1
    return torques[jnp.clip(k, 0, torques.shape[0] - 1)]


def prbs(key: PRNGKeyArray, n_segments: int, torque_bound: float, dtype=None) -> Array:
    """A pseudo-random binary sequence: each segment and axis `±torque_bound` at random
    `(n_segments, 3)`."""
    signs = jax.random.rademacher(key, (n_segments, 3))
    return torque_bound * signs.astype(dtype or jnp.result_type(float))


def fisher_information(
    inertia: Float[Array, "3 3"],
    omega0: Float[Array, "3"],
    torques: Float[Array, "S 3"],
    ts: Float[Array, " T"],
    *,
    q0: Float[Array, "4"] | None = None,
    sigma_omega: float | Array = 1.0,
    sigma_angle: float | Array | None = None,
    substeps: int = 4,
) -> Float[Array, "p p"]:
    """`F = JᵀJ` of the sampled gyro (and, with `sigma_angle`, attitude) data with respect to
    the six inertia entries `(I11, I22, I33, I12, I13, I23)` followed by Ω0 (and the initial
    attitude): the first 6×6 block concerns the inertia. The torque is `torques` on equal
    segments of `[ts[0], ts[-1]]`; `substeps` RK4 steps per sample interval."""
    dtype = ts.dtype
    q0 = quat.identity(dtype=dtype) if q0 is None else q0
    edges = jnp.linspace(ts[0], ts[-1], torques.shape[0] + 1)
    with_q = sigma_angle is not None

    def torque(t, w, q):
        return piecewise_constant(torques, edges, t)

    def samples(theta):
        dI = jnp.zeros((3, 3), dtype)
        for k, (i, j) in enumerate(_ENTRIES):
            dI = dI.at[i, j].add(theta[k])
            if i != j:
                dI = dI.at[j, i].add(theta[k])
        q_start = quat.retract(q0, theta[9:12]) if with_q else q0
        W, Q = flow(inertia + dI, omega0 + theta[6:9], q_start, ts, substeps, torque)
        out = [W.reshape(-1) / sigma_omega]
        if sigma_angle is not None:
            ref = jax.lax.stop_gradient(Q)
            out.append(quat.local(ref, Q).reshape(-1) / sigma_angle)
        return jnp.concatenate(out)

    J = jax.jacfwd(samples)(jnp.zeros(12 if with_q else 9, dtype))
    return J.T @ J


def log_det_criterion(F: Float[Array, "p p"]) -> Float[Array, ""]:
    """`φ = log det F − log det F_νν`: log det of the inertia block's Schur complement."""
    return jnp.linalg.slogdet(F)[1] - jnp.linalg.slogdet(F[6:, 6:])[1]


def design_excitation(
    inertia: RealLike,
    omega0: RealLike,
    duration: float,
    *,
    torque_bound: float,
    n_segments: int = 8,
    samples_per_segment: int = 10,
    q0: RealLike | None = None,
    sigma_omega: float = 1.0,
    sigma_angle: float | None = None,
    steps: int = 60,
    learning_rate: float = 0.3,
    init: RealLike | None = None,
    key: PRNGKeyArray | None = None,
    step_angle: float = 0.05,
) -> ExcitationDesign:
    """The bounded piecewise-constant torque profile on `[0, duration]` that maximises the
    information about the inertia (see the module docstring), for a body near `inertia`
    (`(3,)` moments or a 3×3 tensor: the design is local, around a prior guess) starting at
    `omega0` (and `q0`), sampled `samples_per_segment` times per segment by a gyro of noise
    `sigma_omega` (and a star tracker of noise `sigma_angle`, if given).

    `n_segments` segments, `|u_i| ≤ torque_bound` on each axis; `steps` ascent steps of size
    `learning_rate` (in the unbounded variable z, `u = u_max tanh z`) from `init` (a torque
    profile `(n_segments, 3)`) or a PRBS drawn with `key` (default `PRNGKey(0)`); the RK4 steps
    turn the body by at most `step_angle`."""
    I = check_inertia(as_tensor(inertia))
    dtype = I.dtype
    w0 = check_finite(vector(omega0, 3, "omega0").astype(dtype), "omega0")
    for name, x in (("inertia", I), ("omega0", w0)):
        if concrete_value(x) is None:
            raise ValueError(
                f"{name} must be concrete (not traced under jax.jit or jax.vmap): the design's "
                "RK4 step count comes from the prior's rates; close over it, one design per prior"
            )
    duration = _positive(duration, "duration")
    torque_bound = _positive(torque_bound, "torque_bound")
    step_angle = _positive(step_angle, "step_angle")
    for name, x in (("sigma_omega", sigma_omega), ("sigma_angle", sigma_angle)):
        if x is not None:
            _positive(x, name, traced=True)  # (noise levels: traced ones go through)
    n_segments = integer(n_segments, "n_segments")
    samples_per_segment = integer(samples_per_segment, "samples_per_segment")
    steps = integer(steps, "steps", 0)
    q = None if q0 is None else _unit(vector(q0, 4, "q0").astype(dtype), "q0")
    S = n_segments
    ts = jnp.linspace(0.0, duration, S * samples_per_segment + 1, dtype=dtype)
    if init is None:
        u0 = 0.9 * prbs(jax.random.PRNGKey(0) if key is None else key, S, torque_bound, dtype)
    else:
        u0 = as_float(init, "init").astype(dtype)
        if u0.shape != (S, 3):
            raise ValueError(f"init must have shape ({S}, 3), got {tuple(u0.shape)}")
        u0 = check_finite(u0, "init")
    z0 = jnp.arctanh(jnp.clip(u0 / torque_bound, -0.999, 0.999))
    # the fastest rotation the bounded torque can reach: the step count of the flow
    rate = float(jnp.linalg.norm(w0)) + torque_bound * math.sqrt(3) * duration / float(
        jnp.linalg.eigvalsh(I)[0]
    )
    substeps = max(1, math.ceil(duration / (S * samples_per_segment) * rate / step_angle))
    return _ascend(
        I,
        w0,
        q,
        ts,
        z0,
        jnp.asarray(torque_bound, dtype),
        jnp.asarray(sigma_omega, dtype),
        None if sigma_angle is None else jnp.asarray(sigma_angle, dtype),
        jnp.asarray(learning_rate, dtype),
        steps,
        substeps,
    )


def _positive(x: object, name: str, *, traced: bool = False) -> float:
    """`x` as a float: a positive finite number, known now (or, with `traced`, unchecked
    while traced, returned as NaN: its value is not used here)."""
    v = concrete_value(x)
    if v is None and traced:
        return math.nan
    if v is None or v.ndim != 0 or v.dtype == bool or not (v > 0 and math.isfinite(v)):
        raise ValueError(f"{name} must be a positive number (known when called), got {x!r}")
    return float(v)


@quick_compile_jit
def _ascend(I, w0, q0, ts, z0, bound, sigma_omega, sigma_angle, lr, steps: int, substeps: int):
    def phi(z):
        F = fisher_information(
            I,
            w0,
            bound * jnp.tanh(z),
            ts,
            q0=q0,
            sigma_omega=sigma_omega,
            sigma_angle=sigma_angle,
            substeps=substeps,
        )
        return log_det_criterion(F)

    value_and_grad = jax.value_and_grad(phi)

    def step(carry, k):
        z, best_z, best = carry
        f, g = value_and_grad(z)
        better = f > best
        best_z = jnp.where(better, z, best_z)
        best = jnp.where(better, f, best)
        eta = lr * (1 - k / max(steps, 1))
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        z = z + eta * g / (jnp.sqrt(jnp.mean(g * g)) + 1e-30)
        return (z, best_z, best), f

    init = (z0, z0, jnp.asarray(-jnp.inf, z0.dtype))
    (z, best_z, best), history = jax.lax.scan(step, init, jnp.arange(steps, dtype=z0.dtype))
    f_last = phi(z)  # the last iterate too
    best_z = jnp.where(f_last > best, z, best_z)
    u = bound * jnp.tanh(best_z)
    F = fisher_information(
        I, w0, u, ts, q0=q0, sigma_omega=sigma_omega, sigma_angle=sigma_angle, substeps=substeps
    )
    cov = jnp.linalg.inv(F)
    std6 = jnp.sqrt(jnp.clip(jnp.diagonal(cov)[:6], 0.0))
    std = jnp.zeros((3, 3), std6.dtype)
    for k, (i, j) in enumerate(_ENTRIES):
        std = std.at[i, j].set(std6[k]).at[j, i].set(std6[k])
    return ExcitationDesign(
        torques=u,
        edges=jnp.linspace(ts[0], ts[-1], u.shape[0] + 1),
        ts=ts,
        log_det=log_det_criterion(F),
        history=jnp.concatenate([history, f_last[None]]),
        inertia_std=std,
    )
