"""Covariance of least-squares and M-estimates, with a gauge direction removed.

With weighted residuals `z (n,)`, their Jacobian `J (n, p)` at the estimate and `d` degrees of
freedom used (`p` minus the gauge directions):

- `"gauss_newton"`: `s² (JᵀJ)⁺` with the residual variance `s² = Σ z²/(n − d)` (Seber & Wild,
  Nonlinear Regression, 1989, §2.1): right when the weights are correct up to one common factor;
- `"sandwich"`: `n/(n − d) · A⁺ B A⁺` with `A = Σ ψ'(z_i) J_iᵀJ_i`, `B = Σ ψ(z_i)² J_iᵀJ_i`
  (Huber & Ronchetti, Robust Statistics, 2009, §6.2; White 1980 for ψ(z) = z): also right
  when the noise level differs between residuals (gyro vs attitude, one axis vs another), and
  the covariance of a robust (Huber, Cauchy) fit.

Gauge: a direction `u` of the parameters that changes no residual (the overall scale of the
inertia factor when the trace is fixed) makes JᵀJ singular. With `G = A + c uuᵀ` (`c > 0`),
`A⁺ = G⁻¹ − uuᵀ/c` exactly when `Au = 0` (`u` unit): a well-conditioned solve instead of a
pseudo-inverse with a threshold.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .losses import Loss

__all__ = ["METHODS", "covariance"]

METHODS = ("gauss_newton", "sandwich")


def _pinv(A: Float[Array, "p p"], gauge: Float[Array, " p"] | None) -> Float[Array, "p p"]:
    if gauge is None:
        return jnp.linalg.inv(A)
    u = gauge / jnp.linalg.norm(gauge)
    c = jnp.trace(A) / A.shape[0]
    return jnp.linalg.inv(A + c * jnp.outer(u, u)) - jnp.outer(u, u) / c


def covariance(
    z: Float[Array, " n"],
    J: Float[Array, "n p"],
    loss: Loss,
    method: str,
    gauge: Float[Array, " p"] | None = None,
) -> Float[Array, "p p"]:
    """The covariance of the parameters by `method` (one of `METHODS`), see the module
    docstring; `gauge`: the direction that changes no residual, or None."""
    n, p = J.shape
    dof = n - (p - (gauge is not None))
    if method == "gauss_newton":
        return jnp.sum(loss.transform(z) ** 2) / dof * _pinv(J.T @ J, gauge)
    A_inv = _pinv(J.T @ (loss.dpsi(z)[:, None] * J), gauge)
    B = J.T @ (loss.psi(z)[:, None] ** 2 * J)
    return n / dof * A_inv @ B @ A_inv
