"""The unknowns of an identification as one flat vector, and the physical inertia parameters.

Inertia: with the second-moment ("pseudo-inertia") matrix `Σ = L Lᵀ ⪰ 0` (L lower triangular,
six free entries), `I = tr(Σ) E − Σ` has principal moments `I_i = σ_j + σ_k ≥ 0` (σ ≥ 0 the
eigenvalues of Σ), which satisfy the triangle inequality: EVERY parameter value is a physical
body (Wensing, Kim & Slotine, "Linear matrix inequalities for physically consistent inertial
parameter identification", IEEE RA-L 2018: the pseudo-inertia `Σ ⪰ 0`; Rucker & Wensing,
"Smooth parameterization of rigid-body inertia", IEEE RA-L 2022: its Cholesky factor). Planar
bodies (one σ = 0, `I3 = I1 + I2`) lie inside the parameter space; only a rank-one Σ (a rod)
is singular. With the trace fixed, the overall scale of L is a gauge direction.

The vector: `[L (6) | Ω0 (E × 3) | δq0 (E × 3, with attitude data) | bias (3) | scale (3)]`,
where `q0 = q_ref ∘ exp(δq0)` and the gyro model is `ω_gyro = (1 + s) ⊙ Ω + b`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..rotations import quat

__all__ = ["Layout", "inertia_from_params", "params_from_inertia"]


def _tril(params: Float[Array, "6"]) -> Float[Array, "3 3"]:
    """L (lower triangular) from (L00, L11, L22, L10, L20, L21)."""
    L = jnp.diag(params[:3])
    return L.at[1, 0].set(params[3]).at[2, 0].set(params[4]).at[2, 1].set(params[5])


def inertia_from_params(params: Float[ArrayLike, "6"], trace: float | None) -> Float[Array, "3 3"]:
    """`I = tr(Σ) E − Σ`, Σ = L Lᵀ, rescaled to `trace` if given (physical for every value)."""
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


class Layout(NamedTuple):
    """Where each unknown sits in the flat vector (static: part of the compiled program)."""

    E: int
    attitude: bool
    bias: bool
    scale: bool

    @property
    def size(self) -> int:
        return 6 + 3 * self.E * (1 + self.attitude) + 3 * self.bias + 3 * self.scale

    def _at(self, name: str) -> int:
        k = 6 + 3 * self.E
        if name == "q0":
            return k
        k += 3 * self.E * self.attitude
        return k if name == "bias" else k + 3 * self.bias

    def pack(self, L, omega0) -> Float[Array, " p"]:
        """The starting vector from L and Ω0 (E, 3): zero attitude increments, bias and scale
        error."""
        n = 3 * self.E * self.attitude + 3 * self.bias + 3 * self.scale
        return jnp.concatenate([L, omega0.reshape(-1), jnp.zeros(n, omega0.dtype)])

    def inertia(self, p, trace: float | None) -> Float[Array, "3 3"]:
        return inertia_from_params(p[:6], trace)

    def omega0(self, p) -> Float[Array, "E 3"]:
        return p[6 : 6 + 3 * self.E].reshape(self.E, 3)

    def q0(self, p, q_ref) -> Float[Array, "E 4"]:
        if not self.attitude:
            return q_ref
        k = self._at("q0")
        return quat.retract(q_ref, p[k : k + 3 * self.E].reshape(self.E, 3))

    def gyro(self, p) -> tuple[Float[Array, "3"], Float[Array, "3"]]:
        """`(b, s)` of the gyro model (zeros where not fitted)."""
        zero = jnp.zeros(3, p.dtype)
        b = p[self._at("bias") :][:3] if self.bias else zero
        s = p[self._at("scale") :][:3] if self.scale else zero
        return b, s

    def gauge(self, p, trace: float | None) -> Float[Array, " p"] | None:
        """The direction that changes nothing (the scale of L with the trace fixed)."""
        if trace is None:
            return None
        return jnp.zeros_like(p).at[:6].set(p[:6])
