"""Modified Rodrigues parameters `p = tan(χ/4) e = λ/(1 + λ0)` (Schaub & Junkins).

Every rotation has two MRP vectors, `p` and its shadow `−p/|p|²` (from `q` and `−q`); the one with
`|p| ≤ 1` (χ ≤ π) is returned by `from_quat`/`from_matrix`, so MRPs are finite for every rotation
(unlike the Gibbs vector, `rigidjax.gibbs`). Conventions as `rigidjax.quat`; matches SciPy's
`Rotation.as_mrp`/`from_mrp`.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._checks import matrix, vector
from .._custom_types import Mat33, Mat33Like, Quat, QuatLike, Vec3, Vec3Like
from . import _quat_core, _validation, quat
from ._compiled import compiled

__all__ = ["compose", "from_matrix", "from_quat", "rotate", "shadow", "to_matrix", "to_quat"]


def _from_unit_quat(q: Quat) -> Vec3:
    return _from_canonical(quat.canonical(q))


def _from_canonical(q: Quat) -> Vec3:
    """`λ/(1 + λ0)` of a unit quaternion with λ0 ≥ 0."""
    return q[..., 1:] / (1 + q[..., :1])


def from_quat(q: QuatLike) -> Vec3:
    """`p = λ/(1 + λ0)` of `quat.canonical(q)` (`q` finite, non-zero, treated as `q/|q|`), so
    `|p| ≤ 1`."""
    return _from_unit_quat(_quat_core._unit(vector(q, 4, "q"), "q"))


def _to_quat(p: Vec3) -> Quat:
    p2 = jnp.sum(p * p, axis=-1, keepdims=True)
    return jnp.concatenate([1 - p2, 2 * p], axis=-1) / (1 + p2)


def to_quat(p: Vec3Like) -> Quat:
    """`(1 − p², 2p)/(1 + p²)`, for any finite `p` (a shadow `|p| > 1` gives λ0 < 0)."""
    return _to_quat(_finite(p, "p"))


def _finite(p: Vec3Like, name: str) -> Vec3:
    return _validation.check_finite(vector(p, 3, name), name, 1)


def from_matrix(P: Mat33Like) -> Vec3:
    """MRP (`|p| ≤ 1`) of a rotation matrix, through the largest-component quaternion; `P` is
    checked and orthogonalised as by `quat.from_matrix` (one compiled program)."""
    P = matrix(P, "P")
    return _from_matrix(P, mode=_quat_core._matrix_mode(P, "P"))


@compiled(2)
def _from_matrix(P: Mat33, mode: str) -> Vec3:
    return _from_canonical(_quat_core._quat_of_matrix(P, "P", mode))  # (canonical already)


def to_matrix(p: Vec3Like) -> Mat33:
    """`P = E + (8 S² + 4(1 − p²) S)/(1 + p²)²`, `S = p × E`; `p` must be finite."""
    q = to_quat(p)
    return _quat_core._to_matrix(q, quat.norm2(q))


def rotate(p: Vec3Like, r: Vec3Like) -> Vec3:
    """`P(p) r`; `p` must be finite."""
    return quat.rotate(_to_quat(_finite(p, "p")), r)


def compose(p1: Vec3Like, p2: Vec3Like) -> Vec3:
    """MRP (`|p| ≤ 1`) of `P(p1) P(p2)`, through the Hamilton product; `p1`, `p2` finite."""
    q = quat.mul(_to_quat(_finite(p1, "p1")), _to_quat(_finite(p2, "p2")))
    return _from_unit_quat(q / jnp.sqrt(quat.norm2(q))[..., None])


def shadow(p: Vec3Like) -> Vec3:
    """The same rotation with `|p| ≤ 1`: `−p/|p|²` where `|p| > 1`, else `p` (the switch used to
    keep MRP integrations away from the singularity at χ = 2π). Finite gradients at p = 0."""
    p = vector(p, 3, "p")
    p2 = jnp.sum(p * p, axis=-1, keepdims=True)
    far = p2 > 1
    return jnp.where(far, -p / jnp.where(far, p2, jnp.ones_like(p2)), p)
