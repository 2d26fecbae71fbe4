"""Wahba's problem: the rotation that best maps vectors `b_i` onto `a_i`, as SciPy's
`Rotation.align_vectors`.

Minimise `L(C) = ½ Σ w_i |a_i − C b_i|²` over rotations C. With `B = Σ w_i a_i b_iᵀ` and
`z = Σ w_i b_i × a_i`, `Σ w_i a_iᵀ C(q) b_i = qᵀ K q` for the unit quaternion `q = (λ0, λ)` of C,
with Davenport's symmetric matrix (in rigidjax's convention, C maps b to a)

    K = [[tr B, zᵀ], [z, B + Bᵀ − tr B E]],

so the optimal q is the eigenvector of the largest eigenvalue `λ_max` of K (Davenport's
q-method; Markley & Crassidis, "Fundamentals of Spacecraft Attitude Determination and Control",
2014, §5.5). `λ_max = s1 + s2 ± s3` (the singular values of B, the last with the sign of det B),
the optimum is unique iff `s2 ± s3 > 0` (the gap `λ_max − λ_2 = 2(s2 ± s3)`), and the eigenvector's
derivative needs only that gap. When the optimum is not unique (collinear vectors, all weights
zero) the optimal rotation closest to the identity is returned (the projection of `(1, 0, 0, 0)`
on the top eigenspace), and the derivative is the finite part of the perturbation formula.

Sensitivity (Markley 1993, as SciPy): `mean(w) / ζ · (κ E + B Bᵀ)` with `κ = s1s2 + s2s3 + s3s1`
and `ζ = (s1 + s2)(s2 + s3)(s3 + s1)` (signed s3), from the singular values as SciPy.

An infinite weight makes its pair primary (SciPy's "align-constrain", Magner 2018): the smallest
rotation `q_pri` taking `b̂_p` to `â_p` (`∝ (1 + â·b̂, b̂ × â)`, beyond 90° through a half-turn
that takes b̂_p to −b̂_p), then the turn `φ = atan2(Σ w (c × a)·â_p, Σ w (c·a − (c·â_p)(a·â_p)))`
about `â_p` that best aligns the others, `c = P(q_pri) b`. One vector pair takes this path too.

The value is SciPy's (the SVD of B, `_kabsch_quat`) where the optimum is unique; K gives the
derivative and the degenerate cases, except where one pair dominates: there the derivative is
`_refined`'s (`_scipy_value`), K's rounding being larger than the light pairs' gap.

Disparate finite weights (one pair's `w |a| |b|` above 1e6 times the others' sum): B rounds the
light pairs away at `eps w_max` (2.7e-6 rad at weights (1e10, 1); SciPy loses as much, up to
4e-6 measured). With `refine=True` the constrained solution is refined there by two Newton
steps on the full objective (`_refined`): within 4e-16 rad of a 50-digit (mpmath) solution in
30 random cases measured at weights (1e10, 1).
"""

from __future__ import annotations

from typing import Any, Literal, overload

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import Check, as_float, floats, is_concrete, validate_all, zero_vector
from .._compile import quick_compile_jit
from .._custom_types import Mat33, Quat, RealLike, Scalar
from . import _validation as _v
from ._quat_core import _from_orthogonal, _from_rotvec, _to_matrix, canonical, mul, rotate

# --------------------------------------------------------------------------- q-method


__all__ = ["DOMINANCE", "align_vectors"]


def _davenport_k(B: Mat33) -> Float[Array, "4 4"]:
    tr = jnp.trace(B)
    z = jnp.stack([B[2, 1] - B[1, 2], B[0, 2] - B[2, 0], B[1, 0] - B[0, 1]])
    S = B + B.T - tr * jnp.eye(3, dtype=B.dtype)
    top = jnp.concatenate([tr[None], z])
    return jnp.concatenate([top[None, :], jnp.concatenate([z[:, None], S], axis=1)], axis=0)


def _top_space(K: Float[Array, "4 4"]) -> tuple[Quat, Array, Array, Array]:
    """Eigen-decomposition of K and the optimal quaternion: the top eigenvector, or, if the top
    eigenvalue is (to rounding) multiple, the normalised projection of the identity onto its
    eigenspace (when that projection is not ~0)."""
    w, V = jnp.linalg.eigh(K)
    scale = jnp.max(jnp.abs(w))
    near = w >= w[-1] - 256 * jnp.finfo(K.dtype).eps * scale
    p = V @ jnp.where(near, V[0, :], jnp.zeros_like(w))
    n2 = jnp.sum(p * p)
    use = n2 > 1e-6
    v = jnp.where(use, p / jnp.sqrt(jnp.where(use, n2, jnp.ones_like(n2))), V[:, -1])
    return v, w, V, near


def _kabsch_svd(B: Mat33) -> tuple[Mat33, Array, Mat33]:
    """SciPy's SVD `B = U S Vᵀ` with Kabsch's sign: where det(U Vᵀ) < 0, U's last column and the
    last singular value negated, so that `U Vᵀ` is a rotation. The same LAPACK SVD as SciPy's on
    the CPU: the same numbers, also where B rounds light pairs away (`refine`)."""
    u, s, vh = jnp.linalg.svd(B)
    flip = _v.det(jnp, u @ vh) < 0
    u = u.at[:, -1].set(jnp.where(flip, -u[:, -1], u[:, -1]))
    return u, s.at[-1].set(jnp.where(flip, -s[-1], s[-1])), vh


def _kabsch_quat(B: Mat33) -> Quat:
    """SciPy's rotation for B, `C = U Vᵀ` (`_kabsch_svd`), as a quaternion."""
    u, _, vh = _kabsch_svd(B)
    return _from_orthogonal(u @ vh)


@jax.custom_jvp
def _optimal_quat(B: Mat33) -> Quat:
    """The optimal quaternion for B: SciPy's (`_kabsch_quat`) where the optimum is unique, else
    the optimal one closest to the identity (`_top_space`), of the sign of K's top eigenvector."""
    v, _, _, near = _top_space(_davenport_k(B))
    q = _kabsch_quat(B)
    q = jnp.where(q @ v < 0, -q, q)
    return jnp.where(near[-2], v, q)


@_optimal_quat.defjvp
def _optimal_quat_jvp(primals: Any, tangents: Any) -> tuple[Quat, Quat]:
    # dv = Σ_{i outside the top eigenspace} V_i (V_iᵀ dK v) / (λ_max − λ_i)
    # (v: K's own eigenvector, of the value's sign)
    (B,), (dB,) = primals, tangents
    v, w, V, near = _top_space(_davenport_k(B))
    gap = w[-1] - w
    proj = V.T @ (_davenport_k(dB) @ v)
    coef = jnp.where(near, jnp.zeros_like(gap), proj / jnp.where(near, jnp.ones_like(gap), gap))
    return _optimal_quat(B), V @ coef


def _kabsch(a: Array, b: Array, w: Array) -> tuple[Quat, Mat33]:
    """Optimal quaternion and B of the weighted problem (all weights finite); B formed as SciPy
    forms it, `(w a)ᵀ b`."""
    B = (w[:, None] * a).T @ b
    return _optimal_quat(B), B


def _sensitivity(B: Mat33, w: Array) -> Mat33:
    """SciPy's sensitivity from the singular values of B, the last signed by det(U Vᵀ) (κ and ζ of
    the module docstring; from λ_max, `(λ_max² − |B|²)/2` cancels at disparate weights: 1e-6
    relative at (1e10, 1, 1), measured). The singular values' derivative `uᵢᵀ dB vᵢ` is finite
    also where they repeat."""
    s = _kabsch_svd(B)[1]
    kappa = s[0] * s[1] + s[1] * s[2] + s[2] * s[0]
    zeta = (s[0] + s[1]) * (s[1] + s[2]) * (s[2] + s[0])
    return jnp.mean(w) / zeta * (kappa * jnp.eye(3, dtype=B.dtype) + B @ B.T)


# --------------------------------------------------------------------------- primary vector


def _unit3(x: Array) -> Array:
    n2 = jnp.sum(x * x, -1)
    ok = n2 > 0
    return x / jnp.sqrt(jnp.where(ok, n2, jnp.ones_like(n2)))


def _min_rotation(a: Array, b: Array) -> Quat:
    """Smallest rotation taking unit `b` onto unit `a`, `s = b × a`, `c = a·b`: `∝ (1 + c, s)` for
    c ≥ 0; for c < 0 the half-turn about `n ⟂ b` (n ∥ s; SciPy's axis ⟂ a, from a's two largest
    components, when `|s|` is at rounding level) that takes b to −b, followed by the smallest
    rotation `∝ (1 − c, −s)` from −b to a. Both factors are well conditioned and the product maps
    b onto a to rounding; it is the smallest rotation (about s, by atan2(|s|, c)) for n ∥ s."""
    c, s = jnp.dot(a, b), jnp.cross(b, a)
    i = jnp.argmin(jnp.abs(a))
    zero = jnp.zeros((), a.dtype)
    r_alt = jnp.stack(
        [
            jnp.where(i == 1, a[2], jnp.where(i == 2, -a[1], zero)),
            jnp.where(i == 2, a[0], jnp.where(i == 0, -a[2], zero)),
            jnp.where(i == 0, a[1], jnp.where(i == 1, -a[0], zero)),
        ]
    )
    tiny = 16 * jnp.finfo(a.dtype).eps
    v = jnp.where(jnp.sum(s * s) > tiny * tiny, s, r_alt)
    n = _unit3(v - jnp.dot(v, b) * b)
    direct = c >= 0
    q_near = jnp.concatenate([(1 + jnp.abs(c))[None], s])  # |c|: finite where unused
    q_back = jnp.concatenate([(1 + jnp.abs(c))[None], -s])
    q_near = q_near / jnp.linalg.norm(q_near)
    q_back = q_back / jnp.linalg.norm(q_back)
    q_far = mul(q_back, jnp.concatenate([zero[None], n]))
    return jnp.where(direct, q_near, q_far)


def _constrained(a: Array, b: Array, w: Array, primary: Array) -> Quat:
    """SciPy's align-constrain: the pair `primary` (index) aligned exactly, the others (weights
    `w`, the primary's ignored) best aligned by a turn about it."""
    a_p, b_p = _unit3(a[primary]), _unit3(b[primary])
    q_pri = _min_rotation(a_p, b_p)
    if a.shape[0] == 1:
        return q_pri
    w_sec = jnp.where(jnp.arange(a.shape[0]) == primary, 0.0, w).astype(a.dtype)
    c = rotate(q_pri, b)
    sin_t = jnp.sum(w_sec * (jnp.cross(c, a) @ a_p))
    cos_t = jnp.sum(w_sec * (jnp.sum(c * a, -1) - (c @ a_p) * (a @ a_p)))
    none = (sin_t == 0) & (cos_t == 0)  # no secondary information: no turn (finite gradient)
    phi = jnp.arctan2(sin_t, jnp.where(none, jnp.ones_like(cos_t), cos_t))
    return mul(_from_rotvec(jnp.where(none, 0.0, phi) * a_p), q_pri)


# above this ratio the q-method's loss, eps · ratio, exceeds 1e-10 rad
DOMINANCE = 1e6


def _dominant(a: Array, b: Array, w: Array) -> tuple[Array, Array]:
    """`(p, dominant)`: the pair `p` of the largest `w_i |a_i| |b_i|`, and whether it outweighs
    the others `DOMINANCE` times (then `_refined` solves the problem, not the q-method)."""
    s = w * jnp.sqrt(jnp.sum(a * a, -1) * jnp.sum(b * b, -1))
    p = jnp.argmax(s)
    return p, (s[p] > DOMINANCE * (jnp.sum(s) - s[p])) & (s.shape[0] > 1)


def _refined(a: Array, b: Array, w: Array, p: Array, active: Array | bool = True) -> Quat:
    """The optimum when pair `p` dominates (`_dominant`). Forming B (or K) rounds the other
    pairs' terms at `eps w_p`, a loss of about `eps w_p / Σ_others w` in the rotation about
    `a_p` (2e-6 at weights (1e10, 1)). Instead: start from the constrained solution with pair p
    primary (within about `Σ_others w / w_p` of the optimum) and take two Newton steps on
    `L(δ) = −Σ w_i a_i · exp(δ × E) c_i`, `c_i = P(q) b_i`, `q ← exp(δ) q`:
    `δ = H⁻¹ g`, `g = Σ w_i c_i × a_i`, `H = Σ w_i ((a_i·c_i) E − (a_i c_iᵀ + c_i a_iᵀ)/2)` (the
    second-order expansion of L at δ = 0). The primary term `w_p c_p × a_p` is ⟂ `a_p`, but its
    rounding (`eps w_p`) is not: it is projected on the plane ⟂ `a_p`, so that the rotation
    about `a_p` is fixed by the other pairs alone, to rounding (measured: from 1e-10 to 2e-16 in
    the first step). The second step makes the derivative the implicit one at the optimum. Where
    not `active` (traced weights, no dominant pair) H is replaced by E (finite values and
    gradients in the branch not taken)."""
    q = _constrained(a, b, w, p)
    n = _unit3(a[p])
    eye = jnp.eye(3, dtype=a.dtype)
    for _ in range(2):
        c = rotate(q, b)
        G = w[:, None] * jnp.cross(c, a)
        G = G.at[p].add(-n * (n @ G[p]))
        ac = jnp.sum(a * c, -1)
        H = jnp.einsum(
            "n,nij->ij",
            w,
            ac[:, None, None] * eye
            - 0.5 * (a[:, :, None] * c[:, None, :] + c[:, :, None] * a[:, None, :]),
        )
        H = jnp.where(active, H, eye)
        q = mul(_from_rotvec(jnp.linalg.solve(H, jnp.sum(G, 0))), q)
    return q


@jax.custom_jvp
def _scipy_value(q: Quat, a: Array, b: Array, w: Array, p: Array, dominant: Array) -> Quat:
    """SciPy's `q`; where pair `p` is `dominant`, with the derivative of the optimum
    (`_refined`): K's perturbation formula loses it there (K's rounding, eps w_max, over the
    light pairs' gap). A value-only call does not run `_refined`."""
    return q


@_scipy_value.defjvp
def _scipy_value_jvp(primals: Any, tangents: Any) -> tuple[Quat, Quat]:
    q, a, b, w, p, dominant = primals
    dq, da, db, dw, _, _ = tangents
    q_opt, dq_opt = jax.jvp(lambda a, b, w: _refined(a, b, w, p, dominant), (a, b, w), (da, db, dw))
    dq_opt = jnp.where(q_opt @ q < 0, -dq_opt, dq_opt)
    return q, jnp.where(dominant, dq_opt, dq)


# --------------------------------------------------------------------------- checks


def _weight_checks() -> list[Check]:
    def nan(xp: Any, w: Any) -> Any:
        return xp.isnan(w)

    def negative(xp: Any, w: Any) -> Any:
        return w < 0

    def several_inf(xp: Any, w: Any) -> Any:
        return xp.sum(xp.isinf(w)) > 1

    def where(bad: Any) -> Any:
        def detail(w: np.ndarray) -> str:
            k = _v.first(bad(np, w))
            return f", got {_v.at('weights', k)} = {w[k]:.6g}"

        return detail

    hint = "; a weight is the importance of its pair (0 leaves it out, inf makes it primary)"
    return [
        Check(nan, "`weights` may not contain NaN values", where(nan), hint),
        Check(negative, "`weights` may not contain negative values", where(negative), hint),
        Check(
            several_inf,
            "Only one infinite weight is allowed",
            lambda w: f", got weights = {_v.fmt(w)}",
            "; an infinite weight marks the one pair aligned exactly (the primary vectors)",
        ),
    ]


def _args(
    a: RealLike, b: RealLike, weights: RealLike | None
) -> tuple[Array, Array, Array, tuple[int, ...]]:
    a, b = floats((a, "a"), (b, "b"))
    shape_a = tuple(a.shape)
    for x, name in ((a, "a"), (b, "b")):
        if x.ndim not in (1, 2) or x.shape[-1] != 3:
            raise ValueError(
                f"Expected input `{name}` to have shape (3,) or (N, 3), got {tuple(x.shape)} "
                "(use jax.vmap for a batch of problems)"
            )
    if a.shape != b.shape:
        raise ValueError(
            f"Expected inputs `a` and `b` to have same shapes, got {tuple(a.shape)} and "
            f"{tuple(b.shape)} respectively (one vector of b for each of a)"
        )
    a, b = jnp.atleast_2d(a), jnp.atleast_2d(b)
    n = a.shape[0]
    if n == 0:
        raise ValueError("a and b must hold at least one vector pair, got shape (0, 3)")
    a = _v.check_finite(a, "a", 1)
    b = _v.check_finite(b, "b", 1)
    if weights is None:
        w = jnp.ones(n, a.dtype)
    else:
        w = as_float(weights, "weights").astype(a.dtype)
        if w.ndim != 1:
            raise ValueError(f"Expected `weights` to be 1 dimensional, got shape {w.shape}.")
        if w.shape[0] != n:
            raise ValueError(
                "Expected `weights` to have number of values equal to number of input vectors, "
                f"got {w.shape[0]} values and {n} vectors."
            )
        w = validate_all(w, _weight_checks())
    return a, b, w, shape_a


def _zero_primary_check(a: Array, b: Array, primary: Array, active: Array) -> Array:
    def bad(xp: Any, ab: Any) -> Any:
        return zero_vector(xp, ab)

    # (only where there is a primary pair: traced weights may have none)
    ab = jnp.where(active, jnp.stack([a[primary], b[primary]]), jnp.ones((2, 3), a.dtype))
    return validate_all(
        ab,
        [
            Check(
                bad,
                "Cannot align zero length primary vectors",
                lambda x: f": a = {_v.fmt(x[0])}, b = {_v.fmt(x[1])}",
                "; the primary pair (the one vector pair, or the one of infinite weight) needs "
                "non-zero a and b",
            )
        ],
        on=primary,
    )


# --------------------------------------------------------------------------- public


@overload
def align_vectors(
    a: RealLike,
    b: RealLike,
    weights: RealLike | None = None,
    return_sensitivity: Literal[False] = False,
    *,
    refine: bool = False,
) -> tuple[Quat, Scalar]: ...
@overload
def align_vectors(
    a: RealLike,
    b: RealLike,
    weights: RealLike | None = None,
    *,
    return_sensitivity: Literal[True],
    refine: bool = False,
) -> tuple[Quat, Scalar, Mat33]: ...
def align_vectors(
    a: RealLike,
    b: RealLike,
    weights: RealLike | None = None,
    return_sensitivity: bool = False,
    *,
    refine: bool = False,
) -> tuple[Quat, Scalar] | tuple[Quat, Scalar, Mat33]:
    """The rotation `q` that best maps `b` onto `a` (Wahba's problem), as SciPy's
    `Rotation.align_vectors`: minimises `½ Σ w_i |a_i − P(q) b_i|²` (module docstring).

    `a`, `b`: `(N, 3)` or `(3,)` (one pair), finite; use `jax.vmap` for a batch of problems.
    `weights (N,)`: non-negative (0 leaves a pair out), default all 1; one weight may be `inf`,
    making its pair primary: aligned exactly, the others then best aligned by a turn about it
    (SciPy's align-constrain). A single pair gives the smallest rotation taking `b` onto `a`
    (for `b = −a` a half-turn about SciPy's axis ⟂ a).

    Returns `(q, rssd)`: the unit quaternion (`canonical` sign) and the root sum of squared
    distances `√(Σ w_i |a_i − P(q) b_i|²)` (the primary pair left out), computed from the
    residuals (0, with gradient 0, for a fit exact to rounding: `rssd ≤ 64 eps √(Σ w(|a|² +
    |b|²))`). `return_sensitivity=True` adds SciPy's sensitivity matrix (3, 3) (not defined for a
    single pair or an infinite weight: ValueError; NaN if traced weights hold an `inf`).

    With finite weights the rotation is SciPy's: its SVD of `B = Σ w_i a_i b_iᵀ` (on the CPU the
    same LAPACK call, so the same numbers). Where one pair outweighs the others (`w|a||b|` over
    1e6 times their sum) B rounds the light pairs away at `eps w_max`, and so does SciPy (up to
    4e-6 rad at weights (1e10, 1)); `refine=True` returns the optimum itself there, to rounding
    (two Newton steps from the constrained solution, `_refined`).

    Values and gradients are finite everywhere; the gradient is exact when the optimum is unique
    (not all vectors collinear). Where it is not unique the rotation closest to the identity
    among the optimal ones is returned. Bad input raises SciPy's ValueErrors (shapes, negative
    or NaN weights, two infinite weights, a zero primary vector), under `jit` as run-time errors.
    """
    a, b, w, _ = _args(a, b, weights)
    n = a.shape[0]
    has_inf = bool(np.any(np.isinf(np.asarray(w)))) if is_concrete(w) else None
    if return_sensitivity and (n == 1 or has_inf):
        raise ValueError(
            "Cannot return sensitivity matrix with an infinite weight or one vector pair "
            "(the primary pair is fitted exactly: the sensitivity has no meaning)"
        )
    is_inf = jnp.isinf(w) if n > 1 else jnp.ones((1,), bool)
    primary = jnp.argmax(is_inf)
    if n == 1 or has_inf is not False:
        primary = _zero_primary_check(a, b, primary, is_inf[primary])
    solve = _solve_quick if all(map(is_concrete, (a, b, w))) else _solve
    return solve(a, b, w, primary, has_inf, refine, return_sensitivity)


def _solve_core(
    a: Array,
    b: Array,
    w: Array,
    primary: Array,
    has_inf: bool | None,
    refine: bool,
    sensitivity: bool,
) -> tuple[Quat, Scalar] | tuple[Quat, Scalar, Mat33]:
    """`align_vectors` of checked arguments, `primary` the index of the infinite weight (if
    any), `has_inf` whether there is one (None: traced weights, both paths)."""
    n = a.shape[0]
    is_inf = jnp.isinf(w) if n > 1 else jnp.ones((1,), bool)
    w_fin = jnp.where(jnp.isinf(w), jnp.zeros_like(w), w)
    if n == 1 or has_inf:
        q = _constrained(a, b, w_fin, primary)
        sens = None
    else:
        q, B = _kabsch(a, b, w_fin)
        p, dominant = _dominant(a, b, w_fin)
        if refine:
            q_opt = _refined(a, b, w_fin, p, dominant)
            q = jnp.where(dominant, jnp.where(q_opt @ q < 0, -q_opt, q_opt), q)
        else:
            q = _scipy_value(q, a, b, w_fin, p, dominant)
        sens = _sensitivity(B, w) if sensitivity else None
        if has_inf is None:  # traced weights: both paths, the one that applies selected
            any_inf = jnp.any(is_inf)
            q = jnp.where(any_inf, _constrained(a, b, w_fin, primary), q)
            sens = None if sens is None else jnp.where(any_inf, jnp.nan, sens)
    q = canonical(q)
    left_out = is_inf & (jnp.isinf(w) | (n > 1))  # a single finite-weight pair keeps its weight
    w_rssd = jnp.where(left_out, jnp.zeros_like(w_fin), w_fin)
    res = a - jnp.einsum("ij,nj->ni", _to_matrix(q, jnp.sum(q * q)), b)
    ssd = jnp.sum(w_rssd * jnp.sum(res * res, -1))
    # a fit exact to rounding is a perfect fit: rssd 0 with gradient 0 (a subgradient at the
    # kink of √ssd; the direction of the rounding residual is noise)
    scale = jnp.sum(w_rssd * (jnp.sum(a * a, -1) + jnp.sum(b * b, -1)))
    pos = ssd > (64 * jnp.finfo(ssd.dtype).eps) ** 2 * scale
    rssd = jnp.where(pos, jnp.sqrt(jnp.where(pos, ssd, jnp.ones_like(ssd))), jnp.zeros_like(ssd))
    if sensitivity:
        assert sens is not None
        return q, rssd, sens
    return q, rssd


# one compiled program per shape, dtype and flags: concrete arrays with XLA's quicker CPU
# compile (`quick_compile_jit`), tracers (derivatives, jit, vmap) nested in the caller's program
_solve_quick = quick_compile_jit(_solve_core)
_solve = eqx.filter_jit(_solve_core)
