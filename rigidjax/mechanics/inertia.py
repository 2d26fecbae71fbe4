"""Inertia tensors: point masses, primitive bodies, Steiner's theorem, principal axes, checks.

Source: Zegrya–Parshin lectures (004, THEORY §6). The inertia tensor about a point O is
`I_ik = Σ m (x_l² δ_ik − x_i x_k)` (an integral for a continuum), symmetric and positive
semi-definite; its eigenvalues are the principal moments, its eigenvectors the principal axes.
Each principal moment is at most the sum of the other two (equality for a planar body,
`I3 = I1 + I2`); a collinear body (the "rotator") has `I3 = 0`, `I1 = I2`.

All functions are pure JAX (jit / vmap / grad), accept leading batch dimensions and keep the
floating dtype of their inputs (integers are promoted to the default float dtype).
Primitives are given about their centre of mass in their symmetry axes (symmetry axis = z).
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool

from .._checks import (
    as_float,
    attach_check,
    check_nonnegative,
    check_positive,
    check_shape,
    floats,
    inertia_rtol,
    is_concrete,
    matrix,
    vector,
)
from .._custom_types import (
    InertiaLike,
    Mat33,
    Mat33Like,
    RealLike,
    Scalar,
    ScalarLike,
    Vec3,
    Vec3Like,
)

__all__ = [
    "as_tensor",
    "box",
    "center_of_mass",
    "check_inertia",
    "combine",
    "ellipsoid",
    "from_moments_and_axes",
    "parallel_axis",
    "point_masses",
    "principal_axes",
    "principal_moments",
    "rod",
    "solid_cone",
    "solid_cylinder",
    "solid_sphere",
    "spherical_shell",
]


def diagonal(T: Mat33) -> Vec3:
    """The diagonal `(..., 3)` of tensors `T (..., 3, 3)`, as three static slices: their
    transpose is a pad, where `jnp.diagonal`'s is a scatter (a gradient w.r.t. the moments of
    1e5 bodies on 2 CPU cores: 1.0 ms instead of 2.7 ms)."""
    return jnp.stack([T[..., 0, 0], T[..., 1, 1], T[..., 2, 2]], -1)


@jax.jit
def _diag(a: Scalar, b: Scalar, c: Scalar) -> Mat33:
    """Diagonal tensor diag(a, b, c) with the broadcast batch shape of a, b, c (one compiled
    program)."""
    a, b, c = jnp.broadcast_arrays(a, b, c)
    z = jnp.zeros_like(a)
    return jnp.stack(
        [jnp.stack([a, z, z], -1), jnp.stack([z, b, z], -1), jnp.stack([z, z, c], -1)], -2
    )


def _sym(a: Vec3) -> Mat33:
    """The tensor `a² E − a a` (the point-mass tensor of unit mass at `a`)."""
    eye = jnp.eye(3, dtype=a.dtype)
    a2 = jnp.sum(a * a, axis=-1)[..., None, None]
    return a2 * eye - a[..., :, None] * a[..., None, :]


# --------------------------------------------------------------------------- point masses


def _points(masses: RealLike, positions: RealLike) -> tuple[Array, Array]:
    """`masses (..., N)` and `positions (..., N, 3)` checked and broadcast together."""
    m, x = floats((masses, "masses"), (positions, "positions"))
    m = check_nonnegative(m, "masses", "a mass")
    check_shape(x, (3,), "positions")
    if x.ndim < 2:
        raise ValueError(f"positions must have shape (..., N, 3), got {tuple(x.shape)}")
    shape = jnp.broadcast_shapes(m.shape, x.shape[:-1])
    return jnp.broadcast_to(m, shape), jnp.broadcast_to(x, (*shape, 3))


def point_masses(
    masses: Annotated[RealLike, "*#batch N"], positions: Annotated[RealLike, "*#batch N 3"]
) -> Mat33:
    """Inertia tensor of point masses about the origin (Zegrya–Parshin (004)):
    `I_ik = Σ m (x_l² δ_ik − x_i x_k)`.

    `masses` (..., N) (broadcast against `positions[..., 0]`, so a scalar means equal masses),
    `positions` (..., N, 3). Returns (..., 3, 3).
    """
    m, x = _points(masses, positions)
    r2 = jnp.sum(x * x, axis=-1)
    eye = jnp.eye(3, dtype=x.dtype)
    return jnp.sum(m * r2, axis=-1)[..., None, None] * eye - jnp.einsum(
        "...n,...ni,...nk->...ik", m, x, x
    )


def center_of_mass(
    masses: Annotated[RealLike, "*#batch N"], positions: Annotated[RealLike, "*#batch N 3"]
) -> Vec3:
    """`R = Σ m x / Σ m` for `masses` (..., N), `positions` (..., N, 3)."""
    m, x = _points(masses, positions)
    return jnp.einsum("...n,...ni->...i", m, x) / jnp.sum(m, axis=-1)[..., None]


# --------------------------------------------------------------------------- primitives


def _body(mass: ScalarLike, *lengths: tuple[RealLike, str]) -> list[Array]:
    """`mass` and the `(length, name)` pairs as float arrays of one dtype (`floats`), the mass
    checked to be positive and the lengths non-negative (a clear error naming the argument)."""
    m, *ls = floats((mass, "mass"), *lengths)
    checked = [
        check_nonnegative(x, name, "a length") for x, (_, name) in zip(ls, lengths, strict=True)
    ]
    return [check_positive(m, "mass"), *checked]


def solid_sphere(mass: ScalarLike, radius: ScalarLike) -> Mat33:
    """Homogeneous ball about its centre: `I = 2/5 m r² E`."""
    m, r = _body(mass, (radius, "radius"))
    i = 0.4 * m * r**2
    return _diag(i, i, i)


def spherical_shell(mass: ScalarLike, radius: ScalarLike) -> Mat33:
    """Thin spherical shell about its centre: `I = 2/3 m r² E`."""
    m, r = _body(mass, (radius, "radius"))
    i = (2.0 / 3.0) * m * r**2
    return _diag(i, i, i)


def _pairwise_squares(mass: ScalarLike, lengths: Vec3Like, name: str, divisor: float) -> Mat33:
    """`diag(b² + c², a² + c², a² + b²) m/divisor` for `lengths = (a, b, c)` (..., 3)."""
    m, s = _body(mass, (lengths, name))
    check_shape(s, (3,), name)
    a2, b2, c2 = s[..., 0] ** 2, s[..., 1] ** 2, s[..., 2] ** 2
    k = m / divisor
    return _diag(k * (b2 + c2), k * (a2 + c2), k * (a2 + b2))


def box(mass: ScalarLike, size: Vec3Like) -> Mat33:
    """Homogeneous rectangular box with full edge lengths `size = (a, b, c)` (..., 3) along
    x, y, z, about its centre: `diag(b² + c², a² + c², a² + b²) m/12`."""
    return _pairwise_squares(mass, size, "size", 12.0)


def solid_cylinder(mass: ScalarLike, radius: ScalarLike, height: ScalarLike) -> Mat33:
    """Homogeneous solid cylinder, axis z, about its centre:
    `I_zz = ½ m r²`, `I_xx = I_yy = m (3 r² + h²)/12`."""
    m, r, h = _body(mass, (radius, "radius"), (height, "height"))
    i = m * (3.0 * r**2 + h**2) / 12.0
    return _diag(i, i, 0.5 * m * r**2)


def rod(mass: ScalarLike, length: ScalarLike) -> Mat33:
    """Thin rod along z about its centre: `I_xx = I_yy = m L²/12`, `I_zz = 0` — the "rotator"
    of Zegrya–Parshin (004). Singular: not accepted by `check_inertia` (no inverse)."""
    m, L = _body(mass, (length, "length"))
    i = m * L**2 / 12.0
    return _diag(i, i, jnp.zeros_like(i))


def ellipsoid(mass: ScalarLike, semi_axes: Vec3Like) -> Mat33:
    """Homogeneous solid ellipsoid with semi-axes `(a, b, c)` (..., 3) along x, y, z:
    `diag(b² + c², a² + c², a² + b²) m/5`."""
    return _pairwise_squares(mass, semi_axes, "semi_axes", 5.0)


def solid_cone(mass: ScalarLike, radius: ScalarLike, height: ScalarLike) -> Mat33:
    """Homogeneous solid right circular cone, axis z, about its centre of mass (which lies on
    the axis at h/4 from the base: base at z = −h/4, apex at z = +3h/4):
    `I_zz = 3/10 m r²`, `I_xx = I_yy = 3/20 m r² + 3/80 m h²`."""
    m, r, h = _body(mass, (radius, "radius"), (height, "height"))
    i = 0.15 * m * r**2 + 0.0375 * m * h**2
    return _diag(i, i, 0.3 * m * r**2)


# --------------------------------------------------------------------------- transformations


def parallel_axis(
    I_com: Mat33Like, mass: ScalarLike, offset: Vec3Like, *, to_com: bool = False
) -> Mat33:
    """Steiner's (Huygens–Steiner) theorem, Zegrya–Parshin (004) (11.33):
    `Ĩ_ik = I_ik + m (a² δ_ik − a_i a_k)`.

    `I_com` is about the centre of mass; the result is about the point displaced by `offset`
    `a` from it (the sign of `a` does not matter). With `to_com=True` the inverse: `I_com` is
    then the tensor about that point and the tensor about the centre of mass is returned.
    """
    I, m, a = floats((I_com, "I_com"), (mass, "mass"), (offset, "offset"))
    check_shape(I, (3, 3), "I_com")
    check_shape(a, (3,), "offset")
    shift = m[..., None, None] * _sym(a)
    return I - shift if to_com else I + shift


def combine(
    inertias: Annotated[RealLike, "*#batch K 3 3"],
    masses: Annotated[RealLike, "*#batch K"],
    coms: Annotated[RealLike, "*#batch K 3"],
) -> tuple[Mat33, Scalar, Vec3]:
    """Compound body from K parts (inertia tensors are additive, 004).

    `inertias` (..., K, 3, 3) each about its part's own centre of mass (in common axes),
    `masses` (..., K), `coms` (..., K, 3). Returns `(I, M, R)`: the tensor about the common
    centre of mass `R = Σ m_k c_k / M`, the total mass `M = Σ m_k` and `R`. Each part is shifted
    by Steiner's theorem to `R`: `I = Σ [I_k + m_k (d_k² E − d_k d_k)]`, `d_k = c_k − R`.
    """
    I, m, c = floats((inertias, "inertias"), (masses, "masses"), (coms, "coms"))
    check_shape(I, (3, 3), "inertias")
    check_shape(c, (3,), "coms")
    if I.ndim < 3 or c.ndim < 2:
        raise ValueError(
            "inertias must have shape (..., K, 3, 3) and coms (..., K, 3), got "
            f"{tuple(I.shape)} and {tuple(c.shape)}"
        )
    shape = jnp.broadcast_shapes(I.shape[:-2], m.shape, c.shape[:-1])
    I = jnp.broadcast_to(I, (*shape, 3, 3))
    m = jnp.broadcast_to(m, shape)
    c = jnp.broadcast_to(c, (*shape, 3))
    M = jnp.sum(m, axis=-1)
    R = jnp.einsum("...k,...ki->...i", m, c) / M[..., None]
    d = c - R[..., None, :]
    total = jnp.sum(I + m[..., None, None] * _sym(d), axis=-3)
    return total, M, R


# --------------------------------------------------------------------------- principal axes


def principal_moments(I: Mat33Like) -> Vec3:
    """Principal moments (eigenvalues of the symmetric part of `I`), ascending, (..., 3).
    Gradients are finite also for repeated moments (symmetric / spherical tops)."""
    I = matrix(I, "I")
    return jnp.linalg.eigvalsh(I)


def principal_axes(I: Mat33Like) -> tuple[Vec3, Mat33]:
    """`(moments, axes)`: principal moments ascending (..., 3) and the principal axes as the
    COLUMNS of `axes` (..., 3, 3), right-handed (det = +1), so `I = axes diag(moments) axesᵀ`.

    Via `jnp.linalg.eigh` (uses the symmetric part). Each axis is defined up to sign (the last
    column is flipped to make det = +1). Gradient caveat: for repeated moments (symmetric top
    I1 = I2, spherical top) the axes are not unique and their gradient is NaN/inf; the
    moments' gradient stays finite — differentiate `moments` only (or `principal_moments`).
    """
    I = matrix(I, "I")
    w, v = jnp.linalg.eigh(I)
    s = jnp.sign(jnp.linalg.det(v))
    s = jnp.where(s == 0, jnp.ones_like(s), s)
    v = v.at[..., :, 2].multiply(s[..., None])
    return w, v


def from_moments_and_axes(moments: Vec3Like, axes: Mat33Like | None = None) -> Mat33:
    """`I = axes diag(moments) axesᵀ` (principal axes as columns of `axes`); `diag(moments)`
    when `axes` is None. Inverse of `principal_axes`."""
    w = vector(moments, 3, "moments")
    D = _diag(w[..., 0], w[..., 1], w[..., 2])
    if axes is None:
        return D
    w, A = floats((w, "moments"), (axes, "axes"))
    check_shape(A, (3, 3), "axes")
    return (A * w[..., None, :]) @ jnp.swapaxes(A, -1, -2)


def as_tensor(inertia: InertiaLike) -> Mat33:
    """Inertia tensor from principal moments (..., 3) → diag, or a tensor (..., 3, 3) as is.

    Shapes ending in (3, 3) are read as tensors, so a batch of three moment vectors (3, 3) is
    ambiguous and read as one tensor: use `from_moments_and_axes` for those.
    """
    x = as_float(inertia, "inertia")
    if x.ndim >= 2 and x.shape[-2:] == (3, 3):
        return x
    if x.ndim >= 1 and x.shape[-1] == 3:
        return from_moments_and_axes(x)
    raise ValueError(
        "inertia must be principal moments of shape (..., 3) or a tensor of shape (..., 3, 3), "
        f"got {tuple(x.shape)}"
    )


# --------------------------------------------------------------------------- validation


def _violations(I: Any, rtol: float, xp: Any, diagonal: bool = False) -> tuple[Any, ...]:
    """Per-matrix diagnostics with the array module `xp` (numpy on concrete input, else jnp);
    a `diagonal` tensor's principal moments are its diagonal in order (no eigensolver: one per
    body of a traced batch cost as much as integrating it)."""
    if diagonal:
        # symmetric by construction; min, middle, max of the diagonal componentwise (no sort,
        # no reduction over a 3-axis: one fused pass over a traced batch)
        d = [I[..., i, i] for i in range(3)]
        finite = xp.isfinite(d[0]) & xp.isfinite(d[1]) & xp.isfinite(d[2])
        d = [xp.where(finite, x, 0) for x in d]
        lo = xp.minimum(xp.minimum(d[0], d[1]), d[2])
        hi = xp.maximum(xp.maximum(d[0], d[1]), d[2])
        w = xp.stack([lo, d[0] + d[1] + d[2] - lo - hi, hi], axis=-1)
        size = scale = xp.maximum(xp.abs(lo), xp.abs(hi))
        asym = xp.zeros_like(size)
    else:  # eigenvalues of the symmetric part (numpy's eigvalsh would read one triangle only)
        asym = xp.max(xp.abs(I - xp.swapaxes(I, -1, -2)), axis=(-2, -1))
        size = xp.max(xp.abs(I), axis=(-2, -1))
        finite = xp.all(xp.isfinite(I), axis=(-2, -1))
        sym = 0.5 * (I + xp.swapaxes(I, -1, -2))
        w = xp.linalg.eigvalsh(xp.where(finite[..., None, None], sym, 0))
        scale = xp.max(xp.abs(w), axis=-1)
    bad_sym = ~(asym <= rtol * size) | ~finite
    bad_pd = ~(w[..., 0] > rtol * scale)
    excess = w[..., 2] - (w[..., 0] + w[..., 1])
    bad_tri = ~(excess <= rtol * scale)
    return finite, asym, size, w, excess, bad_sym, bad_pd, bad_tri


def check_inertia(
    I: Mat33Like, name: str = "inertia", rtol: float | None = None, *, diagonal: bool = False
) -> Mat33:
    """Return `I` (..., 3, 3) unchanged after checking it is a valid inertia tensor for dynamics:

    1. finite and symmetric: `max|I − Iᵀ| ≤ rtol · max|I|`;
    2. positive definite: smallest principal moment `> rtol · largest`. A rotator / collinear
       body (004: `I3 = 0`) is a physical limit but has no inverse, so it is rejected;
    3. triangle inequality (004): each principal moment ≤ the sum of the other two, within
       `rtol · largest` (a planar body, `I3 = I1 + I2`, passes).

    `rtol` defaults to `max(1e-9, 1000 eps)` of the dtype. On concrete input a ValueError with
    the numbers is raised; under jit/vmap (traced input) `equinox.error_if` raises at run time
    with a static message. `diagonal`: `I` is diagonal by construction (principal moments).
    """
    I = matrix(I, name)
    tol = inertia_rtol(I.dtype) if rtol is None else float(rtol)
    if not is_concrete(I):
        finite, _, _, _, _, bad_sym, bad_pd, bad_tri = _violations(I, tol, jnp, diagonal)
        fails = jnp.stack([~jnp.all(finite), jnp.any(bad_sym), jnp.any(bad_pd), jnp.any(bad_tri)])
        msgs = [
            f"{name} has non-finite entries (NaN or inf); give finite moments",
            f"{name} is not symmetric (|I - I^T| > rtol*max|I|, rtol={tol:g}); "
            f"symmetrize it with (I + I^T)/2",
            f"{name} is not positive definite (smallest principal moment <= rtol*largest, "
            f"rtol={tol:g}); a rotator/collinear body (I3 = 0) is a physical limit but not "
            f"invertible, as needed for dynamics: give the body some thickness",
            f"{name} violates the triangle inequality (largest principal moment > sum of the "
            f"other two, beyond rtol={tol:g}); no mass distribution has such moments: "
            f"check the values/units",
        ]
        return attach_check(I, jnp.any(fails), jnp.argmax(fails), msgs)

    finite, asym, size, w, excess, bad_sym, bad_pd, bad_tri = _violations(np.asarray(I), tol, np)
    batch = I.shape[:-2]
    problems = []

    def first(mask: Bool[np.ndarray, "*batch"] | np.bool_) -> tuple[tuple[int, ...], str]:
        """Index of the first offending matrix and, for a batch, how many offend."""
        idx = tuple(int(i) for i in np.argwhere(mask)[0]) if batch else ()
        at = f" ({int(mask.sum())} of {math.prod(batch)} in the batch; first at {idx})"
        return idx, at if batch else ""

    if not finite.all():
        _, at = first(~finite)
        problems.append(f"has non-finite entries{at}; give finite moments")

    def pd(idx: tuple[int, ...]) -> tuple[str, str]:
        wi = w[idx]
        return (
            f"is not positive definite: smallest principal moment {wi[0]:.6g} <= rtol*largest "
            f"= {tol * np.max(np.abs(wi)):.3g} (moments {wi})"
        ), (
            "; a rotator/collinear body (I3 = 0) is a physical limit but not invertible, as "
            "needed for dynamics: give the body some thickness"
        )

    def tri(idx: tuple[int, ...]) -> tuple[str, str]:
        wi = w[idx]
        return (
            f"violates the triangle inequality: largest principal moment I3 = {wi[2]:.6g} "
            f"exceeds I1 + I2 = {wi[0] + wi[1]:.6g} by {excess[idx]:.3g} "
            f"(relative {excess[idx] / np.max(np.abs(wi)):.3g} > rtol = {tol:g})"
        ), "; no mass distribution has such moments: check the values/units"

    def sym(idx: tuple[int, ...]) -> tuple[str, str]:
        return (
            f"is not symmetric: max|I - I^T| = {asym[idx]:.3g} > rtol*max|I| = "
            f"{tol * size[idx]:.3g}"
        ), "; symmetrize it with (I + I^T)/2"

    for mask, describe in (
        (bad_sym & finite, sym),
        (bad_pd & ~bad_sym, pd),
        (bad_tri & ~bad_sym, tri),
    ):
        if mask.any():
            idx, at = first(mask)
            what, fix = describe(idx)
            problems.append(what + at + fix)
    if problems:
        raise ValueError(f"{name} " + f"; and {name} ".join(problems))
    return I
