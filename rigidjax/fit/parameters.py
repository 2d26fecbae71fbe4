"""The unknowns of an identification as one flat vector, and the physical inertia parameters.

Inertia: the six entries of the second-moment ("pseudo-inertia") matrix `Σ = tr(I)/2 E − I`,
`θ = (Σ11, Σ22, Σ33, Σ12, Σ13, Σ23)`, with `I = tr(Σ) E − Σ` (linear both ways). The principal
moments are `I_i = σ_j + σ_k` (σ the eigenvalues of Σ), so `Σ ⪰ 0` is exactly the physical
set: positive moments that satisfy the triangle inequality (Wensing, Kim & Slotine, "Linear
matrix inequalities for physically consistent inertial parameter identification", IEEE RA-L
2018). The fits keep `Σ ⪰ 0` as a constraint (`feasibility`, `project`: the smallest
eigenvalue `σ_min ≥ 0`) rather than by a factor `Σ = L Lᵀ`: the map `L ↦ L Lᵀ` is singular
wherever `Σ` is (its Jacobian loses rank when a diagonal entry of L vanishes), so a planar
body (`σ_min = 0`, `I3 = I1 + I2`, a legitimate `RigidBody`) would be a singular point of the
fit: a rank-deficient Jacobian (reported as not identifiable), no covariance, slow
convergence. In θ the Jacobian is regular up to the boundary, planar bodies included. With the
trace fixed, the overall scale of θ is a gauge direction. A rank-one Σ (a rod) has a zero
moment: no rigid body the fits can simulate.

The vector: `[θ (6) | Ω0 (E × 3) | δq0 (E × 3, with attitude data) | bias (3) | scale (3)]`,
where `q0 = q_ref ∘ exp(δq0)` and the gyro model is `ω_gyro = (1 + s) ⊙ Ω + b`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..rotations import quat

__all__ = ["Layout", "feasibility", "inertia_from_params", "params_from_inertia", "project"]


def _sym(params: Float[Array, "6"]) -> Float[Array, "3 3"]:
    """Σ (symmetric) from (Σ11, Σ22, Σ33, Σ12, Σ13, Σ23)."""
    p = params
    return jnp.stack(
        [
            jnp.stack([p[0], p[3], p[4]]),
            jnp.stack([p[3], p[1], p[5]]),
            jnp.stack([p[4], p[5], p[2]]),
        ]
    )


def inertia_from_params(params: Float[ArrayLike, "6"], trace: float | None) -> Float[Array, "3 3"]:
    """`I = tr(Σ) E − Σ`, rescaled to `trace` if given (physical where `Σ ⪰ 0`)."""
    S = _sym(jnp.asarray(params))
    I = jnp.trace(S) * jnp.eye(3, dtype=S.dtype) - S
    return I if trace is None else I * (trace / jnp.trace(I))


def params_from_inertia(
    I: Float[ArrayLike, "3 3"], trace: float | None = None
) -> Float[Array, "6"]:
    """Parameters of `I`: the entries of `Σ = tr(I)/2 E − I` (exact, planar bodies included)."""
    del trace  # the same parameters serve both gauges
    I = jnp.asarray(I)
    S = jnp.trace(I) / 2 * jnp.eye(3, dtype=I.dtype) - I
    return jnp.stack([S[0, 0], S[1, 1], S[2, 2], S[1, 0], S[2, 0], S[2, 1]])


def feasibility(params: Float[Array, "6"]) -> tuple[Float[Array, ""], Float[Array, "6"]]:
    """`(c, ∇c)`: `c = σ_min(Σ) = vᵀΣv` (≥ 0: physical; v its unit eigenvector) and its
    gradient `∂c/∂θ = (v1², v2², v3², 2v1v2, 2v1v3, 2v2v3)` (first-order perturbation of a
    simple eigenvalue)."""
    s, V = jnp.linalg.eigh(_sym(params))
    v = V[:, 0]
    return s[0], jnp.stack(
        [v[0] ** 2, v[1] ** 2, v[2] ** 2, 2 * v[0] * v[1], 2 * v[0] * v[2], 2 * v[1] * v[2]]
    )


def project(params: Float[Array, "6"]) -> Float[Array, "6"]:
    """The nearest physical parameters (Frobenius-nearest `Σ ⪰ 0`: negative eigenvalues set to
    0); a physical θ is returned unchanged."""
    s, V = jnp.linalg.eigh(_sym(params))
    S = (V * jnp.maximum(s, 0.0)) @ V.T
    clipped = jnp.stack([S[0, 0], S[1, 1], S[2, 2], S[1, 0], S[2, 0], S[2, 1]])
    return jnp.where(s[0] < 0, clipped, params)


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

    def pack(self, theta, omega0) -> Float[Array, " p"]:
        """The starting vector from θ and Ω0 (E, 3): zero attitude increments, bias and scale
        error."""
        n = 3 * self.E * self.attitude + 3 * self.bias + 3 * self.scale
        return jnp.concatenate([theta, omega0.reshape(-1), jnp.zeros(n, omega0.dtype)])

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
        """The direction that changes nothing (the scale of θ with the trace fixed)."""
        if trace is None:
            return None
        return jnp.zeros_like(p).at[:6].set(p[:6])

    def constraint(self, p) -> tuple[Float[Array, ""], Float[Array, " p"]]:
        """`feasibility` of the inertia parameters, its gradient padded to the whole vector."""
        c, n = feasibility(p[:6])
        return c, jnp.zeros_like(p).at[:6].set(n)

    def project(self, p) -> Float[Array, " p"]:
        """`p` with the inertia parameters made physical (`project`)."""
        return p.at[:6].set(project(p[:6]))
