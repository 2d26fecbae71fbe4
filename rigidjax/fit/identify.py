"""Identification of the inertia tensor from measured rotation: one or several experiments, gyro
and/or attitude data, gyro bias and scale factor, robust losses, covariance.

Least squares through the model of the motion (`rigidjax.fit.flow`: Euler's equations and the
quaternion kinematics, fixed RK4 steps), by Levenberg–Marquardt (`rigidjax.fit.levenberg`) with
forward-mode Jacobians. The unknowns (`rigidjax.fit.parameters`): the inertia (kept physical as
a constraint, planar bodies included), one initial state per experiment, and the sensor errors.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._checks import Check, check_frame, integer, is_concrete, validate, validate_all
from .._compile import quick_compile_jit
from .._custom_types import Frame, RealLike
from ..mechanics.inertia import as_tensor, check_inertia, principal_axes
from ..rotations import quat
from .covariance import METHODS, covariance
from .experiments import (
    Experiments,
    angular_rate,
    experiments,
    guess,
    initial_states,
    turned_angle,
)
from .flow import flow, substeps_for, torque_rows
from .initial import linear_inertia
from .levenberg import LMResult, levenberg_marquardt
from .losses import Loss, make_loss
from .parameters import Layout, inertia_from_params, params_from_inertia

__all__ = ["InertiaEstimate", "identify_inertia", "inertia_from_params", "params_from_inertia"]

TURN = 30.0  # rad: how far the first prefix of a long record turns the body (see `_fit`)
MAX_PREFIXES = 20


class InertiaEstimate(eqx.Module):
    """Result of `identify_inertia`.

    `inertia` (3×3, body axes) and its entry-wise standard deviation `inertia_std`, the
    `principal_moments` (ascending) and their std `principal_moments_std` (first-order:
    `var λ_i = (v_i⊗v_i)ᵀ Cov(I) (v_i⊗v_i)`); `omega0`, `q0`: the fitted initial state of each
    experiment (`(3,)`, `(4,)` for one experiment, `(E, 3)`, `(E, 4)` for several; `q0` is the
    given/identity one unless attitude data were fitted); `gyro_bias`, `gyro_scale` (`ω_gyro =
    (1 + s) ⊙ Ω + b`; zero where not fitted) and their std; `residuals`: the weighted residuals
    `z` (gyro block `(E, T, 3)`, then attitude, flattened); `cost = Σ ρ(z)`; `covariance` of the
    parameter vector (`rigidjax.fit.parameters`) by `covariance_method`; `converged`;
    `identifiable` (the Jacobian has full rank up to the scale gauge; `identify_inertia` raises
    when it does not); `scale`: how the unobservable scale was fixed; `loss`.
    """

    inertia: Float[Array, "3 3"]
    inertia_std: Float[Array, "3 3"]
    principal_moments_std: Float[Array, "3"]
    omega0: Float[Array, "*E 3"]
    q0: Float[Array, "*E 4"]
    gyro_bias: Float[Array, "3"]
    gyro_bias_std: Float[Array, "3"]
    gyro_scale: Float[Array, "3"]
    gyro_scale_std: Float[Array, "3"]
    residuals: Float[Array, " n"]
    cost: Float[Array, ""]
    covariance: Float[Array, "p p"]
    converged: Bool[Array, ""]
    identifiable: Bool[Array, ""]
    num_steps: Int[Array, ""]
    scale: str = eqx.field(static=True)
    loss: str = eqx.field(static=True, default="l2")
    covariance_method: str = eqx.field(static=True, default="gauss_newton")

    @property
    def principal_moments(self) -> Float[Array, "*batch 3"]:
        return principal_axes(self.inertia)[0]

    @property
    def principal_axes(self) -> Float[Array, "*batch 3 3"]:
        return principal_axes(self.inertia)[1]


def identify_inertia(
    ts: RealLike,
    omega_obs: RealLike | None = None,
    quat_obs: RealLike | None = None,
    torque: Callable | Sequence[Callable] | None = None,
    *,
    torque_frame: Frame = "body",
    inertia_guess: RealLike | None = None,
    omega0_guess: RealLike | None = None,
    q0_guess: RealLike | None = None,
    trace: float | None = None,
    sigma_omega: float = 1.0,
    sigma_angle: float = 1.0,
    gyro_bias: bool = False,
    gyro_scale: bool = False,
    loss: str = "l2",
    loss_scale: float | None = None,
    covariance: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    solver_rtol: float = 1e-10,
    solver_atol: float = 1e-14,
    max_steps: int | np.integer = 256,
    sim_max_steps: int | np.integer = 1_000_000,
) -> InertiaEstimate:
    """Fit the inertia tensor, the initial state of each experiment and the gyro errors to gyro
    data `omega_obs` (body angular velocity), attitude data `quat_obs` (scalar first), or both.

    Data: one experiment, `omega_obs (T, 3)` / `quat_obs (T, 4)` at `ts (T,)`; or E experiments
    of the same body, `(E, T, 3)` / `(E, T, 4)` at `ts (T,)` or `(E, T)`: one inertia tensor,
    one initial state per experiment, one set of sensor errors.

    Residuals: `z = ((1 + s) ⊙ Ω_model + b − ω_obs)/sigma_omega` and the tangent-space attitude
    error `log(q_obs⁻¹ ∘ q_model)/sigma_angle`; minimised: `Σ ρ(z)` with `loss` `"l2"`,
    `"huber"` or `"cauchy"` (`rigidjax.fit.losses`; `loss_scale` c in units of z, so give the
    sigmas with a robust loss). Unknowns: the six inertia parameters, Ω(0) and (with attitude
    data) q(0) of each experiment, the gyro bias b with `gyro_bias=True`, the per-axis gyro
    scale-factor error s with `gyro_scale=True` (with both data kinds, the gyro residuals are
    fitted first, then everything). Start: `inertia_guess` (moments or a tensor, checked as
    `RigidBody`'s: finite, positive definite, triangle inequality), else the linear
    least-squares estimate from Euler's equations (`rigidjax.fit.initial`), and where the fit
    from it fails (not converged, not identifiable, or a degenerate rod, as noisy attitude data
    can lead to) a sphere of its trace, keeping the better fit. The estimate is physical: the
    fit keeps the second-moment matrix `Σ = tr(I)/2 E − I ⪰ 0` as a constraint
    (`rigidjax.fit.parameters`), so a planar body (`I3 = I1 + I2`) is reached and identified
    like any other; where the constraint is active, the std is that of the unconstrained
    linearisation. A long record (the body turning through more than `TURN` = 30 rad) is fitted
    in growing prefixes, each turning it twice as far as the last (a continuation in the
    horizon: a small error of I shifts the phase of the motion in proportion to the time, and
    the cost of the whole record at once has minima all around the truth).

    Covariance (`rigidjax.fit.covariance`): `"gauss_newton"` (`s²(JᵀJ)⁻¹`, residual-variance
    scaled; default for `"l2"`) or `"sandwich"` (`A⁻¹BA⁻¹`; default for the robust losses).

    Scale: torque-free motion depends on I only up to a factor (Euler's equations are
    homogeneous in I), so without `torque` the tensor is normalised to `trace` (a positive
    number, default 1) and `result.scale` says so; with a known `torque(t, Ω, q)` (or one per
    experiment) the absolute tensor is fitted (unless `trace` is given). A torque piecewise
    constant between sample times is evaluated on the right piece.

    Integration (`rigidjax.fit.flow`): RK4 with each step turning the body by at most
    `h = min(rtol, atol)^(1/5)` rad (default 0.02 rad; RK4's local error is O(h⁵)); a sample
    interval that needs more than `sim_max_steps` steps is an error. `max_steps`: the most
    Levenberg–Marquardt steps (`converged` is False when they run out). The fit is compiled
    once per data shape and set of options, and `jax.vmap`-able over datasets.
    """
    check_frame(torque_frame, "torque_frame")
    data = experiments(ts, omega_obs, quat_obs)
    E, T = data.shape
    dtype = data.ts.dtype
    if trace is not None and type(trace) not in (int, float, bool) and is_concrete(trace):
        trace = float(trace)  # a NumPy or JAX scalar (np.float64 too: a static field's float)
    if trace is not None and not (
        isinstance(trace, int | float) and not isinstance(trace, bool) and 0 < trace < math.inf
    ):
        raise ValueError(
            f"trace must be positive (and finite), got {trace!r}: it is the trace the inertia "
            "tensor is normalised to (a Python number; the fit is compiled for it)"
        )
    max_steps, sim_max_steps = (
        integer(max_steps, "max_steps"),
        integer(sim_max_steps, "sim_max_steps"),
    )
    if torque is None and trace is None:
        trace = 1.0
    scale = (
        f"normalised to trace {trace:g} (the data fix the inertia only up to scale)"
        if torque is None
        else ("absolute (known torque)" if trace is None else f"trace fixed to {trace:g}")
    )
    if torque is not None and not callable(torque):
        torque = tuple(torque)
        if len(torque) != E or not all(callable(f) for f in torque):
            raise ValueError(
                f"torque must be one callable torque(t, omega, q) or a sequence of {E} (one per "
                "experiment)"
            )
    layout = Layout(E, data.quat is not None, bool(gyro_bias), bool(gyro_scale))
    n_res = 3 * E * T * ((data.omega is not None) + (data.quat is not None))
    n_par = layout.size - (trace is not None)
    if n_res <= n_par:
        raise ValueError(
            f"too few samples: {n_res} residuals for {n_par} unknowns; give more times in ts"
        )
    if (gyro_bias or gyro_scale) and data.omega is None:
        raise ValueError("gyro_bias and gyro_scale need gyro data: give omega_obs")
    rho = make_loss(loss, loss_scale, dtype)
    method = ("gauss_newton" if loss == "l2" else "sandwich") if covariance is None else covariance
    if method not in METHODS:
        raise ValueError(f"covariance must be one of {METHODS} or None, got {covariance!r}")
    tol = [x for x in (rtol, atol) if x is not None]
    checks = (("rtol", rtol), ("atol", atol), ("sigma_omega", sigma_omega))
    for name, x in (*checks, ("sigma_angle", sigma_angle)):
        if isinstance(x, int | float) and not x > 0:  # arrays (traced too) are taken as given
            raise ValueError(f"{name} must be a positive number, got {x!r}")
    step_angle = min(min(tol) ** 0.2, 0.1) if tol else 0.02

    I_guess = (
        None
        if inertia_guess is None
        else check_inertia(as_tensor(inertia_guess).astype(dtype), "inertia_guess")
    )
    model = _Model(
        torque,
        torque_frame,
        trace,
        jnp.asarray(sigma_omega, dtype),
        jnp.asarray(sigma_angle, dtype),
        rho,
    )
    est, needed = _fit(
        data,
        (
            I_guess,
            guess(omega0_guess, 3, E, "omega0_guess", dtype),
            guess(q0_guess, 4, E, "q0_guess", dtype),
        ),
        model,
        layout,
        _Options(method, step_angle, sim_max_steps, solver_rtol, solver_atol, max_steps),
        scale,
    )
    # an RK4 step count capped by sim_max_steps would make the model inaccurate: a wrong fit
    # (the check goes with every output, so that it runs whatever a jitted caller keeps)
    est = validate_all(
        needed,
        [
            Check(
                lambda xp, n: n > sim_max_steps,
                f"the model's simulation reached sim_max_steps = {sim_max_steps} RK4 steps in "
                "a sample interval",
                lambda n: (
                    f" (it needs {int(n)}: each step turns the body by at most {step_angle:g} rad "
                    "at the data's largest angular rate)"
                ),
                hint="; raise sim_max_steps, give samples closer together, or loosen rtol/atol",
            )
        ],
        on=cast(InertiaEstimate, est),
    )
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
    """What the fit assumes besides the data: the known torque(s), the gauge, the noise levels
    and the loss."""

    torque: Callable | tuple[Callable, ...] | None
    torque_frame: Frame = eqx.field(static=True)
    trace: float | None = eqx.field(static=True)
    sigma_omega: Array
    sigma_angle: Array
    loss: Loss


class _Options(eqx.Module):
    covariance: str = eqx.field(static=True)
    step_angle: float = eqx.field(static=True)
    sim_max_steps: int = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)


def _linear_guess(data: Experiments, q_ref: Array, model: _Model) -> Array:
    """`linear_inertia` from the gyro data (or attitude central differences) and the torque
    at the samples (at the measured attitude, else the starting one)."""
    if data.omega is not None:
        w = data.omega
    else:
        assert data.quat is not None
        dt = (data.ts[:, 2:] - data.ts[:, :-2])[..., None]
        w = quat.local(data.quat[:, :-2], data.quat[:, 2:]) / dt
        w = jnp.concatenate([w[:, :1], w, w[:, -1:]], axis=1)
    K = None
    if model.torque is not None:
        q = (
            data.quat
            if data.quat is not None
            else jnp.broadcast_to(q_ref[:, None], (*w.shape[:2], 4))
        )
        K = jax.vmap(
            lambda t, w, q: torque_rows(model.torque, model.torque_frame, t, w, q),
            in_axes=1,
            out_axes=1,
        )(data.ts, w, q)
    return linear_inertia(data.ts, w, K)


@quick_compile_jit
def _fit(
    data: Experiments,
    guesses: tuple[Array | None, Array | None, Array | None],
    model: _Model,
    layout: Layout,
    opts: _Options,
    scale: str,
) -> tuple[InertiaEstimate, Int[Array, ""]]:
    """The fit, compiled as one program (calls with the same shapes and options reuse it), and
    the most RK4 steps a sample interval needs (the model is integrated with at most
    `sim_max_steps`)."""
    data = data.arranged()
    E, T = data.shape
    I_guess, w_guess, q_guess = guesses
    w_guess, q_ref = initial_states(data, w_guess, q_guess)
    if I_guess is None:  # the linear least-squares estimate (rigidjax.fit.initial), then a
        # sphere of its trace where the fit from it fails (see below)
        I_lin = _linear_guess(data, q_ref, model)
        starts = jnp.stack([I_lin, jnp.trace(I_lin) / 3 * jnp.eye(3, dtype=I_lin.dtype)])
    else:
        starts = I_guess[None]
    p0s = jax.vmap(lambda I: layout.pack(params_from_inertia(I), w_guess))(starts)
    needed = substeps_for(data.ts, 1.25 * angular_rate(data), opts.step_angle, 2**31 - 1)
    substeps = jnp.minimum(needed, opts.sim_max_steps)

    # stages (one Levenberg–Marquardt loop, `rigidjax.fit.levenberg`): the gyro residuals with
    # ideal sensors, then with the sensor errors free, then with the attitude residuals too
    # (they wrap at π and make the cost multimodal far from the solution)
    gyro, att = data.omega is not None, data.quat is not None
    sensors = gyro and (layout.bias or layout.scale)
    s_sensors = 1 if sensors else 0
    s_attitude = s_sensors + 1 if gyro and att else 0
    # before them, on a long record, the first stage's residuals of growing prefixes: the cost
    # has more minima the longer the record (a small error of I shifts the phase of the motion
    # in proportion to the time), so the fit first follows the body through TURN rad, then
    # twice as far at each stage (a continuation in the horizon), up to the whole record; the
    # model is integrated over the prefix only, so that all of them cost about one whole stage
    turned = turned_angle(data)
    prefixes = jnp.clip(jnp.ceil(jnp.log2(jnp.max(turned[:, -1]) / TURN)), 0, MAX_PREFIXES)
    prefixes = prefixes.astype(jnp.int32)
    stages = prefixes + 1 + s_sensors + (gyro and att)

    def residuals(p, stage):
        inside = (turned <= TURN * jnp.exp2(stage)) | (stage >= prefixes)  # (E, T)
        steps = jnp.where(jnp.any(inside[:, 1:], axis=0), substeps, 0)  # none past the prefix
        inside = inside[..., None]
        stage = jnp.maximum(stage - prefixes, 0)
        I = layout.inertia(p, model.trace)
        b, s = (jnp.where(stage >= s_sensors, x, 0.0) for x in layout.gyro(p))

        W, Q = flow(
            I,
            layout.omega0(p),
            layout.q0(p, q_ref),
            data.ts,
            steps,
            model.torque,
            model.torque_frame,
            attitude=att or model.torque is not None,
        )
        z = []
        if data.omega is not None:
            dw = ((1 + s) * W + b - data.omega) / model.sigma_omega
            z.append(jnp.where(inside, dw, 0.0).reshape(-1))
        if data.quat is not None:
            dq = quat.local(data.quat, Q) / model.sigma_angle
            z.append(jnp.where(inside & (stage >= s_attitude), dq, 0.0).reshape(-1))
        z = jnp.concatenate(z)
        return model.loss.transform(z), z

    def solve(p0):
        return levenberg_marquardt(
            residuals,
            p0,
            stages=stages,
            coarse=prefixes,
            rtol=opts.rtol,
            atol=opts.atol,
            max_steps=opts.max_steps,
            constraint=layout.constraint,
            project=layout.project,
        )

    eps = jnp.finfo(p0s.dtype).eps
    free = p0s.shape[1] - (model.trace is not None)  # every parameter but the scale gauge

    def rank(J):  # of the (weighted) Jacobian (n, p)
        # full_matrices=False: JAX's LAPACK call allocates U even without compute_uv, (n, n) by
        # default (28.8 GB for 10⁴ samples of gyro and attitude data); (n, p) so, same values
        sv = jnp.linalg.svd(J, full_matrices=False, compute_uv=False)
        return jnp.sum(sv > jnp.sqrt(eps) * sv[0])

    def good(sol):  # converged, identifiable, and not a degenerate body (a rod: I_min = 0)
        I = layout.inertia(sol.params, model.trace)
        thick = jnp.linalg.eigvalsh(I)[0] > jnp.sqrt(eps) * jnp.trace(I)
        return sol.converged & (rank(sol.aux_jacobian) >= free) & thick

    def attempt(state):  # the fit from the next start, kept if better (converged, lower cost)
        k, best = state
        sol = solve(p0s[k])
        better = (sol.converged & ~best.converged) | (
            (sol.converged == best.converged) & (sol.cost < best.cost)
        )
        return k + 1, jax.tree.map(lambda a, b: jnp.where(better, a, b), sol, best)

    # the starts in turn until a good fit: the second (a sphere) runs only where the first
    # fails, as from noisy data, where the linear estimate can lead to a degenerate body
    r0, a0 = jax.eval_shape(residuals, p0s[0], jnp.asarray(0))
    n = p0s.shape[1]
    none = LMResult(
        *(jnp.zeros(shape, p0s.dtype) for shape in ((n,), r0.shape, (*r0.shape, n))),
        *(jnp.zeros(shape, p0s.dtype) for shape in (a0.shape, (*a0.shape, n))),
        cost=jnp.asarray(jnp.inf, p0s.dtype),
        num_steps=jnp.asarray(0),
        converged=jnp.asarray(False),
    )

    def more(state):
        return (state[0] < p0s.shape[0]) & ~good(state[1])

    _, sol = jax.lax.while_loop(more, attempt, (jnp.asarray(0), none))
    p, z, Jz = sol.params, sol.aux, sol.aux_jacobian
    gauge = layout.gauge(p, model.trace)
    cov = covariance(z, Jz, model.loss, opts.covariance, gauge)
    I = layout.inertia(p, model.trace)
    JI = jax.jacfwd(lambda x: inertia_from_params(x, model.trace))(p[:6]).reshape(9, 6)
    cov_I = JI @ cov[:6, :6] @ JI.T
    _, V = jnp.linalg.eigh(I)
    a = jax.vmap(lambda v: jnp.outer(v, v).reshape(9))(V.T)  # dλ_i/dI = v_i v_iᵀ
    std = jnp.sqrt(jnp.clip(jnp.diagonal(cov), 0.0))
    b, s = layout.gyro(p)
    k = layout.size - 3 * layout.scale
    zero = jnp.zeros(3, p.dtype)
    b_std = std[k - 3 : k] if layout.bias else zero
    s_std = std[layout.size - 3 :] if layout.scale else zero
    w0, q0 = layout.omega0(p), quat.canonical(layout.q0(p, q_ref))
    est = InertiaEstimate(
        inertia=I,
        inertia_std=jnp.sqrt(jnp.clip(jnp.diagonal(cov_I), 0.0)).reshape(3, 3),
        principal_moments_std=jnp.sqrt(jnp.clip(jnp.einsum("ia,ab,ib->i", a, cov_I, a), 0.0)),
        omega0=w0 if data.several else w0[0],
        q0=q0 if data.several else q0[0],
        gyro_bias=b,
        gyro_bias_std=b_std,
        gyro_scale=s,
        gyro_scale_std=s_std,
        residuals=z,
        cost=jnp.sum(model.loss.rho(z)),
        covariance=cov,
        converged=sol.converged,
        identifiable=rank(Jz) >= free,
        num_steps=sol.num_steps,
        scale=scale,
        loss=model.loss.name,
        covariance_method=opts.covariance,
    )
    return est, jnp.max(needed)
