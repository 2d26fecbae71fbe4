"""Gradient-based identification of the inertia tensor from measured rotation.

Least squares through the simulator (optimistix Levenberg–Marquardt; Jacobians in forward mode
through Diffrax with `ForwardMode`). The inertia is parameterised so that EVERY parameter value is
a physical body: with the second-moment ("pseudo-inertia") matrix Σ = L Lᵀ ⪰ 0 (L lower
triangular, six free entries), the inertia `I = tr(Σ) E − Σ` has principal moments
`I_i = σ_j + σ_k ≥ 0` (σ ≥ 0 the eigenvalues of Σ), which satisfy the triangle inequality. Planar
bodies (one σ = 0, `I3 = I1 + I2`) lie inside the parameter space, not on an unreachable
boundary; only a rank-one Σ (a rod, `I3 = 0`) is singular.
"""

from __future__ import annotations

from collections.abc import Callable

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float

from .._checks import as_float, check_finite, check_times, validate, vector
from .._custom_types import Frame, RealLike
from .._integrate import SolveOptions
from ..mechanics.body import RigidBody
from ..mechanics.dynamics import simulate
from ..mechanics.inertia import as_tensor, principal_axes
from ..rotations import quat


class InertiaEstimate(eqx.Module):
    """Result of `identify_inertia`.

    `inertia` (3×3, body axes); `omega0`, `q0` (fitted initial state; `q0` is the given/identity
    one unless attitude data were fitted); `residuals` (weighted, at the solution); `cost` =
    ½ Σ r²; `covariance` (Gauss–Newton `s² (JᵀJ)⁻¹` of the parameter vector) and `inertia_std`
    (its propagation to the 3×3 entries); `converged` (solver success with a finite cost);
    `identifiable` (the Jacobian of the residuals has full rank, up to the scale gauge: the data
    fix every inertia parameter; `identify_inertia` raises when they do not); `scale`: how the
    unobservable scale was fixed.
    """

    inertia: Float[Array, "3 3"]
    omega0: Float[Array, "3"]
    q0: Float[Array, "4"]
    residuals: Float[Array, " n"]
    cost: Float[Array, ""]
    covariance: Float[Array, "p p"]
    inertia_std: Float[Array, "3 3"]
    converged: Bool[Array, ""]
    identifiable: Bool[Array, ""]
    num_steps: Array
    scale: str = eqx.field(static=True)

    @property
    def principal_moments(self) -> Float[Array, "3"]:
        return principal_axes(self.inertia)[0]

    @property
    def principal_axes(self) -> Float[Array, "3 3"]:
        return principal_axes(self.inertia)[1]


def _tril(params: Float[Array, "6"]) -> Float[Array, "3 3"]:
    """L (lower triangular) from (L00, L11, L22, L10, L20, L21)."""
    L = jnp.diag(params[:3])
    return L.at[1, 0].set(params[3]).at[2, 0].set(params[4]).at[2, 1].set(params[5])


def inertia_from_params(params: Float[ArrayLike, "6"], trace: float | None) -> Float[Array, "3 3"]:
    """`I = tr(Σ) E − Σ`, Σ = L Lᵀ, rescaled to `trace` if given (physical for every value;
    with `trace` the overall scale of L is a redundant direction, harmless to Levenberg–Marquardt
    and removed from the covariance by the pseudo-inverse)."""
    L = _tril(jnp.asarray(params))
    S = L @ L.T
    I = jnp.trace(S) * jnp.eye(3, dtype=S.dtype) - S
    return I if trace is None else I * (trace / jnp.trace(I))


def params_from_inertia(
    I: Float[ArrayLike, "3 3"], trace: float | None = None
) -> Float[Array, "6"]:
    """Parameters of `I` (Σ = tr(I)/2 E − I, Cholesky; a planar body's singular Σ is nudged by
    1e-9·tr Σ so the factor exists)."""
    del trace  # the same factor serves both gauges
    I = jnp.asarray(I)
    S = jnp.trace(I) / 2 * jnp.eye(3, dtype=I.dtype) - I
    L = jnp.linalg.cholesky(S + 1e-9 * jnp.trace(S) * jnp.eye(3, dtype=I.dtype))
    return jnp.concatenate([jnp.diagonal(L), jnp.stack([L[1, 0], L[2, 0], L[2, 1]])])


def identify_inertia(
    ts: RealLike,
    omega_obs: RealLike | None = None,
    quat_obs: RealLike | None = None,
    torque: Callable | None = None,
    *,
    torque_frame: Frame = "body",
    inertia_guess: RealLike | None = None,
    omega0_guess: RealLike | None = None,
    q0_guess: RealLike | None = None,
    trace: float | None = None,
    sigma_omega: float = 1.0,
    sigma_angle: float = 1.0,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    solver_rtol: float = 1e-10,
    solver_atol: float = 1e-12,
    max_steps: int = 256,
    sim_max_steps: int = 100_000,
) -> InertiaEstimate:
    """Fit the inertia tensor and the initial state to gyro data `omega_obs (T, 3)` (body angular
    velocity), attitude data `quat_obs (T, 4)` (scalar first), or both, sampled at `ts (T,)`.

    Residuals: `(Ω_model − Ω_obs)/sigma_omega` and the tangent-space attitude error
    `log(q_obs⁻¹ ∘ q_model)/sigma_angle` (a 3-vector per sample). Unknowns: the six inertia
    parameters (physical by construction), Ω(0), and q(0) when attitude data are given (with
    both kinds of data, a gyro-only fit first provides the starting point).

    Scale: torque-free motion depends on I only up to a factor (Euler's equations are
    homogeneous in I), so without `torque` the tensor is normalised to `trace` (default 1) and
    `result.scale` says so; with a known `torque(t, Ω, q)` the absolute tensor is fitted (unless
    `trace` is given). `vmap`-able over datasets. A (nearly) planar body, `I3 ≈ I1 + I2`, sits
    where Σ is singular and the Cholesky factor flattens the cost: convergence is slower there
    (raise `max_steps`).
    """
    ts = check_times(as_float(ts, "ts"))
    if omega_obs is None and quat_obs is None:
        raise ValueError("give omega_obs (gyro data), quat_obs (attitude data), or both")
    dtype = ts.dtype
    T = ts.shape[0]
    if omega_obs is not None:
        omega_obs = check_finite(vector(omega_obs, 3, "omega_obs").astype(dtype), "omega_obs")
        if omega_obs.shape != (T, 3):
            raise ValueError(f"omega_obs must have shape ({T}, 3), got {tuple(omega_obs.shape)}")
    if quat_obs is not None:
        quat_obs = check_finite(vector(quat_obs, 4, "quat_obs").astype(dtype), "quat_obs")
        if quat_obs.shape != (T, 4):
            raise ValueError(f"quat_obs must have shape ({T}, 4), got {tuple(quat_obs.shape)}")
        quat_obs = validate(
            quat_obs,
            lambda xp, q: ~(xp.sum(q * q, axis=-1) > 0),
            "quat_obs must hold non-zero quaternions (they are normalised)",
            hint="; drop the samples without attitude",
        )
        quat_obs = quat.normalize(quat_obs)
    if torque is None and trace is None:
        trace = 1.0
    scale = (
        f"normalised to trace {trace:g} (the data fix the inertia only up to scale)"
        if torque is None
        else ("absolute (known torque)" if trace is None else f"trace fixed to {trace:g}")
    )

    fit_q0 = quat_obs is not None
    n_res = 3 * T * ((omega_obs is not None) + fit_q0)
    n_par = (5 if trace is not None else 6) + 3 + 3 * fit_q0  # identifiable unknowns
    if n_res <= n_par:
        raise ValueError(
            f"too few samples: {n_res} residuals for {n_par} unknowns; give more times in ts"
        )

    if inertia_guess is None:
        I_guess = jnp.eye(3, dtype=dtype) * ((trace if trace is not None else 3.0) / 3)
    else:
        I_guess = as_tensor(inertia_guess).astype(dtype)
    if omega0_guess is not None:
        w_guess = vector(omega0_guess, 3, "omega0_guess").astype(dtype)
    elif omega_obs is not None:
        w_guess = omega_obs[0]
    else:  # attitude only: finite-difference the first two samples
        assert quat_obs is not None
        w_guess = quat.local(quat_obs[0], quat_obs[1]) / (ts[1] - ts[0])
    if q0_guess is not None:
        q_ref = quat.normalize(vector(q0_guess, 4, "q0_guess").astype(dtype))
    elif fit_q0:
        q_ref = quat_obs[0]
    else:
        q_ref = quat.identity(dtype=dtype)

    model = _Model(torque, torque_frame, trace, scale, sigma_omega, sigma_angle)
    # forward mode: the Jacobian of the residuals is what Levenberg–Marquardt needs
    sim = SolveOptions(rtol=rtol, atol=atol, max_steps=sim_max_steps, adjoint=diffrax.ForwardMode())
    lm = optx.LevenbergMarquardt(rtol=solver_rtol, atol=solver_atol)
    start = (params_from_inertia(I_guess, trace), w_guess, q_ref)
    est = _fit(ts, omega_obs, quat_obs, start, model, sim, lm, max_steps)
    identifiable = validate(
        est.identifiable,
        lambda xp, ok: ~ok,
        "the inertia is not identifiable from these data: the fitted motion does not depend on "
        "every inertia parameter (e.g. Ω is constant: a spin about a principal axis, or too "
        "short a record)",
        hint="; use data of a tumbling (non-steady) motion, a longer record, or a known torque",
    )
    return eqx.tree_at(lambda e: e.identifiable, est, identifiable)


class _Model(eqx.Module):
    """What the fit assumes besides the data: the known torque, the gauge and the noise levels."""

    torque: Callable | None
    torque_frame: Frame = eqx.field(static=True)
    trace: float | None = eqx.field(static=True)
    scale: str = eqx.field(static=True)
    sigma_omega: float
    sigma_angle: float


@eqx.filter_jit
def _fit(
    ts: Array,
    omega_obs: Array | None,
    quat_obs: Array | None,
    start: tuple[Array, Array, Array],
    model: _Model,
    sim: SolveOptions,
    lm: optx.LevenbergMarquardt,
    max_steps: int,
) -> InertiaEstimate:
    """The least-squares fit, compiled as one program (repeated calls with the same shapes and
    settings reuse it)."""
    dtype = ts.dtype
    fit_q0 = quat_obs is not None
    trace, k = model.trace, 6
    inertia_params0, w_guess, q_ref = start

    def unpack(p):
        I = inertia_from_params(p[:k], trace)
        q0 = quat.retract(q_ref, p[k + 3 : k + 6]) if p.shape[0] > k + 3 else q_ref
        return I, p[k : k + 3], q0

    def residuals(p, use_attitude):
        I, w0, q0 = unpack(p)
        traj = simulate(
            RigidBody(I, check=False),
            w0,
            q0,
            ts,
            torque=model.torque,
            torque_frame=model.torque_frame,
            options=sim,
        )
        out = []
        if omega_obs is not None:
            out.append(((traj.omega - omega_obs) / model.sigma_omega).reshape(-1))
        if use_attitude:
            assert quat_obs is not None
            out.append((quat.local(quat_obs, traj.quat) / model.sigma_angle).reshape(-1))
        return jnp.concatenate(out)

    def fit(p0, use_attitude):
        return optx.least_squares(
            residuals,
            lm,
            p0,
            args=use_attitude,
            max_steps=max_steps,
            throw=False,
        )

    p0 = jnp.concatenate([inertia_params0, w_guess])
    if fit_q0 and omega_obs is not None:
        # Attitude residuals wrap at π and make the cost multimodal far from the solution:
        # fit the (smooth) gyro residuals first, then everything from there.
        p0 = fit(p0, False).value
    sol = fit(jnp.concatenate([p0, jnp.zeros(3, dtype)]) if fit_q0 else p0, fit_q0)
    p = sol.value
    # residuals and Jacobian at the solution from one forward-mode pass
    J, r = jax.jacfwd(lambda q: (residuals(q, fit_q0),) * 2, has_aux=True)(p)
    cost = 0.5 * jnp.sum(r * r)
    # with `trace` fixed the scale of L is not identifiable: one parameter fewer
    s2 = 2 * cost / (r.shape[0] - p.shape[0] + (trace is not None))
    cov = s2 * jnp.linalg.pinv(J.T @ J)
    # rank of the (weighted) Jacobian: every parameter but the scale gauge must be fixed
    sv = jnp.linalg.svd(J, compute_uv=False)
    rank = jnp.sum(sv > jnp.sqrt(jnp.finfo(dtype).eps) * sv[0])
    JI = jax.jacfwd(lambda q: inertia_from_params(q, trace))(p[:k]).reshape(9, k)
    I_std = jnp.sqrt(jnp.diagonal(JI @ cov[:k, :k] @ JI.T)).reshape(3, 3)
    I, w0, q0 = unpack(p)
    return InertiaEstimate(
        inertia=I,
        omega0=w0,
        q0=quat.canonical(q0),
        residuals=r,
        cost=cost,
        covariance=cov,
        inertia_std=I_std,
        converged=(sol.result == optx.RESULTS.successful) & jnp.isfinite(cost),
        identifiable=rank >= p.shape[0] - (trace is not None),
        num_steps=sol.stats["num_steps"],
        scale=model.scale,
    )
