"""Rotation tensor P ∈ SO(3) and rotation vector θ = θ m (Zhilin ch. 3.12–3.14; article 003).

Conventions (THEORY): `P` maps a body vector to space, `a' = P a`; `hat(a) = a × E`;
left (space) angular velocity `Ṗ = ω × P`, right (body) `Ṗ = P (Ω × E)`, `Ω = Pᵀ ω`.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import DTypeLike, PRNGKeyArray

from .._checks import broadcast_batch, check_frame, is_concrete, matrix, validate, vector
from .._custom_types import Frame, Mat33, Mat33Like, Scalar, Vec3, Vec3Like
from . import _quat_core, _series, _validation, quat
from ._compiled import compiled

__all__ = [
    "Z",
    "Z_inv",
    "angular_velocity",
    "check_rotation",
    "compose",
    "distance",
    "exp",
    "hat",
    "log",
    "orthogonality_error",
    "project",
    "random",
    "rotate",
    "rotate_tensor",
    "shadow",
    "vee",
]


def hat(v: Vec3Like) -> Mat33:
    """Skew matrix `v × E`: `hat(v) @ a = v × a`."""
    v = vector(v, 3, "v")
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2
    )


def vee(A: Mat33Like) -> Vec3:
    """Inverse of `hat` on skew matrices: `−½ A_×` (Zhilin's vector invariant, `(a × E)_× = −2a`).

    Uses only the skew part of `A`, so `vee(A) = vee((A − Aᵀ)/2)`.
    """
    A = matrix(A, "A")
    return 0.5 * jnp.stack(
        [A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]],
        -1,
    )


def _sq(theta: Vec3) -> Scalar:
    return jnp.sum(theta * theta, axis=-1)


def _hat_sq(theta: Vec3, x2: Scalar) -> Mat33:
    """`(θ × E)² = θθ − θ² E`, elementwise (cheaper than a matrix product)."""
    return theta[..., :, None] * theta[..., None, :] - x2[..., None, None] * jnp.eye(
        3, dtype=theta.dtype
    )


def exp(theta: Vec3Like) -> Mat33:
    """`P(θ) = exp(θ × E) = E + (sin θ/θ) R + ((1 − cos θ)/θ²) R²`, `R = θ × E` (Zhilin; Euler's
    theorem). Finite values and gradients at θ = 0. A non-finite concrete `theta` is an error
    naming it; traced, no check (the integrators' hot path): NaN in, NaN out. One compiled
    program per shape and dtype (see `rotations._compiled`)."""
    return _exp(_eager_finite(vector(theta, 3, "theta"), "theta"))


def _eager_finite(x: Vec3, name: str) -> Vec3:
    """`x`, checked to be finite where it is concrete (an error naming `name`); traced, as it
    is: the integrator algebra (`exp`, `Z`, `Z_inv`, `shadow`, `rotate`) carries no run-time
    check on the hot path (NaN in, NaN out)."""
    return _validation.check_finite(x, name, 1) if is_concrete(x) else x


def _quadratic(theta: Vec3, first, second) -> Mat33:
    """`E + first(θ²) R + second(θ²) R²`, `R = θ × E` (the form of `exp` and `Z_inv`), the
    coefficients as series in θ² where θ is small."""
    x2 = _sq(theta)
    a, b = first(x2)[..., None, None], second(x2)[..., None, None]
    return jnp.eye(3, dtype=theta.dtype) + a * hat(theta) + b * _hat_sq(theta, x2)


@compiled(1)
def _exp(theta: Vec3) -> Mat33:
    return _quadratic(theta, _series.sin_over, _series.one_minus_cos_over)


def log(P: Mat33Like) -> Vec3:
    """Rotation vector of `P` with |θ| ≤ π, through the largest-component quaternion
    (exact at θ = π, no loss of accuracy near it, finite gradients at the identity).

    As `quat.from_matrix` (and SciPy): a non-finite `P` or det P ≤ 0 is an error naming `P`;
    a matrix with det > 0 that is not orthogonal is replaced by its nearest rotation. One
    compiled program per shape and dtype, as `quat.from_matrix`."""
    P = matrix(P, "P")
    return _log(P, mode=_quat_core._matrix_mode(P, "P"))


@compiled(2)
def _log(P: Mat33, mode: str) -> Vec3:
    return _quat_core._to_rotvec(_quat_core._quat_of_matrix(P, "P", mode))


def rotate(theta: Vec3Like, a: Vec3Like) -> Vec3:
    """`a' = a + (sin θ/θ) θ × a + ((1 − cos θ)/θ²) θ × (θ × a)` (Zhilin). A non-finite
    concrete `theta` or `a` is an error naming it, as in `exp`."""
    theta = _eager_finite(vector(theta, 3, "theta"), "theta")
    a = _eager_finite(vector(a, 3, "a"), "a")
    broadcast_batch(theta=theta.shape[:-1], a=a.shape[:-1])
    x2 = _sq(theta)[..., None]
    theta = jnp.broadcast_to(theta, jnp.broadcast_shapes(theta.shape, a.shape))
    t = jnp.cross(theta, a)
    return a + _series.sin_over(x2) * t + _series.one_minus_cos_over(x2) * jnp.cross(theta, t)


def rotate_tensor(P: Mat33Like, T: Mat33Like) -> Mat33:
    """Second-order tensor carried by the rotation: `T' = P T Pᵀ` (article 003)."""
    P = matrix(P, "P")
    T = matrix(T, "T")
    return P @ T @ jnp.swapaxes(P, -1, -2)


def Z_inv(theta: Vec3Like) -> Mat33:
    """`Z⁻¹(θ) = E + ((1 − cos θ)/θ²) R + ((θ − sin θ)/θ³) R²`: `ω = Z⁻¹ θ̇` (Zhilin 3.14.13).

    The left Jacobian of SO(3). A non-finite concrete `theta` is an error, as in `exp`."""
    theta = _eager_finite(vector(theta, 3, "theta"), "theta")
    return _quadratic(theta, _series.one_minus_cos_over, _series.theta_minus_sin_over)


def Z(theta: Vec3Like) -> Mat33:
    """Integrator tensor `Z(θ) = E − ½ R + ((1 − g)/θ²) R²`, `g = θ sin θ/(2(1 − cos θ))`:
    `θ̇ = Z ω` (Zhilin 3.14.15). `det Z = θ²/(2(1 − cos θ))`, singular at |θ| = 2π. A
    non-finite concrete `theta` is an error, as in `exp`."""
    theta = _eager_finite(vector(theta, 3, "theta"), "theta")
    R = hat(theta)
    x2 = _sq(theta)
    d = _series.zhilin_d(x2)[..., None, None]
    return jnp.eye(3, dtype=theta.dtype) - 0.5 * R + d * _hat_sq(theta, x2)


def compose(phi: Vec3Like, psi: Vec3Like) -> Vec3:
    """Rotation vector (|θ| ≤ π) of `exp(phi) @ exp(psi)`, via the quaternion product. `phi`,
    `psi` must be finite."""
    phi = _validation.check_finite(vector(phi, 3, "phi"), "phi", 1)
    psi = _validation.check_finite(vector(psi, 3, "psi"), "psi", 1)
    broadcast_batch(phi=phi.shape[:-1], psi=psi.shape[:-1])
    return _quat_core._to_rotvec(
        quat.mul(_quat_core._from_rotvec(phi), _quat_core._from_rotvec(psi))
    )


def shadow(theta: Vec3Like) -> Vec3:
    """The same rotation with |θ| ≤ π: `θ − 2πk θ/|θ|`, k = round(|θ|/2π) (Zhilin 3.14).

    `P(θ) = P(θ − 2π θ/|θ|)`, so the shadow vector keeps an integration of θ̇ = Zω away from the
    singularity of Z at |θ| = 2π. A non-finite concrete `theta` is an error, as in `exp`.
    """
    theta = _eager_finite(vector(theta, 3, "theta"), "theta")
    x2 = _sq(theta)
    two_pi = 2 * jnp.pi
    # k = 0 (|θ| < π) leaves θ untouched: no square root of a possibly zero x2 there.
    far = x2 > jnp.pi**2
    n = jnp.sqrt(jnp.where(far, x2, jnp.ones_like(x2)))
    k = jnp.round(n / two_pi)
    scale = jnp.where(far, 1 - two_pi * k / n, jnp.ones_like(n))
    return scale[..., None] * theta


def angular_velocity(P: Mat33Like, P_dot: Mat33Like, frame: Frame = "space") -> Vec3:
    """`ω = −½ (Ṗ Pᵀ)_× = vee(Ṗ Pᵀ)` (space, Zhilin 3.12) or `Ω = vee(Pᵀ Ṗ) = Pᵀ ω` (body).
    `P`, `P_dot` must be finite."""
    P = _validation.check_finite(matrix(P, "P"), "P", 2)
    P_dot = _validation.check_finite(matrix(P_dot, "P_dot"), "P_dot", 2)
    broadcast_batch(P=P.shape[:-2], P_dot=P_dot.shape[:-2])
    check_frame(frame)
    Pt = jnp.swapaxes(P, -1, -2)
    return vee(P_dot @ Pt) if frame == "space" else vee(Pt @ P_dot)


def project(A: Mat33Like) -> Mat33:
    """Nearest rotation to a (nearly orthogonal) matrix in the Frobenius norm: `U diag(1,1,det) Vᵀ`
    from the SVD `A = U S Vᵀ`, singular values `σ1 ≥ σ2 ≥ σ3` (orthogonal Procrustes). `A` must
    be finite, of rank ≥ 2 (`σ2 > 64 eps σ1`): otherwise (the zero matrix, one column or row
    direction only) many rotations are equally near, and that is an error naming `A`."""
    A = _validation.check_finite(matrix(A, "A"), "A", 2)
    U, S, Vt = jnp.linalg.svd(A)

    def degenerate(xp: Any, s: Any) -> Any:
        return ~(s[..., 1] > 64 * xp.finfo(s.dtype).eps * s[..., 0])

    def detail(s: np.ndarray) -> str:
        k = _validation.first(degenerate(np, s))
        return f": singular values of {_validation.at('A', k)} = {_validation.fmt(s[k])}"

    U = validate(
        S,
        degenerate,
        "A has rank < 2: many rotations are equally near to it, so there is no nearest one",
        detail,
        hint="; give a matrix with at least two independent columns (e.g. a noisy rotation)",
        on=U,
    )
    d = jnp.linalg.det(U @ Vt)
    U = U.at[..., :, 2].multiply(d[..., None])
    return U @ Vt


def distance(P1: Mat33Like, P2: Mat33Like) -> Scalar:
    """Geodesic distance `|log(P1ᵀ P2)|` ∈ [0, π] (the angle of the relative rotation); `P1`, `P2`
    are checked and orthogonalised as by `quat.from_matrix` (one compiled program)."""
    P1, P2 = matrix(P1, "P1"), matrix(P2, "P2")
    broadcast_batch(P1=P1.shape[:-2], P2=P2.shape[:-2])
    return _distance(
        P1, P2, mode1=_quat_core._matrix_mode(P1, "P1"), mode2=_quat_core._matrix_mode(P2, "P2")
    )


@compiled(2, 2)
def _distance(P1: Mat33, P2: Mat33, mode1: str, mode2: str) -> Scalar:
    if mode1 == mode2 == "rotation":  # both orthogonal to rounding: the relative rotation's
        # angle, one conversion (the same derivative: that of the projections on SO(3))
        M = jnp.swapaxes(P1, -1, -2) @ P2
        return _quat_core._angle(_quat_core._quat_of_matrix(M, "P1ᵀ P2", "rotation"))
    q1 = _quat_core._quat_of_matrix(P1, "P1", mode1)
    q2 = _quat_core._quat_of_matrix(P2, "P2", mode2)
    return _quat_core._angle(quat.mul(quat.conj(q1), q2))


def orthogonality_error(P: Mat33Like) -> Scalar:
    """`‖PᵀP − E‖_F`: how far a matrix is from orthogonal."""
    P = matrix(P, "P")
    return jnp.linalg.norm(jnp.swapaxes(P, -1, -2) @ P - jnp.eye(3, dtype=P.dtype), axis=(-2, -1))


def check_rotation(P: Mat33Like, atol: float = 1e-6, name: str = "P") -> Mat33:
    """Return `P` unchanged if it is a rotation to within `atol` (`‖PᵀP − E‖_F` and `det P − 1`);
    otherwise a ValueError stating the deviation (concrete input) or a runtime error (under
    jit/vmap), with the fix."""
    P = matrix(P, name)

    def bad(xp, A):
        err = xp.linalg.norm(xp.swapaxes(A, -1, -2) @ A - xp.eye(3), axis=(-2, -1))
        return ~((err <= atol) & (xp.abs(xp.linalg.det(A) - 1) <= atol))

    def detail(A):
        err = np.linalg.norm(np.swapaxes(A, -1, -2) @ A - np.eye(3), axis=(-2, -1))
        return f": ‖PᵀP − E‖ = {np.max(err):.3g}, det = {np.min(np.linalg.det(A)):.6g}"

    return validate(
        P,
        bad,
        f"{name} is not a rotation matrix",
        detail,
        hint=f" (tolerance {atol:g}); pass rigidjax.so3.project({name}) for the nearest rotation",
    )


def random(
    key: PRNGKeyArray, shape: int | tuple[int, ...] = (), dtype: DTypeLike | None = None
) -> Mat33:
    """Rotations uniformly distributed on SO(3) (Haar measure), from normalised Gaussian
    quaternions; `shape` as `quat.random`'s."""
    return quat.to_matrix(quat.random(key, shape, dtype))
