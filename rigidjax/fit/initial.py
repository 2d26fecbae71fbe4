"""The starting inertia of a fit: Euler's equations are LINEAR in the six entries of I.

`I Ω̇ + Ω × IΩ = K` reads `A(Ω, Ω̇) θ = K` with `θ = (I11, I22, I33, I12, I13, I23)` and
`A = L(Ω̇) + Ω̂ L(Ω)`, where `I a = L(a) θ`. With Ω from the gyro (or from attitude differences)
and Ω̇ from central differences, the equations of all samples and experiments are solved in
the least-squares sense: torque-free, `θ` is the right singular vector of the smallest singular
value (the scale is free); with a known torque, `θ = A⁺K`. This is the classical linear
estimate of spacecraft inertia (e.g. Tanygin & Williams, "Mass property estimation using
coasting maneuvers", J. Guidance 1997); the nonlinear fit starts from it, which keeps
Levenberg–Marquardt away from the local minima that an isotropic start can fall into; where
that fit fails, from a sphere, which escapes those of a linear estimate spoiled by noise
(attitude data differenced twice). The
estimate is made physical by clipping the eigenvalues of `Σ = tr(I)/2 E − I` at 1% of the
largest (`rigidjax.fit.parameters`).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..rotations import so3

__all__ = ["linear_inertia"]


def _lin(a: Float[Array, "*n 3"]) -> Float[Array, "*n 3 6"]:
    """`L(a)` with `I a = L(a) θ`, θ = (I11, I22, I33, I12, I13, I23)."""
    a1, a2, a3 = a[..., 0], a[..., 1], a[..., 2]
    z = jnp.zeros_like(a1)
    rows = [
        [a1, z, z, a2, a3, z],
        [z, a2, z, a1, z, a3],
        [z, z, a3, z, a1, a2],
    ]
    return jnp.stack([jnp.stack(r, -1) for r in rows], -2)


def _tensor(theta: Float[Array, "6"]) -> Float[Array, "3 3"]:
    t = theta
    return jnp.array([[t[0], t[3], t[4]], [t[3], t[1], t[5]], [t[4], t[5], t[2]]])


def linear_inertia(
    ts: Float[Array, "E T"],
    omega: Float[Array, "E T 3"],
    torque: Float[Array, "E T 3"] | None,
) -> Float[Array, "3 3"]:
    """The least-squares inertia from Euler's equations at the interior samples (see the
    module docstring), physical and, torque-free, of trace 1."""
    dt = (ts[:, 2:] - ts[:, :-2])[..., None]
    w = omega[:, 1:-1]
    dw = (omega[:, 2:] - omega[:, :-2]) / dt
    A = _lin(dw) + so3.hat(w) @ _lin(w)  # (E, T-2, 3, 6)
    A = A.reshape(-1, 6)
    if torque is None:
        theta = jnp.linalg.svd(A, full_matrices=False)[2][-1]
        I = _tensor(theta)
        I = I * jnp.sign(jnp.trace(I))
    else:
        theta = jnp.linalg.lstsq(A, torque[:, 1:-1].reshape(-1))[0]
        I = _tensor(theta)
    # physical: Σ = tr(I)/2 E − I ⪰ 0, eigenvalues clipped at 1% of the largest
    S = jnp.trace(I) / 2 * jnp.eye(3, dtype=I.dtype) - I
    s, V = jnp.linalg.eigh(S)
    s = jnp.maximum(s, 0.01 * jnp.maximum(s[-1], 1e-300))
    S = (V * s) @ V.T
    I = jnp.trace(S) * jnp.eye(3, dtype=I.dtype) - S
    return I if torque is not None else I / jnp.trace(I)
