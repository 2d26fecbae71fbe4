"""Finite rotation groups and the reduction of a rotation by them, as SciPy's
`Rotation.create_group` and `Rotation.reduce` (scipy/spatial/transform/_rotation_groups.py).

Groups (elements in SciPy's order, scalar-first): `"Cn"` the n turns by 2πk/n about `axis`;
`"Dn"` those and the n half-turns about the axes at angles πk/n in the plane ⟂ `axis`; `"T"`
(12), `"O"` (24) and `"I"` (60) the rotations of the tetrahedron, octahedron and icosahedron
(unit quaternions with entries 0, ±½, ±√2/2, ±1/(2φ), ±φ/2, φ the golden ratio).

Reduction: `r = l ∘ q ∘ ρ` with `l` from `left` and `ρ` from `right` chosen to maximise
`|r0|` (the smallest rotation angle, `2 acos|r0|`), where
`r0 = Σ ± l q ρ` is computed for all pairs as `(l̄ · (q ∘ ρ))` with `l̄ = (l0, −l)`.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, Literal, TypeAlias, overload

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, DTypeLike, Float, Int

from .._checks import vector
from .._custom_types import Quat, QuatLike
from ._quat_core import _unit, mul

__all__ = ["reduce", "rotation_group"]

_AXES = ("x", "y", "z", "X", "Y", "Z")
if TYPE_CHECKING:
    GroupName: TypeAlias = str
    GroupAxis: TypeAlias = Literal["x", "y", "z", "X", "Y", "Z"]
else:  # validated by `rotation_group` itself (SciPy's ValueErrors), not by the runtime checker
    GroupName = GroupAxis = object


def _rotvec_quat(rv: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions of rotation vectors (NumPy, for the constant tables)."""
    t = np.linalg.norm(rv, axis=-1, keepdims=True)
    axis = np.divide(rv, t, out=np.zeros_like(rv), where=t > 0)
    return np.concatenate([np.cos(t / 2), np.sin(t / 2) * axis], axis=-1)


def _canonical_rotvec(q: np.ndarray) -> np.ndarray:
    """SciPy's `as_rotvec` (w ≥ 0 representative) of scalar-first unit quaternions."""
    q = np.where(q[:, :1] < 0, -q, q)
    n = np.linalg.norm(q[:, 1:], axis=-1, keepdims=True)
    ang = 2 * np.arctan2(n, q[:, :1])
    return np.divide(ang * q[:, 1:], n, out=np.zeros_like(q[:, 1:]), where=n > 0)


def _cyclic(n: int, axis: int) -> np.ndarray:
    thetas = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rv = np.stack([thetas, np.zeros(n), np.zeros(n)], axis=-1)
    return _rotvec_quat(np.roll(rv, axis, axis=1))


def _dicyclic(n: int, axis: int) -> np.ndarray:
    g1 = _canonical_rotvec(_cyclic(n, axis))
    thetas = np.linspace(0, np.pi, n, endpoint=False)
    rv = np.pi * np.stack([np.zeros(n), np.cos(thetas), np.sin(thetas)], axis=-1)
    return _rotvec_quat(np.concatenate([g1, np.roll(rv, axis, axis=1)]))


def _tetrahedral_xyzw() -> np.ndarray:
    c = 0.5
    signs = [(-1, -1, 1), (-1, 1, 1), (1, -1, 1), (1, 1, 1)]
    signs += [(x, y, -z) for x, y, z in signs]
    g2 = np.array([[c, c * x, c * y, c * z] for x, y, z in signs])
    return np.concatenate([np.eye(4), g2])


def _octahedral_xyzw() -> np.ndarray:
    c = np.sqrt(2) / 2
    g2 = np.array(
        [
            [c, 0, 0, c],
            [0, c, 0, c],
            [0, 0, c, c],
            [0, 0, -c, c],
            [0, -c, 0, c],
            [-c, 0, 0, c],
            [0, c, c, 0],
            [0, -c, c, 0],
            [c, 0, c, 0],
            [-c, 0, c, 0],
            [c, c, 0, 0],
            [-c, c, 0, 0],
        ]
    )
    return np.concatenate([_tetrahedral_xyzw(), g2])


def _icosahedral_xyzw() -> np.ndarray:
    """The tetrahedral group and the 48 rotations whose quaternions are the even permutations of
    (±a, ±b, ±c, 0), (a, b, c) = (1, 1/φ, φ)/2, up to sign (the first non-zero entry positive);
    in SciPy's order: lexicographic with the entries ranked +a, +b, +c, −a, −b, −c, 0."""
    phi = (1 + np.sqrt(5)) / 2
    value = np.array([0.0, 0.5, 0.5 / phi, phi / 2])  # of the entry codes 0, ±1, ±2, ±3
    pairs = list(itertools.combinations(range(4), 2))
    even = [
        p for p in itertools.permutations(range(4)) if sum(p[i] > p[j] for i, j in pairs) % 2 == 0
    ]
    codes = {
        tuple(s * (1, 2, 3, 0)[i] for s, i in zip(signs, p, strict=True))
        for p in even
        for signs in itertools.product((1, -1), repeat=4)
    }
    rank = {1: 0, 2: 1, 3: 2, -1: 3, -2: 4, -3: 5, 0: 6}
    rows = sorted(
        (e for e in codes if next(k for k in e if k) > 0), key=lambda e: [rank[k] for k in e]
    )
    return np.concatenate([_tetrahedral_xyzw(), np.sign(rows) * value[np.abs(rows)]])


def rotation_group(
    name: GroupName, axis: GroupAxis = "Z", dtype: DTypeLike | None = None
) -> Float[Array, "K 4"]:
    """The elements of a finite rotation group as unit quaternions `(K, 4)` (scalar-first), in the
    order and with the signs of SciPy's `Rotation.create_group(name, axis)`.

    `name`: `"I"` (icosahedral, 60), `"O"` (octahedral, 24), `"T"` (tetrahedral, 12), `"Dn"`
    (dihedral, 2n) or `"Cn"` (cyclic, n) with a positive integer n; `axis` (`"x"`, `"y"`, `"z"`,
    any case) is the main axis of `Cn` and `Dn` (ignored by the others). Rotation groups only (no
    reflections). Bad arguments raise SciPy's `ValueError`s.
    """
    if not isinstance(name, str):
        raise ValueError(f"`group` argument must be a string, got name={name!r}")
    if axis not in _AXES:
        raise ValueError("`axis` must be one of " + ", ".join(_AXES) + f"; got axis={axis!r}")
    if name in ("I", "O", "T"):
        symbol, order = name, 1
    elif name[:1] in ("C", "D") and name[1:].isdigit():
        symbol, order = name[:1], int(name[1:])
    else:
        raise ValueError(
            f"`group` must be one of 'I', 'O', 'T', 'Dn', 'Cn' (n a positive integer, e.g. "
            f"'C4', 'D2'); got name={name!r}"
        )
    if order < 1:
        raise ValueError(f"Group order must be positive; got name={name!r}")
    k = "xyz".index(axis.lower())
    if symbol == "C":
        q = _cyclic(order, k)
    elif symbol == "D":
        q = _dicyclic(order, k)
    else:
        xyzw = {"I": _icosahedral_xyzw, "O": _octahedral_xyzw, "T": _tetrahedral_xyzw}[symbol]()
        q = np.roll(xyzw, 1, axis=-1)
    dtype = jnp.result_type(float) if dtype is None else dtype
    return jnp.asarray(q, dtype=dtype)


def _group_arg(g: QuatLike, name: str) -> Quat:
    g = vector(g, 4, name)
    if g.ndim != 2 or g.shape[0] < 1:
        raise ValueError(f"{name} must be a set of rotations of shape (K, 4), K ≥ 1, got {g.shape}")
    return _unit(g, name)


@overload
def reduce(
    q: QuatLike,
    left: QuatLike | None = None,
    right: QuatLike | None = None,
    return_indices: Literal[False] = False,
) -> Quat: ...
@overload
def reduce(
    q: QuatLike,
    left: QuatLike | None = None,
    right: QuatLike | None = None,
    *,
    return_indices: Literal[True],
) -> tuple[Quat, Int[Array, "*batch"] | None, Int[Array, "*batch"] | None]: ...
def reduce(
    q: QuatLike,
    left: QuatLike | None = None,
    right: QuatLike | None = None,
    return_indices: bool = False,
) -> Quat | tuple[Quat, Int[Array, "*batch"] | None, Int[Array, "*batch"] | None]:
    """The smallest rotation `l ∘ q ∘ ρ` over `l` in `left` and `ρ` in `right` (SciPy's
    `Rotation.reduce`): with `left`/`right` the symmetry groups (`rotation_group`) of two objects
    related by `q`, the smallest rotation that aligns them up to their symmetries.

    `q (..., 4)`; `left (L, 4)`, `right (R, 4)` sets of rotations, default the identity.
    Returns the reduced unit quaternions `(..., 4)` (sign of the product as computed); with
    `return_indices=True` also the indices `(...)` of the chosen elements of `left` and `right`
    (`None` for an argument not given; SciPy returns them with a leading length-1 axis for a single
    rotation, here they have the batch shape of `q`). Exact ties go to the first pair (row-major
    over left, right); pairs whose magnitudes differ only by rounding (symmetric groups give
    many) are told apart by that rounding, as in SciPy, which may choose another of them: the
    reduced rotations' magnitudes agree. Differentiable in `q` (the choice is piecewise
    constant).
    """
    q = _unit(vector(q, 4, "q"), "q")
    lg = None if left is None else _group_arg(left, "left").astype(q.dtype)
    rg = None if right is None else _group_arg(right, "right").astype(q.dtype)
    if lg is None and rg is None:
        return (q, None, None) if return_indices else q
    e = jnp.array([[1.0, 0.0, 0.0, 0.0]], q.dtype)
    ls = e if lg is None else lg
    rs = e if rg is None else rg
    qr = mul(q[..., None, :], rs)  # (..., R, 4)
    lbar = ls * jnp.array([1, -1, -1, -1], q.dtype)  # scalar part of l ∘ x is l̄ · x
    r0 = jnp.abs(jnp.einsum("li,...ri->...lr", lbar, qr))  # (..., L, R)
    flat = jnp.argmax(r0.reshape(*r0.shape[:-2], ls.shape[0] * rs.shape[0]), axis=-1)
    li, ri = flat // rs.shape[0], flat % rs.shape[0]
    reduced = mul(ls[li], jnp.take_along_axis(qr, ri[..., None, None], axis=-2)[..., 0, :])
    if not return_indices:
        return reduced
    return reduced, (None if lg is None else li), (None if rg is None else ri)
