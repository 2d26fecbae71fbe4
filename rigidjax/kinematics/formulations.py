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
from typing import TypeAlias

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._checks import check_frame, matrix, validate, vector
from .._custom_types import EulerSeq, Frame, Mat33, Mat33Like, Quat, Vec3, Vec3Like
from ..rotations import euler, quat, so3
from . import euler_atlas

__all__ = [
    "METHODS",
    "AbstractKinematics",
    "CayleyKlein",
    "EulerAngles",
    "EulerState",
    "PoissonMatrix",
    "Quaternion",
    "RotationVector",
    "check_omega",
    "lookup",
]


def _unit_state(q: Quat) -> Quat:
    """`q / |q|` of an integrator's state, not user input: no argument checks. A batched loop
    also evaluates lanes it discards (a finished body's, an event's placeholder), where the
    state may be zero: those stay zero, with finite derivatives (the double `where`)."""
    n2 = quat.norm2(q)[..., None]
    some = n2 > 0
    return jnp.where(some, q / jnp.sqrt(jnp.where(some, n2, 1)), q)


class AbstractKinematics(eqx.Module):
    """An attitude state with its kinematic equation and its map to the rotation tensor."""

    frame: Frame = eqx.field(static=True, default="space", kw_only=True)

    def __check_init__(self):
        check_frame(self.frame)

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
        """Unit quaternion of a state (either sign: the drivers make a trajectory's sign
        continuous)."""
        return quat.from_matrix(self.to_matrix(y), assume_valid=True)  # a state, not user input

    def step_end(self, y: Array) -> tuple[Array, Bool[Array, "*#batch"]]:
        """Map applied to the state after each solver step: `(y', changed_chart)` (per state)."""
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
        return quat._from_rotvec(y)  # a state, not user input: no argument checks

    def vector_field(self, y: Vec3, w: Vec3) -> Vec3:
        # Zᵀ(θ) = Z(−θ)
        return jnp.einsum("...ij,...j->...i", so3.Z(y if self.frame == "space" else -y), w)

    def step_end(self, y: Vec3) -> tuple[Vec3, Bool[Array, "*#batch"]]:
        return so3.shadow(y), jnp.sum(y * y, axis=-1) > jnp.pi**2


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
        return _unit_state(y)

    def vector_field(self, y: Quat, w: Vec3) -> Quat:
        pure = jnp.concatenate([jnp.zeros_like(w[..., :1]), w], axis=-1)
        return 0.5 * (quat.mul(pure, y) if self.frame == "space" else quat.mul(y, pure))

    def step_end(self, y: Quat) -> tuple[Quat, Bool[Array, "*#batch"]]:
        return y * jax.lax.rsqrt(jnp.sum(y * y, axis=-1, keepdims=True)), jnp.array(False)


EulerState: TypeAlias = Float[Array, "*#batch 4"]
"""State of `EulerAngles`: three angles of the current chart and the chart (0.0 = `seq`,
1.0 = its partner)."""


class EulerAngles(AbstractKinematics):
    """Kinematic Euler formulas `(α̇, β̇, γ̇) = J⁻¹(angles) ω` (Borisov–Mamaev 001; THEORY §4) for
    any sequence `seq` (`rigidjax.euler`'s strings), integrated in an atlas of two charts so they
    never lock: `seq` and `partner = euler_atlas.partner(seq)` (e.g. `"ZXZ"` ↔ `"ZXY"`,
    `"XYZ"` ↔ `"XYX"`, `"zxz"` ↔ `"yxz"`).

    State `(α, β, γ, chart)` (`EulerState`): the angles of the current chart and the chart
    (0.0 = `seq`, 1.0 = partner), whose rate is zero. The charts' margins `m = |det J|`
    (`|sin β|` proper, `|cos β|` Tait–Bryan) satisfy `m² + m'² ≥ 1` at every attitude
    (proof in `euler_atlas`), so `max(m, m') ≥ 1/√2`. After every solver step (`step_end`) the
    state changes chart when its margin is below `switch` (default 0.5: β within 30° of lock),
    the angles converted exactly through the rotation (`euler.from_quat` of the quaternion) and
    the first one turned by 2π if needed so that `to_quat` keeps its sign; the new chart's margin
    is then ≥ √(1 − switch²) (0.87), so it does not chatter back. `from_matrix` starts in `seq`
    unless its margin is below `switch` (e.g. `"ZXZ"` at the identity starts in `"ZXY"`).
    First and third angles are kept within ±3π by 4π turns (the period of the quaternion; the
    vector field is 2π-periodic, so these are not jumps) so they stay scaled like the
    tolerances.

    `angles(y)` gives the angles in `seq` wherever they are defined. Inside a step the stages
    use the chart of the step's start; a trial stage of a step that overshoots into lock (or the
    first-same-as-last stage at a step end on the lock, just before the switch) sees `|det J|`
    floored at `gimbal_tol`: finite rates, which the error control rejects or which the switch
    and the FSAL reset discard. `switch=0` turns the atlas off: one chart, `seq`, the classical
    formulas, with a clear error where `|det J| < gimbal_tol` (gimbal lock).
    """

    seq: EulerSeq = eqx.field(static=True, default="ZXZ")
    switch: float = eqx.field(static=True, default=0.5)
    gimbal_tol: float = eqx.field(static=True, default=1e-6)

    def __check_init__(self):
        euler_atlas.partner(self.seq)  # validates seq
        if not 0 <= self.switch < 2**-0.5:
            raise ValueError(
                "switch (the margin |det J| below which the Euler chart is changed) must be in "
                f"[0, 1/√2) (0 turns the atlas off), got {self.switch!r}"
            )

    @property
    def partner(self) -> str:
        """The second chart's sequence (`euler_atlas.partner(seq)`)."""
        return euler_atlas.partner(self.seq)

    @staticmethod
    def _split(y: EulerState) -> tuple[Vec3, Bool[Array, "*#batch"]]:
        """Angles and `in_partner` (chart slot 1.0) of a state."""
        return y[..., :3], y[..., 3] > 0.5

    def from_matrix(self, P: Mat33Like) -> EulerState:
        q = quat.from_matrix(matrix(P, "P0"))
        a, b = euler.from_quat(q, self.seq), euler.from_quat(q, self.partner)
        use_b = euler_atlas.margin(a, self.seq) < self.switch
        return jnp.concatenate(
            [jnp.where(use_b[..., None], b, a), use_b[..., None].astype(a.dtype)], axis=-1
        )

    def to_quat(self, y: EulerState) -> Quat:
        """Quaternion of the current chart's angles (`euler.to_quat`; unit, either sign)."""
        a, in_b = self._split(y)
        qa, qb = euler._to_quat(a, self.seq), euler._to_quat(a, self.partner)
        return jnp.where(in_b[..., None], qb, qa)

    def to_matrix(self, y: EulerState) -> Mat33:
        return quat.to_matrix(self.to_quat(y))

    def angles(self, y: EulerState) -> Vec3:
        """Euler angles in `seq` of states (any batch shape), in `rigidjax.euler`'s ranges: the
        state's own angles (first and third wrapped to [−π, π]) in the `seq` chart, else
        `euler.from_quat(to_quat(y), seq)` — near the lock of `seq` the first and third angles are
        ill-conditioned (only their sum or difference is defined) and at lock (middle angle
        within `euler.gimbal_tol` of it) the third is 0, `rigidjax.euler`'s (SciPy's) choice."""
        a, in_b = self._split(y)
        own = a - 2 * jnp.pi * jnp.round(a / (2 * jnp.pi)) * jnp.array([1.0, 0.0, 1.0], a.dtype)
        beta = a[..., 1]
        if euler_atlas.is_proper(self.seq):
            in_range = (beta >= 0) & (beta <= jnp.pi)
        else:
            in_range = jnp.abs(beta) <= jnp.pi / 2
        converted = euler.from_quat(self.to_quat(y), self.seq)
        return jnp.where((~in_b & in_range)[..., None], own, converted)

    def vector_field(self, y: EulerState, w: Vec3) -> EulerState:
        # J of the current chart (both are finite everywhere), then the closed-form inverse
        # J⁻¹ = (c2×c3, c3×c1, c1×c2)ᵀ / det J of `euler.omega_to_rates`
        a, in_b = self._split(y)
        J = euler.jacobian(a, self.seq, self.frame)
        if self.switch > 0:
            J = jnp.where(in_b[..., None, None], euler.jacobian(a, self.partner, self.frame), J)
        c1, c2, c3 = J[..., 0], J[..., 1], J[..., 2]
        adj = jnp.stack([jnp.cross(c2, c3), jnp.cross(c3, c1), jnp.cross(c1, c2)], axis=-2)
        det = jnp.sum(c1 * adj[..., 0, :], -1)
        tol = self.gimbal_tol
        if self.switch == 0:  # one chart: the classical formulas, singular at lock
            det = validate(
                det,
                lambda xp, d: ~(xp.abs(d) >= tol),
                f"gimbal lock: middle angle of seq={self.seq!r} within |det J| < {tol} of its "
                "singular value (0/π proper Euler, ±π/2 Tait–Bryan) with the atlas off "
                "(switch=0): use switch > 0 (the default) or quaternion/rotation-vector kinematics",
            )
        else:
            det = jnp.where(jnp.abs(det) >= tol, det, jnp.where(det < 0, -tol, tol))
        rates = jnp.einsum("...ij,...j->...i", adj, w) / det[..., None]
        return jnp.concatenate([rates, jnp.zeros_like(y[..., 3:])], axis=-1)

    def step_end(self, y: EulerState) -> tuple[EulerState, Bool[Array, "*#batch"]]:
        """Change chart when the current margin is below `switch` (converting the angles through
        the quaternion, same sign); otherwise wrap the first and third angles by 4π beyond ±3π."""
        a, in_b = self._split(y)
        m = jnp.where(in_b, euler_atlas.margin(a, self.partner), euler_atlas.margin(a, self.seq))
        switch = m < self.switch
        q = self.to_quat(y)
        to_a, to_b = euler.from_quat(q, self.seq), euler.from_quat(q, self.partner)
        new = jnp.where(in_b[..., None], to_a, to_b)
        q_new = jnp.where(
            in_b[..., None], euler._to_quat(new, self.seq), euler._to_quat(new, self.partner)
        )
        first = new[..., 0]
        turn = jnp.where(
            jnp.sum(q * q_new, -1) < 0, jnp.where(first < 0, 2 * jnp.pi, -2 * jnp.pi), 0
        )
        new = jnp.concatenate([new[..., :1] + turn[..., None], new[..., 1:]], axis=-1)
        mask = jnp.array([1.0, 0.0, 1.0], a.dtype)
        wrapped = (
            a
            - jnp.where(jnp.abs(a) > 3 * jnp.pi, 4 * jnp.pi * jnp.round(a / (4 * jnp.pi)), 0) * mask
        )
        y_switched = jnp.concatenate([new, 1 - y[..., 3:]], axis=-1)
        y_kept = jnp.concatenate([wrapped, y[..., 3:]], axis=-1)
        return jnp.where(switch[..., None], y_switched, y_kept), jnp.any(switch)


class CayleyKlein(AbstractKinematics):
    """SU(2) form: the Cayley–Klein matrix `U = [[α, β], [γ, δ]]` of Borisov–Mamaev obeys
    `U̇ = ½ (i ω·σ̄) U` (space) or `U̇ = ½ U (i Ω·σ̄) ` (body), σ̄ the complex-conjugate Pauli
    matrices (U is the conjugate of the physics `λ0 σ0 − i λ·σ`, THEORY §3). The state is stored
    as real `(2, 2, 2)` = (Re U, Im U) so any real Diffrax solver applies; it is renormalised to
    det U = 1 after each step like the quaternion."""

    def from_matrix(self, P: Mat33Like) -> Float[Array, "*batch 2 2 2"]:
        U = quat.to_cayley_klein(quat.from_matrix(P))
        return jnp.stack([jnp.real(U), jnp.imag(U)], axis=-3)

    def to_matrix(self, y: Float[Array, "*#batch 2 2 2"]) -> Mat33:
        return quat.to_matrix(self._quat(y))

    def to_quat(self, y: Float[Array, "*#batch 2 2 2"]) -> Quat:
        return _unit_state(self._quat(y))

    @staticmethod
    def _quat(y: Float[Array, "*#batch 2 2 2"]) -> Quat:
        # α = λ0 + iλ3, β = −λ2 + iλ1 (Borisov–Mamaev), read off the first row
        re, im = y[..., 0, :, :], y[..., 1, :, :]
        return jnp.stack([re[..., 0, 0], im[..., 0, 1], -re[..., 0, 1], im[..., 0, 0]], axis=-1)

    def vector_field(
        self, y: Float[Array, "*#batch 2 2 2"], w: Float[Array, "*#batch 3"]
    ) -> Float[Array, "*batch 2 2 2"]:
        U = y[..., 0, :, :] + 1j * y[..., 1, :, :]
        w1, w2, w3 = w[..., 0], w[..., 1], w[..., 2]
        rows = [jnp.stack([w3, w1 + 1j * w2], -1), jnp.stack([w1 - 1j * w2, -w3], -1)]
        S = jnp.stack(rows, -2)
        dU = 0.5j * (S @ U if self.frame == "space" else U @ S)
        return jnp.stack([jnp.real(dU), jnp.imag(dU)], axis=-3).astype(y.dtype)

    def step_end(
        self, y: Float[Array, "*#batch 2 2 2"]
    ) -> tuple[Float[Array, "*batch 2 2 2"], Bool[Array, "*#batch"]]:
        norm = jnp.linalg.norm(self._quat(y), axis=-1)  # (each state its own)
        return y / norm[..., None, None, None], jnp.array(False)


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
    return validate(w, lambda xp, w: ~xp.isfinite(w), "omega(t) returned a non-finite value")


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
