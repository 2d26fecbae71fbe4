"""Generalized (Davenport) angles: rotations `P = Q(ψ m) Q(ϑ e) Q(φ n)` about fixed axes
`(m, e, n)` with `e ⟂ m, n` (the representation theorem, article 003; THEORY §1), as SciPy's
`Rotation.from_davenport`/`as_davenport` (intrinsic order). Angles from a rotation by the method
of Bernardes & Viollet (2022) shared with `euler` (`_euler_core`). `degrees=True` as in SciPy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import DTypeLike

from .._checks import as_float, matrix, validate, vector
from .._custom_types import DavenportAxesLike, Mat33, Mat33Like, Quat, QuatLike, Vec3, Vec3Like
from . import _quat_core
from ._euler_core import _angles, _angles_arg, _compose

__all__ = [
    "davenport_from_matrix",
    "davenport_from_quat",
    "davenport_to_matrix",
    "davenport_to_quat",
]


def _davenport_axes(axes: DavenportAxesLike, dtype: DTypeLike) -> tuple[Vec3, Vec3, Vec3]:
    """Unit axes (m, e, n) from `axes` of shape (..., 3, 3) = (m, e, n) or (..., 2, 3) = (m, n)."""
    axes = as_float(axes, "axes")
    if axes.ndim < 2 or axes.shape[-1] != 3 or axes.shape[-2] not in (2, 3):
        raise ValueError(
            "axes must have shape (..., 3, 3) with rows (m, e, n) or (..., 2, 3) with rows "
            f"(m, n), got {tuple(axes.shape)}"
        )
    axes = axes.astype(dtype)
    try:
        concrete = np.asarray(axes, dtype=np.float64)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        concrete = None
    if concrete is not None:
        nrm = np.linalg.norm(concrete, axis=-1)
        if not np.all(nrm > 0) or not np.all(np.isfinite(concrete)):
            raise ValueError("axes must be finite, non-zero vectors")
        u = concrete / nrm[..., None]
        if axes.shape[-2] == 2:
            if not np.all(np.linalg.norm(np.cross(u[..., 0, :], u[..., 1, :]), axis=-1) > 1e-6):
                raise ValueError(
                    "axes = (m, n) with m ∥ n leaves the middle axis undefined; "
                    "pass axes = (m, e, n) with e ⟂ m (m = n gives classical Euler angles)"
                )
        else:
            m_dot_e = np.abs(np.sum(u[..., 0, :] * u[..., 1, :], -1))
            e_dot_n = np.abs(np.sum(u[..., 1, :] * u[..., 2, :], -1))
            dots = np.maximum(m_dot_e, e_dot_n)
            if not np.all(dots <= 1e-6):
                raise ValueError(
                    "the middle axis e of axes = (m, e, n) must be perpendicular to both m and n "
                    "(representation theorem, THEORY §1)"
                )
    unit = axes / jnp.linalg.norm(axes, axis=-1, keepdims=True)
    m, n = unit[..., 0, :], unit[..., -1, :]
    if axes.shape[-2] == 2:
        e = jnp.cross(m, n)
        e = e / jnp.linalg.norm(e, axis=-1, keepdims=True)
    else:
        e = unit[..., 1, :]
    if concrete is None:  # traced axes: runtime check (NaN from m ∥ n in the (m, n) form fails it)
        ok = (jnp.abs(jnp.sum(m * e, -1)) <= 1e-6) & (jnp.abs(jnp.sum(e * n, -1)) <= 1e-6)
        msg = "axes: the middle axis e must be perpendicular to m and n (and m ∦ n)"
        e = validate(ok, lambda xp, ok: ~ok, msg, on=e)
    return m, e, n


def davenport_to_quat(angles: Vec3Like, axes: DavenportAxesLike, degrees: bool = False) -> Quat:
    """Quaternion of generalized (Davenport) angles `(ψ, ϑ, φ)`: `q = q(ψ m) ∘ q(ϑ e) ∘ q(φ n)`.

    See `davenport_to_matrix` for `axes`; `angles` must be finite."""
    angles = _angles_arg(angles, 3, degrees)
    m, e, n = _davenport_axes(axes, angles.dtype)
    return _compose(angles, m, e, n)


def davenport_to_matrix(angles: Vec3Like, axes: DavenportAxesLike, degrees: bool = False) -> Mat33:
    """Generalized Euler angles (representation theorem, article 003; THEORY §1):
    `P = Q(ψ m) Q(ϑ e) Q(φ n)` with fixed axes given as `axes = (m, e, n)` (shape (..., 3, 3),
    e ⟂ m and e ⟂ n) or `axes = (m, n)` (shape (..., 2, 3), then `e = m × n/|m × n|`).
    Axes need not be unit. `m = n` (with e given) gives classical Euler angles.

    Equals SciPy `Rotation.from_davenport([m, e, n], "intrinsic", (ψ, ϑ, φ))`. Unsuitable axes
    raise a ValueError (a runtime error if the axes are traced).
    """
    q = davenport_to_quat(angles, axes, degrees)
    return _quat_core._to_matrix(q, _quat_core.norm2(q))


def davenport_from_quat(q: QuatLike, axes: DavenportAxesLike, degrees: bool = False) -> Vec3:
    """Generalized angles `(ψ, ϑ, φ)` of a quaternion (finite, non-zero); see
    `davenport_from_matrix`."""
    angles = _davenport_from_unit_quat(_quat_core._unit(vector(q, 4, "q"), "q"), axes)
    return jnp.rad2deg(angles) if degrees else angles


def _davenport_from_unit_quat(q: Quat, axes: DavenportAxesLike) -> Vec3:
    m, e, n = _davenport_axes(axes, q.dtype)
    return _angles(q, n, e, m, True)


def davenport_from_matrix(P: Mat33Like, axes: DavenportAxesLike, degrees: bool = False) -> Vec3:
    """Generalized angles `(ψ, ϑ, φ)` with `P = Q(ψ m) Q(ϑ e) Q(φ n)` (Bernardes & Viollet 2022).

    As SciPy `Rotation.as_davenport([m, e, n], "intrinsic")`: ψ, φ ∈ [−π, π], ϑ ∈ [−λ, π − λ]
    where λ is the angle from n to m about e; at gimbal lock (ϑ = −λ or π − λ, where m and
    Q(ϑ e) n are parallel) φ = 0. `P` is checked and orthogonalised as by `quat.from_matrix`.
    """
    angles = _davenport_from_unit_quat(_quat_core._from_matrix(matrix(P, "P"), "P"), axes)
    return jnp.rad2deg(angles) if degrees else angles
