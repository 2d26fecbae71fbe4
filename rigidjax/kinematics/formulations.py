"""Attitude kinematics: the Darboux problem's vector fields, one formulation per class.

Each formulation turns an angular velocity into the time derivative of its own attitude state
(Zhilin 3.12–3.14; Borisov–Mamaev 001; exercises 002). `frame="space"` takes the space (left)
angular velocity ω with `Ṗ = ω × P`; `frame="body"` the body (right) one Ω with `Ṗ = P (Ω × E)`.
Every class can be used on its own inside any `diffrax.ODETerm`:

    kin = RotationVector(frame="space")
    term = diffrax.ODETerm(lambda t, y, args: kin.vector_field(y, omega(t)))
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._checks import matrix, vector
from .._custom_types import EulerSeq, Frame, Mat33, Mat33Like, Quat, Vec3, Vec3Like
from ..rotations import euler, quat, so3


class AbstractKinematics(eqx.Module):
    """An attitude state with its kinematic equation and its map to the rotation tensor."""

    frame: Frame = eqx.field(static=True, default="space", kw_only=True)

    def __check_init__(self):
        if self.frame not in ("space", "body"):
            raise ValueError(f"frame must be 'space' or 'body', got {self.frame!r}")

    @abc.abstractmethod
    def from_matrix(self, P: Mat33Like) -> Array:
        """Initial state of this formulation for the rotation tensor P."""

    @abc.abstractmethod
    def to_matrix(self, y: Array) -> Mat33:
        """Rotation tensor of a state (accepts leading batch dimensions)."""

    @abc.abstractmethod
    def vector_field(self, y: Array, w: Vec3) -> Array:
        """ẏ for angular velocity `w` (space ω or body Ω per `frame`)."""

    def to_quat(self, y: Array) -> Quat:
        """Unit quaternion (λ0 ≥ 0) of a state."""
        return quat.from_matrix(self.to_matrix(y))

    def step_end(self, y: Array) -> tuple[Array, Bool[Array, ""]]:
        """Map applied to the state after each solver step: `(y', changed_chart)`."""
        return y, jnp.array(False)


class PoissonMatrix(AbstractKinematics):
    """The Poisson equation on the nine entries of P: `Ṗ = ω × P` or `Ṗ = P (Ω × E)`
    (Zhilin 3.12.2). A general-purpose integrator does not keep P orthogonal: the returned
    matrices are the raw solution; `so3.orthogonality_error` measures the drift."""

    def from_matrix(self, P: Mat33Like) -> Mat33:
        return matrix(P, "P0")

    def to_matrix(self, y: Mat33) -> Mat33:
        return y

    def vector_field(self, y: Mat33, w: Vec3) -> Mat33:
        W = so3.hat(w)
        return W @ y if self.frame == "space" else y @ W


class RotationVector(AbstractKinematics):
    """`θ̇ = Z(θ) ω` (left) or `θ̇ = Zᵀ(θ) Ω` (right), Zhilin (3.14.21)–(3.14.22).

    After every step the state is replaced by its shadow `θ − 2π θ/|θ|` once |θ| > π, so the
    integration never comes near the singularity of Z at |θ| = 2π, however many turns are made.
    """

    def from_matrix(self, P: Mat33Like) -> Vec3:
        return so3.log(P)

    def to_matrix(self, y: Vec3) -> Mat33:
        return so3.exp(y)

    def to_quat(self, y: Vec3) -> Quat:
        return quat.from_rotvec(y)

    def vector_field(self, y: Vec3, w: Vec3) -> Vec3:
        # Zᵀ(θ) = Z(−θ)
        return so3.Z(y if self.frame == "space" else -y) @ w

    def step_end(self, y: Vec3) -> tuple[Vec3, Bool[Array, ""]]:
        return so3.shadow(y), jnp.sum(y * y) > jnp.pi**2


class Quaternion(AbstractKinematics):
    """`q̇ = ½ (0, ω) ∘ q` (space) or `q̇ = ½ q ∘ (0, Ω)` (body) (Borisov–Mamaev 001; 002 #101).

    Norm strategy: the exact flow keeps |q| = 1; the numerical one drifts by the local error, so
    the state is renormalised after every step (a projection, not part of the vector field), and
    `to_matrix` uses the homogeneous formula that is a rotation for any q ≠ 0.
    """

    def from_matrix(self, P: Mat33Like) -> Quat:
        return quat.from_matrix(P)

    def to_matrix(self, y: Quat) -> Mat33:
        return quat.to_matrix(y)

    def to_quat(self, y: Quat) -> Quat:
        return quat.normalize(y)

    def vector_field(self, y: Quat, w: Vec3) -> Quat:
        pure = jnp.concatenate([jnp.zeros_like(w[..., :1]), w], axis=-1)
        return 0.5 * (quat.mul(pure, y) if self.frame == "space" else quat.mul(y, pure))

    def step_end(self, y: Quat) -> tuple[Quat, Bool[Array, ""]]:
        return y * jax.lax.rsqrt(jnp.sum(y * y, axis=-1, keepdims=True)), jnp.array(False)


class EulerAngles(AbstractKinematics):
    """Kinematic Euler formulas for any sequence: `(α̇, β̇, γ̇) = J⁻¹(angles) ω` (Borisov–Mamaev
    001; THEORY §4). Singular at gimbal lock: the vector field raises a clear error when
    |det J| < `gimbal_tol` instead of blowing up — use `RotationVector`, `Quaternion` or the
    geometric solver for such motions."""

    seq: EulerSeq = eqx.field(static=True, default="ZXZ")
    gimbal_tol: float = eqx.field(static=True, default=1e-6)

    def from_matrix(self, P: Mat33Like) -> Vec3:
        return euler.from_matrix(P, self.seq)

    def to_matrix(self, y: Vec3) -> Mat33:
        return euler.to_matrix(y, self.seq)

    def to_quat(self, y: Vec3) -> Quat:
        return quat.canonical(euler.to_quat(y, self.seq))

    def vector_field(self, y: Vec3, w: Vec3) -> Vec3:
        return euler.omega_to_rates(y, w, self.seq, self.frame, check=True, tol=self.gimbal_tol)


class CayleyKlein(AbstractKinematics):
    """SU(2) form: the Cayley–Klein matrix `U = [[α, β], [γ, δ]]` of Borisov–Mamaev obeys
    `U̇ = ½ (i ω·σ̄) U` (space) or `U̇ = ½ U (i Ω·σ̄) ` (body), σ̄ the complex-conjugate Pauli
    matrices (U is the conjugate of the physics `λ0 σ0 − i λ·σ`, THEORY §3). The state is stored
    as real `(2, 2, 2)` = (Re U, Im U) so any real Diffrax solver applies; it is renormalised to
    det U = 1 after each step like the quaternion."""

    def from_matrix(self, P: Mat33Like) -> Float[Array, "2 *batch 2 2"]:
        U = quat.to_cayley_klein(quat.from_matrix(P))
        return jnp.stack([jnp.real(U), jnp.imag(U)])

    def to_matrix(self, y: Float[Array, "*#batch 2 2 2"]) -> Mat33:
        return quat.to_matrix(self._quat(y))

    def to_quat(self, y: Float[Array, "*#batch 2 2 2"]) -> Quat:
        return quat.normalize(self._quat(y))

    @staticmethod
    def _quat(y: Float[Array, "*#batch 2 2 2"]) -> Quat:
        # α = λ0 + iλ3, β = −λ2 + iλ1 (Borisov–Mamaev), read off the first row
        re, im = y[..., 0, :, :], y[..., 1, :, :]
        return jnp.stack([re[..., 0, 0], im[..., 0, 1], -re[..., 0, 1], im[..., 0, 0]], axis=-1)

    def vector_field(self, y: Float[Array, "2 2 2"], w: Float[Array, "3"]) -> Float[Array, "2 2 2"]:
        U = y[0] + 1j * y[1]
        w1, w2, w3 = w[0], w[1], w[2]
        S = jnp.stack([jnp.stack([w3, w1 + 1j * w2]), jnp.stack([w1 - 1j * w2, -w3])])
        dU = 0.5j * (S @ U if self.frame == "space" else U @ S)
        return jnp.stack([jnp.real(dU), jnp.imag(dU)]).astype(y.dtype)

    def step_end(self, y: Float[Array, "2 2 2"]) -> tuple[Float[Array, "2 2 2"], Bool[Array, ""]]:
        q = self._quat(y)
        return y / jnp.linalg.norm(q), jnp.array(False)


METHODS: dict[str, type[AbstractKinematics]] = {
    "matrix": PoissonMatrix,
    "rotvec": RotationVector,
    "quat": Quaternion,
    "euler": EulerAngles,
    "cayley_klein": CayleyKlein,
}


def check_omega(w: Vec3Like) -> Vec3:
    """Angular velocity with a clear runtime error if it is not finite."""
    w = vector(w, 3, "omega(t)")
    return eqx.error_if(w, ~jnp.all(jnp.isfinite(w)), "omega(t) returned a non-finite value")


def lookup(
    method: str | AbstractKinematics,
    frame: Frame,
    *,
    seq: EulerSeq = "ZXZ",
    name: str = "kinematics",
    strict_frame: bool = False,
) -> AbstractKinematics:
    """The kinematics formulation named `method` (a key of `METHODS`) in `frame` (Euler angles
    in sequence `seq`), or `method` itself when it is an `AbstractKinematics` instance (whose
    frame must then be `frame` if `strict_frame`)."""
    if isinstance(method, AbstractKinematics):
        if strict_frame and method.frame != frame:
            raise ValueError(
                f"{name} must use frame={frame!r} here, got an instance with frame={method.frame!r}"
            )
        return method
    if isinstance(method, str) and method in METHODS:
        return METHODS[method](frame=frame, **({"seq": seq} if method == "euler" else {}))
    raise ValueError(
        f"{name} must be one of {sorted([*METHODS, 'geometric'])} or an AbstractKinematics "
        f"instance, got {method!r}"
    )
