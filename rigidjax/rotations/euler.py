"""Angle systems: Euler / Tait–Bryan angles, generalized (Davenport) angles, and their kinematics.

Conventions (THEORY §1, §4): `P` maps body vectors to space. Sequence strings are SciPy's
(`Rotation.from_euler`): letters from `xyz`, all uppercase = intrinsic (rotating axes),
all lowercase = extrinsic (fixed axes), no two consecutive letters equal; three letters, or 1 to
3 for the angle → rotation maps (`to_quat`, `to_matrix`). A bad sequence is SciPy's ValueError
(with the fix). `degrees=True` reads or returns degrees, as SciPy. Intrinsic `"ABC"` with
angles `(α, β, γ)` is `P = R_A(α) R_B(β) R_C(γ)`; extrinsic `"abc"` is `P = R_c(γ) R_b(β) R_a(α)`.
The classical angles of Borisov–Mamaev (001) — precession ψ, nutation θ, spin φ — are `"ZXZ"`
with angles `(ψ, θ, φ)`: `P = Rz(ψ) Rx(θ) Rz(φ)`.

Angle → rotation conversions return the product of the half-angle quaternions (no sign choice).
Rotation → angle conversions use the direct quaternion method of Bernardes & Viollet (2022,
"Quaternion to Euler angles conversion: a direct, general and computationally efficient method",
the algorithm of SciPy) and return SciPy's ranges and gimbal-lock choice: first and third angles
in [−π, π], middle angle in [0, π] (proper Euler) or [−π/2, π/2] (Tait–Bryan); at gimbal lock
(middle angle within `gimbal_tol(dtype)` of 0/π or ±π/2) the third angle is set to 0. Values and
gradients stay finite there.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, DTypeLike, Float

from .._checks import broadcast_batch, check_frame, is_concrete, matrix, validate, vector
from .._custom_types import (
    EulerSeq,
    Frame,
    Mat33,
    Mat33Like,
    Quat,
    QuatLike,
    RealLike,
    Scalar,
    Vec3,
    Vec3Like,
)
from . import _quat_core, _validation
from ._compiled import compiled
from ._euler_core import Axis, _angles, _angles_arg, _basis, _mul_components, gimbal_tol
from .davenport import (
    davenport_from_matrix,
    davenport_from_quat,
    davenport_to_matrix,
    davenport_to_quat,
)

__all__ = [
    "SEQUENCES",
    "Axis",
    "davenport_from_matrix",
    "davenport_from_quat",
    "davenport_to_matrix",
    "davenport_to_quat",
    "from_matrix",
    "from_quat",
    "gimbal_tol",
    "jacobian",
    "omega_to_rates",
    "rates_to_omega",
    "to_matrix",
    "to_quat",
]

SEQUENCES: tuple[str, ...] = tuple(
    s
    for case in (str.upper, str.lower)
    for s in map(
        case,
        ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ"],
    )
)
"""The 24 accepted sequences: 12 intrinsic (upper case) and 12 extrinsic (lower case)."""


# --------------------------------------------------------------------------- helpers


_SEQ_HINT = (
    "; seq must be 1 to 3 letters from 'xyz' (3 for angles out of a rotation), all upper case "
    "(intrinsic, rotating axes) or all lower case (extrinsic, fixed axes), with no two "
    "consecutive letters equal, e.g. 'ZXZ', 'ZYX', 'xyz', 'z'"
)


def _parse_axes(seq: object, three: bool) -> tuple[tuple[int, ...], bool]:
    """Axis indices and `intrinsic` flag of a SciPy sequence string of 1 to 3 axes (exactly 3
    if `three`); a ValueError with SciPy's message (and the fix) if bad."""
    if not isinstance(seq, str):
        raise ValueError(f"Expected `seq` to be a string of axes, got seq={seq!r}" + _SEQ_HINT)
    if three and len(seq) != 3:
        raise ValueError(f"Expected 3 axes, got {seq}." + _SEQ_HINT)
    if not 1 <= len(seq) <= 3:
        raise ValueError(
            "Expected axis specification to be a non-empty string of up to 3 characters, "
            f"got {seq}" + _SEQ_HINT
        )
    if not (set(seq) <= set("xyz") or set(seq) <= set("XYZ")):
        raise ValueError(
            f"Expected axes from `seq` to be from ['x', 'y', 'z'] or ['X', 'Y', 'Z'], got {seq}"
            + _SEQ_HINT
        )
    if any(a == b for a, b in zip(seq, seq[1:], strict=False)):
        raise ValueError(f"Expected consecutive axes to be different, got {seq}" + _SEQ_HINT)
    return tuple("xyz".index(c) for c in seq.lower()), seq.isupper()


def _parse_seq(seq: object) -> tuple[tuple[int, int, int], bool]:
    """Axis indices and `intrinsic` flag of a 3-axis sequence (see `_parse_axes`)."""
    (i, j, k), intrinsic = _parse_axes(seq, True)
    return (i, j, k), intrinsic


def _check_frame(frame: object) -> None:
    check_frame(frame)


def _seq_axes(
    seq: EulerSeq, dtype: DTypeLike
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], bool]:
    (i, j, k), intrinsic = _parse_seq(seq)
    return (_basis(i, dtype), _basis(j, dtype), _basis(k, dtype)), intrinsic


# --------------------------------------------------------------------------- Euler angles


def to_quat(angles: RealLike, seq: EulerSeq = "ZXZ", degrees: bool = False) -> Quat:
    """Unit quaternion of Euler angles: the product of the half-angle quaternions in the order of
    the matrix product (intrinsic `"ABC"`: `q_A(α) ∘ q_B(β) ∘ q_C(γ)`).

    For `"ZXZ"`, `(ψ, θ, φ)` this is Borisov–Mamaev's (001; THEORY §3)
    `λ0 = cos(θ/2) cos((ψ+φ)/2)`, `λ1 = sin(θ/2) cos((ψ−φ)/2)`, `λ2 = sin(θ/2) sin((ψ−φ)/2)`,
    `λ3 = cos(θ/2) sin((ψ+φ)/2)`. No sign normalisation (λ0 may be negative).

    As SciPy's `Rotation.from_euler`: `seq` has 1, 2 or 3 axes and `angles` shape `(..., len(seq))`
    (a scalar for one axis); `degrees=True` reads degrees. `angles` must be finite.
    """
    n = len(_parse_axes(seq, False)[0])
    return _to_quat(_angles_arg(angles, n, degrees, seq=str(seq)), seq)


def _to_quat(angles: Float[Array, "*batch k"], seq: EulerSeq) -> Quat:
    """`to_quat` without the checks of `angles` (1 to 3 axes)."""
    axes, intrinsic = _parse_axes(seq, False)
    n = len(axes)
    order = range(n) if intrinsic else range(n - 1, -1, -1)  # extrinsic "abc": q_c ∘ q_b ∘ q_a

    def factor(m: int) -> list[Array | None]:
        h = angles[..., m] / 2
        f: list[Array | None] = [jnp.cos(h), None, None, None]
        f[axes[m] + 1] = jnp.sin(h)
        return f

    first, *rest = order
    q = factor(first)
    for m in rest:  # basis-axis factors: only the non-zero products are formed
        q = _mul_components(q, factor(m))
    return jnp.stack([jnp.zeros_like(angles[..., 0]) if c is None else c for c in q], axis=-1)


def to_matrix(angles: RealLike, seq: EulerSeq = "ZXZ", degrees: bool = False) -> Mat33:
    """Rotation tensor of Euler angles, e.g. `"ZXZ"`: `P = Rz(ψ) Rx(θ) Rz(φ)` (THEORY §4;
    `Pᵀ` is the direction-cosine matrix of Borisov–Mamaev 001, remark 2). 1 to 3 axes and
    `degrees` as `to_quat`. One compiled program per shape, dtype and sequence."""
    n = len(_parse_axes(seq, False)[0])
    a = _angles_arg(angles, n, seq=str(seq))
    return _to_matrix(a, seq=seq, degrees=bool(degrees))


@compiled(1)
def _to_matrix(angles: Float[Array, "*batch k"], seq: EulerSeq, degrees: bool) -> Mat33:
    # the barrier keeps XLA from fusing the quaternion into each of the nine entries, which
    # recomputed its sines and cosines (1.4× faster for 10⁶ angles; benchmarks/bench_rotations.py)
    q = _to_quat(jnp.deg2rad(angles) if degrees else angles, seq)
    q = jax.lax.optimization_barrier(q)
    return _quat_core._to_matrix(q, _quat_core.norm2(q))


def from_quat(q: QuatLike, seq: EulerSeq = "ZXZ", degrees: bool = False) -> Vec3:
    """Euler angles of a quaternion (any non-zero `q`, treated as `q/|q|`; `±q` give the same).

    Bernardes & Viollet (2022), as SciPy's `Rotation.as_euler`: `seq` has 3 axes; first/third
    angle in [−π, π], middle in [0, π] (proper Euler) or [−π/2, π/2] (Tait–Bryan); at gimbal lock
    the third angle is 0. Finite values and gradients everywhere. `q` must be finite and
    non-zero; `degrees=True` returns degrees.
    """
    _parse_seq(seq)  # a bad sequence before any computation
    angles = _from_unit_quat(_quat_core._unit(vector(q, 4, "q"), "q"), seq)
    return jnp.rad2deg(angles) if degrees else angles


def _from_unit_quat(q: Quat, seq: EulerSeq) -> Vec3:
    (n1, n2, n3), intrinsic = _seq_axes(seq, q.dtype)
    if intrinsic:  # P = R1 R2 R3 is the extrinsic sequence (3, 2, 1)
        return _angles(q, n3, n2, n1, True)
    return _angles(q, n1, n2, n3, False)


def from_matrix(P: Mat33Like, seq: EulerSeq = "ZXZ", degrees: bool = False) -> Vec3:
    """Euler angles of a rotation matrix (via the largest-component `quat.from_matrix`), with the
    ranges and gimbal-lock convention of `from_quat` (3 axes; `degrees=True` returns degrees).
    `P` is checked and orthogonalised as by `quat.from_matrix` (det P ≤ 0 or a non-finite P is an
    error). One compiled program per shape, dtype and sequence, as `quat.from_matrix`."""
    _parse_seq(seq)
    P = matrix(P, "P")
    return _from_matrix(P, seq=seq, degrees=bool(degrees), mode=_quat_core._matrix_mode(P, "P"))


@compiled(2)
def _from_matrix(P: Mat33, seq: EulerSeq, degrees: bool, mode: str) -> Vec3:
    angles = _from_unit_quat(_quat_core._quat_of_matrix(P, "P", mode), seq)
    return jnp.rad2deg(angles) if degrees else angles


# --------------------------------------------------------------------------- kinematics


def _rot_basis(k: int, t: Scalar, v: Vec3) -> Vec3:
    """`R_k(t) v` for the elementary rotation about basis axis k."""
    i, j = (k + 1) % 3, (k + 2) % 3
    c, s = jnp.cos(t), jnp.sin(t)
    comp = {
        k: jnp.broadcast_to(v[..., k], c.shape),
        i: c * v[..., i] - s * v[..., j],
        j: s * v[..., i] + c * v[..., j],
    }
    return jnp.stack([comp[0], comp[1], comp[2]], axis=-1)


def jacobian(angles: Vec3Like, seq: EulerSeq = "ZXZ", frame: Frame = "body") -> Mat33:
    """Matrix `J` (columns per angle) with `ω = J (α̇, β̇, γ̇)`: kinematic Euler formulas for any
    sequence (Borisov–Mamaev 001; THEORY §4).

    Intrinsic `P = R1(α) R2(β) R3(γ)`: body `Ω = R3ᵀR2ᵀ e1 α̇ + R3ᵀ e2 β̇ + e3 γ̇`, space
    `ω = P Ω = e1 α̇ + R1 e2 β̇ + R1R2 e3 γ̇`; an extrinsic sequence is the reversed intrinsic one.
    For `"ZXZ"` body: `Ω1 = ψ̇ sinθ sinφ + θ̇ cosφ`, `Ω2 = ψ̇ sinθ cosφ − θ̇ sinφ`,
    `Ω3 = ψ̇ cosθ + φ̇`. `|det J| = |sin β|` (proper Euler) or `|cos β|` (Tait–Bryan).
    """
    angles = vector(angles, 3, "angles")
    axes, intrinsic = _parse_seq(seq)
    _check_frame(frame)
    if not intrinsic:
        axes, angles = axes[::-1], angles[..., ::-1]
    (k1, k2, k3), t = axes, (angles[..., 0], angles[..., 1], angles[..., 2])
    e = [jnp.broadcast_to(_basis(k, angles.dtype), angles.shape) for k in axes]
    if frame == "body":
        cols = [
            _rot_basis(k3, -t[2], _rot_basis(k2, -t[1], e[0])),
            _rot_basis(k3, -t[2], e[1]),
            e[2],
        ]
    else:
        cols = [e[0], _rot_basis(k1, t[0], e[1]), _rot_basis(k1, t[0], _rot_basis(k2, t[1], e[2]))]
    if not intrinsic:
        cols = cols[::-1]
    return jnp.stack(cols, axis=-1)


def rates_to_omega(
    angles: Vec3Like, rates: Vec3Like, seq: EulerSeq = "ZXZ", frame: Frame = "body"
) -> Vec3:
    """Angular velocity from Euler-angle rates, `ω = J(angles) rates` (see `jacobian`):
    body components Ω for `frame="body"`, space components ω = P Ω for `frame="space"`.
    `angles`, `rates` must be finite."""
    angles = _angles_arg(angles)
    rates = _angles_arg(rates, name="rates")
    broadcast_batch(angles=angles.shape[:-1], rates=rates.shape[:-1])
    J = jacobian(angles, seq, frame)
    return jnp.einsum("...ij,...j->...i", J, rates)


def omega_to_rates(
    angles: Vec3Like,
    omega: Vec3Like,
    seq: EulerSeq = "ZXZ",
    frame: Frame = "body",
    check: bool = False,
    tol: float = 1e-6,
) -> Vec3:
    """Euler-angle rates from the angular velocity (body Ω or space ω): `rates = J⁻¹ ω`, with the
    closed-form inverse `J⁻¹ = (c2×c3, c3×c1, c1×c2)ᵀ / det J` of the columns `c_i` of `jacobian`.

    Singular at gimbal lock, `det J = ±sin β` (proper Euler) or `±cos β` (Tait–Bryan), where the
    rates blow up as 1/det. With `check=True` that is an error naming `angles` (a ValueError on
    concrete angles, else a run-time `equinox.error_if`) where `|det J| < tol`; concrete angles
    at the lock to rounding (`|det J|` ≤ 16 ulp: β = 0 or `np.pi` for the default ZXZ, ±π/2 for
    Tait–Bryan, whose sine or cosine is no exact zero in floating point) are that error whatever
    `check` (traced ones give inf/NaN or rates of order 1e16 there). For aircraft
    angles (THEORY §4; 002 #148) use `seq="ZYX"` with angles (yaw, pitch, roll) and body ω: it
    returns (yaw rate, pitch rate, roll rate). `angles`, `omega` must be finite.
    """
    angles = _angles_arg(angles)
    omega = _angles_arg(omega, name="omega")
    broadcast_batch(angles=angles.shape[:-1], omega=omega.shape[:-1])
    J = jacobian(angles, seq, frame)
    c1, c2, c3 = J[..., 0], J[..., 1], J[..., 2]
    adj = jnp.stack([jnp.cross(c2, c3), jnp.cross(c3, c1), jnp.cross(c1, c2)], axis=-2)
    det = jnp.sum(c1 * adj[..., 0, :], -1)
    if check or is_concrete(det):
        at_lock = 16 * float(np.finfo(det.dtype).eps)  # sin π, cos(π/2) in floating point

        def locked(xp: Any, d: Any) -> Any:
            return ~(xp.abs(d) >= tol) if check else ~(xp.abs(d) > at_lock)

        def detail(d: np.ndarray) -> str:
            k = _validation.first(locked(np, d))
            a = np.broadcast_to(np.asarray(angles), (*d.shape, 3))[k]
            return (
                f": {_validation.at('angles', k)} = {_validation.fmt(a)}, |det J| = {abs(d[k]):.3g}"
            )

        det = validate(
            det,
            locked,
            f"angles are at gimbal lock: the middle angle of seq={seq!r} is "
            + (f"within |det J| = |sin| or |cos| < {tol} of" if check else "at")
            + " its singular value (0/π for proper Euler, ±π/2 for Tait–Bryan)",
            detail,
            hint="; Euler-angle rates are singular there: use quaternion or rotation-vector "
            "kinematics, or the two-chart atlas of rigidjax.kinematics.euler_atlas "
            "(darboux(..., method='euler') switches to the partner sequence before a lock)",
        )
    return jnp.einsum("...ij,...j->...i", adj, omega) / det[..., None]
