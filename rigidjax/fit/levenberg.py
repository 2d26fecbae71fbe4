"""A small Levenberg–Marquardt loop for the fits (one `lax.while_loop`, forward-mode Jacobians).

Marquardt's damped Gauss–Newton step `(JᵀJ + λ diag(JᵀJ) + λ μ E) δ = −Jᵀr` (Marquardt 1963;
Nocedal & Wright, Numerical Optimization, §10.3): a step that lowers the cost is accepted and λ
shrinks by 3, otherwise λ grows by 4. The loop stops when a step (accepted or not) changes the
cost by less than `rtol · cost + atol` and no parameter by more than `√rtol (|p| + √rtol)`, or
after `max_steps` steps; also when no step lowers the cost any more (λ > 10¹⁶: a minimum to
rounding, as with exact data).

Constraint (optional): `c(p) ≥ 0` with its gradient n from `constraint(p)`, and `project(p)`
onto the feasible set. The damped step is the solution of the step's quadratic model `½ δᵀMδ
+ gᵀδ` (`M` the damped matrix above, `g = Jᵀr`) subject to the linearised constraint
`c + nᵀδ ≥ 0`: `δ = −M⁻¹g + ν M⁻¹n`, `ν = max(0, −(c − nᵀM⁻¹g)/(nᵀM⁻¹n))` (Nocedal & Wright
§16.1; the projection in the metric M, so that the loop stops at a Karush–Kuhn–Tucker point
of the constrained problem), and the trial point is `project(p + δ)` (feasible exactly; the
change by `project` is of second order). The loop can so reach and stay on the boundary of the
feasible set, where a smooth reparametrisation would be singular.

Stages: `residuals(p, stage)` may depend on an integer stage `0 … stages − 1`; when stage `s`
has converged the loop goes on from its solution with stage `s + 1` (the identification fits
the smooth gyro residuals before the attitude ones, and a long record's prefixes before it).
The first `coarse` stages are way stations: they stop at the tolerance `max(rtol, 1e-6)`. One
loop, one trace of the Jacobian: the compile time of the fit stays that of one iteration, and
it is independent of the number of stages. The Jacobian and residuals at the solution come back
with the result.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

__all__ = ["LMResult", "levenberg_marquardt"]

COARSE = 1e-6  # the tolerance of the stages before `coarse`: way stations, not answers


class LMResult(NamedTuple):
    """`params`; `residuals` and `jacobian` at `params` (the last stage) as returned by the
    residual function's first output (what is minimised) and its `aux` (second output, with its
    Jacobian `aux_jacobian`); `cost = ½ Σ r²`; `num_steps`; `converged`."""

    params: Float[Array, " p"]
    residuals: Float[Array, " n"]
    jacobian: Float[Array, "n p"]
    aux: Float[Array, " m"]
    aux_jacobian: Float[Array, "m p"]
    cost: Float[Array, ""]
    num_steps: Int[Array, ""]
    converged: Bool[Array, ""]


def levenberg_marquardt(
    residuals: Callable[[Array, Array], tuple[Array, Array]],
    p0: Float[Array, " p"],
    *,
    stages: int | Int[Array, ""] = 1,
    coarse: int | Int[Array, ""] = 0,
    rtol: float = 1e-10,
    atol: float = 1e-14,
    max_steps: int = 256,
    constraint: Callable[[Array], tuple[Array, Array]] | None = None,
    project: Callable[[Array], Array] | None = None,
) -> LMResult:
    """Minimise `½ |r(p)|²` where `(r, aux) = residuals(p, stage)`, subject to `c(p) ≥ 0` with
    `(c, ∇c) = constraint(p)` and `project` if given (p0 is projected first); see the module
    docstring."""
    dtype = p0.dtype
    mu = jnp.asarray(1e-9, dtype)

    def evaluate(p, stage):
        (J, Ja), (r, a) = jax.jacfwd(lambda x: (residuals(x, stage),) * 2, has_aux=True)(p)
        return r, J, a, Ja

    # the shapes of (r, J, aux, aux_J) from the residuals alone: tracing the Jacobian for
    # them would double the fit's tracing time
    r0, a0 = jax.eval_shape(residuals, p0, jnp.asarray(0))
    zeros = [
        jnp.zeros(shape, x.dtype) for x in (r0, a0) for shape in (x.shape, (*x.shape, p0.shape[0]))
    ]
    inf = jnp.asarray(jnp.inf, dtype)

    # state: p, (r, J, aux, aux_J) at p, cost, λ, stage, steps, done
    def cond(s):
        return ~s[-1] & (s[-2] < max_steps)

    def body(s):
        p, (r, J, a, Ja), cost, lam, stage, k, _ = s
        H, g = J.T @ J, J.T @ r
        M = H + lam * (jnp.diag(jnp.diag(H)) + mu * jnp.eye(p.shape[0], dtype=dtype))
        if constraint is None:
            dp = -jnp.linalg.solve(M, g)
        else:  # the step's model minimised subject to the linearised constraint c + nᵀδ ≥ 0
            c, n = constraint(p)
            x = jnp.linalg.solve(M, jnp.stack([g, n], axis=1))
            dp, Mn = -x[:, 0], x[:, 1]
            dp = dp + jnp.maximum(0.0, -(c + n @ dp) / (n @ Mn)) * Mn
        dp = jnp.where(jnp.isfinite(dp), dp, 0.0)
        if project is not None:
            dp = project(p + dp) - p
        trial = evaluate(p + dp, stage)
        new_cost = 0.5 * trial[0] @ trial[0]
        accept = new_cost < cost
        tol = jnp.where(stage < coarse, max(rtol, COARSE), rtol)
        small = jnp.all(jnp.abs(dp) <= jnp.sqrt(tol) * (jnp.abs(p) + jnp.sqrt(tol)))
        # a small step that changes the cost by less than the tolerance either way (accepted,
        # or rejected: at a minimum to rounding, where waiting for λ to grow past 10¹⁶ took
        # ~40 steps), a zero gradient, or no step lowers the cost (λ huge); not on the first
        # evaluation of a stage (cost ∞)
        stalled = (jnp.abs(cost - new_cost) <= tol * cost + atol) & small
        stalled = stalled | (jnp.max(jnp.abs(g)) <= atol) | (lam > 1e16)
        stalled = stalled & jnp.isfinite(cost)
        p = jnp.where(accept, p + dp, p)
        vals = jax.tree.map(lambda x, y: jnp.where(accept, x, y), trial, (r, J, a, Ja))
        cost = jnp.where(accept, new_cost, cost)
        lam = jnp.where(accept, jnp.maximum(lam / 3, 1e-12), lam * 4)
        last = stage == stages - 1
        done = stalled & last
        # next stage: restart from p (cost ∞, zero Jacobian: the next step is δ = 0 and
        # evaluates the new stage's residuals there)
        advance = stalled & ~last
        vals = jax.tree.map(lambda x, z: jnp.where(advance, z, x), vals, tuple(zeros))
        cost = jnp.where(advance, inf, cost)
        lam = jnp.where(advance, 1e-3, lam)
        return p, vals, cost, lam, stage + advance, k + 1, done

    p0 = p0 if project is None else project(p0)
    lam0, int0 = jnp.asarray(1e-3, dtype), jnp.asarray(0)
    init = (p0, tuple(zeros), inf, lam0, int0, int0, jnp.asarray(False))
    p, (r, J, a, Ja), cost, _, _, k, done = jax.lax.while_loop(cond, body, init)
    converged = done & jnp.isfinite(cost)
    return LMResult(p, r, J, a, Ja, cost, k, converged)
