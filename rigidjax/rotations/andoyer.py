"""Andoyer–Deprit canonical variables `(L, G, H, l, g, h)` of a rotating rigid body.

Source: Borisov–Mamaev, *Rigid body dynamics*, ch. 1 §4 (001); THEORY §5.

- `L = M3`: projection of the angular momentum M on the body axis Oz;
- `G = |M|`;
- `H = M_Z`: projection of M on the fixed (space) axis OZ;
- `l`: angle from the body axis Ox to the line of nodes of the plane Σ ⊥ M with the body plane Oxy;
- `g`: angle, in Σ, from its node line with the space plane OXY to its node line with Oxy;
- `h`: angle from the space axis OX to the node line of Σ with OXY.

`(l, L)`, `(g, G)`, `(h, H)` are canonically conjugate pairs. With `cos I = H/G`, `cos J = L/G`
(I, J ∈ [0, π]) the attitude is the product of five elementary rotations (THEORY §5)

    P = Rz(h) Rx(I) Rz(g) Rx(J) Rz(l),

`P` mapping body vectors to space (THEORY conventions), and

    M_body  = (√(G² − L²) sin l, √(G² − L²) cos l, L),
    M_space = P M_body = G (sin I sin h, −sin I cos h, cos I).

The third row of `P`, γ (the space axis OZ in body components), is the source's

    γ1 = (sin ζ cos τ + sin τ cos ζ cos g) sin l + cos ζ sin g cos l,
    γ2 = (sin ζ cos τ + sin τ cos ζ cos g) cos l − cos ζ sin g sin l,
    γ3 = sin ζ sin τ − cos τ cos ζ cos g,          sin τ = L/G, sin ζ = H/G.

(The source's printed α and β are corrupted, α·γ ≠ 0; this module derives everything from `P`.)

Singular sets of the inverse map `to_andoyer`: J ∈ {0, π} (M ∥ body Oz, `|L| = G`: the body node
line and `l` are undefined) and I ∈ {0, π} (M ∥ space OZ, `|H| = G`: `h` is undefined). There the
undefined angle is set to 0 and its share of the rotation goes into `g`, which gives a valid set
(`from_andoyer` reproduces M and P) with finite values and gradients.

Precision: near the poles |L| → G the pair (L, G) fixes √(G² − L²) = |(M1, M2)| only through
G − L, whose absolute error is ~eps G (G is rounded); the in-plane component ρ then has an error
≈ √(ρ² + eps G²) − ρ: ~eps G²/ρ, growing to ~√eps G (about 1e-8 G in float64) when ρ ≲ √eps G.
The same holds for (H, G) and sin I near the space axis OZ. So a round trip
(M, P) → Andoyer → (M, P) is exact to rounding except within ~√eps of these poles, where M and P
come back to ~√eps; the conditioning of the variables, not of the formulas. Exactly on a pole
(in-plane part ≤ eps G) `to_andoyer` returns |L| = G (|H| = G) exactly and the round trip is exact.
"""

from __future__ import annotations

from typing import Annotated, Any, NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._checks import floats, matrix, vector, zero_vector
from .._custom_types import Mat33, Mat33Like, RealLike, Scalar, ScalarLike, Vec3, Vec3Like
from .._numerics import safe_sqrt
from . import _validation

__all__ = [
    "AndoyerVariables",
    "free_body_hamiltonian",
    "from_andoyer",
    "gamma",
    "momentum",
    "space_momentum",
    "to_andoyer",
    "to_momentum_attitude",
]


class AndoyerVariables(NamedTuple):
    """Andoyer–Deprit variables; each field is an array of the same leading batch shape.

    A NamedTuple, hence a JAX pytree: it passes through `jit`, `vmap` and `grad` as is, and
    `from_andoyer(*av)` inverts `to_andoyer`.
    """

    L: Scalar
    G: Scalar
    H: Scalar
    l: Scalar
    g: Scalar
    h: Scalar

    def as_array(self) -> Float[Array, "*#batch 6"]:
        """Stack into one array `(..., 6)` in the order `(L, G, H, l, g, h)`."""
        return jnp.stack(jnp.broadcast_arrays(*self), axis=-1)

    @classmethod
    def from_array(cls, x: Annotated[RealLike, "*#batch 6"]) -> AndoyerVariables:
        """Inverse of `as_array`: split `(..., 6)` into the six fields."""
        x = vector(x, 6, "x")
        return cls(*(x[..., i] for i in range(6)))


# --- private helpers -------------------------------------------------------------------------


def _rz(c: Scalar, s: Scalar) -> Mat33:
    """Rotation about z by the angle with cosine `c`, sine `s`:
    [[c, −s, 0], [s, c, 0], [0, 0, 1]]."""
    o, i = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.stack(
        [jnp.stack([c, -s, o], -1), jnp.stack([s, c, o], -1), jnp.stack([o, o, i], -1)], -2
    )


def _rx(c: Scalar, s: Scalar) -> Mat33:
    """Rotation about x by the angle with cosine `c`, sine `s`:
    [[1, 0, 0], [0, c, −s], [0, s, c]]."""
    o, i = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.stack(
        [jnp.stack([i, o, o], -1), jnp.stack([o, c, -s], -1), jnp.stack([o, s, c], -1)], -2
    )


def _direction(x: Scalar, y: Scalar) -> tuple[Scalar, Scalar, Bool[Array, "*#batch"]]:
    """`(cos φ, sin φ) = (x, y)/√(x² + y²)` for a planar vector of length ≤ 1; `(1, 0)` (φ = 0)
    when its length is at the rounding level (≤ eps), with finite values and gradients.
    Also returns that degeneracy mask."""
    r2 = x * x + y * y
    eps = jnp.finfo(r2.dtype).eps
    degenerate = r2 <= eps * eps
    r = jnp.sqrt(jnp.where(degenerate, jnp.ones_like(r2), r2))
    c = jnp.where(degenerate, jnp.ones_like(x), x / r)
    s = jnp.where(degenerate, jnp.zeros_like(y), y / r)
    return c, s, degenerate


def _broadcast(*xs: ScalarLike, names: tuple[str, ...]) -> list[Scalar]:
    return list(jnp.broadcast_arrays(*floats(*zip(xs, names, strict=True))))


def _checked(*xs: ScalarLike, names: tuple[str, ...]) -> list[Scalar]:
    """The arguments broadcast together and checked at the cost of one run-time check: each
    finite, `G > 0` and `|L|, |H| ≤ G` (to 64 eps; they are projections of M) where present. The
    errors name the argument (ValueError with the value on concrete input)."""
    x = jnp.stack(_broadcast(*xs, names=names), axis=-1)
    col = {n: i for i, n in enumerate(names)}
    checks = [_column_finite(n, i) for n, i in col.items()]
    iG = col["G"]

    def not_positive(xp: Any, v: Any) -> Any:
        return ~(v[..., iG] > 0)

    def at_G(v: np.ndarray) -> str:
        k = _validation.first(not_positive(np, v))
        return f", got {_validation.at('G', k)} = {v[k][iG]:.6g}"

    checks.append(
        _validation.Check(
            not_positive,
            "G must be positive: G = |M| > 0",
            at_G,
            "; Andoyer–Deprit variables need a non-zero angular momentum",
        )
    )
    for n in ("L", "H"):
        if n in col:
            checks.append(_projection_check(n, col[n], iG))
    x = _validation.validate_all(x, checks)
    return [x[..., i] for i in range(len(names))]


def _column_finite(name: str, i: int) -> _validation.Check:
    def bad(xp: Any, v: Any) -> Any:
        return ~xp.isfinite(v[..., i])

    def detail(v: np.ndarray) -> str:
        k = _validation.first(bad(np, v))
        return f", got {_validation.at(name, k)} = {v[k][i]}"

    return _validation.Check(bad, f"{name} must be finite", detail, _validation.NONFINITE_HINT)


def _projection_check(name: str, i: int, iG: int) -> _validation.Check:
    def bad(xp: Any, v: Any) -> Any:
        G = v[..., iG]
        return xp.abs(v[..., i]) > G * (1 + 64 * xp.finfo(v.dtype).eps)

    def detail(v: np.ndarray) -> str:
        k = _validation.first(bad(np, v))
        return f": {_validation.at(name, k)} = {v[k][i]:.9g}, G = {v[k][iG]:.9g}"

    return _validation.Check(
        bad,
        f"|{name}| must not exceed G = |M| ({name} is a projection of M)",
        detail,
        f"; pass |{name}| ≤ G",
    )


def _cos_sin(X: Scalar, G: Scalar) -> tuple[Scalar, Scalar]:
    """`(cos, sin)` of the angle in [0, π] with cosine `X/G` (X = L or H, `|X| ≤ G` checked by
    `_checked`). The sine is `√((G − X)(G + X))/G`, which keeps its relative accuracy near the
    poles better than `√(1 − cos²)`; values are clipped to the unit circle."""
    c = jnp.clip(X / G, -1, 1)
    s = jnp.minimum(safe_sqrt((G - X) * (G + X)) / G, 1)
    return c, s


def _is_zero(xp: Any, M: Any) -> Any:
    return zero_vector(xp, M)


def _at_zero(M: np.ndarray) -> str:
    k = _validation.first(_is_zero(np, M))
    return f": {_validation.at('M_body', k)} = {_validation.fmt(M[k])}"


_zero_momentum = _validation.Check(
    _is_zero,
    "M_body is zero",
    _at_zero,
    "; Andoyer–Deprit variables need G = |M| > 0",
)


# --- public functions ------------------------------------------------------------------------


def momentum(L: ScalarLike, G: ScalarLike, l: ScalarLike) -> Vec3:
    """Body angular momentum `M = (√(G² − L²) sin l, √(G² − L²) cos l, L)` (Borisov–Mamaev (001);
    THEORY §5). `L, l` are cylindrical coordinates on the sphere |M| = G."""
    L, G, l = _checked(L, G, l, names=("L", "G", "l"))
    _, sJ = _cos_sin(L, G)
    rho = G * sJ
    return jnp.stack([rho * jnp.sin(l), rho * jnp.cos(l), L], axis=-1)


def space_momentum(G: ScalarLike, H: ScalarLike, h: ScalarLike) -> Vec3:
    """Space angular momentum `P M = G (sin I sin h, −sin I cos h, cos I)`, `cos I = H/G`
    (THEORY §5)."""
    G, H, h = _checked(G, H, h, names=("G", "H", "h"))
    _, sI = _cos_sin(H, G)
    rho = G * sI
    return jnp.stack([rho * jnp.sin(h), -rho * jnp.cos(h), H], axis=-1)


def from_andoyer(
    L: ScalarLike, G: ScalarLike, H: ScalarLike, l: ScalarLike, g: ScalarLike, h: ScalarLike
) -> tuple[Vec3, Mat33]:
    """Body angular momentum and attitude `(M_body (..., 3), P (..., 3, 3))` of Andoyer–Deprit
    variables (Borisov–Mamaev (001); THEORY §5):

        M_body = (√(G² − L²) sin l, √(G² − L²) cos l, L),
        P = Rz(h) Rx(I) Rz(g) Rx(J) Rz(l),   cos I = H/G, cos J = L/G, I, J ∈ [0, π].

    The six arguments broadcast together; `from_andoyer(*av)` for an `AndoyerVariables` av.
    Raises (a ValueError naming the argument, or a run-time error under jit) if an argument is
    not finite, `G ≤ 0` or `|L|` or `|H|` exceeds G. Gradients are finite everywhere, including
    `|L| = G` and `|H| = G` (where √(G² − L²) has an infinite derivative, the one-sided value 0
    is returned).
    """
    L, G, H, l, g, h = _checked(L, G, H, l, g, h, names=("L", "G", "H", "l", "g", "h"))
    cJ, sJ = _cos_sin(L, G)
    cI, sI = _cos_sin(H, G)
    rho = G * sJ
    M = jnp.stack([rho * jnp.sin(l), rho * jnp.cos(l), L], axis=-1)
    P = (
        _rz(jnp.cos(h), jnp.sin(h))
        @ _rx(cI, sI)
        @ _rz(jnp.cos(g), jnp.sin(g))
        @ _rx(cJ, sJ)
        @ _rz(jnp.cos(l), jnp.sin(l))
    )
    return M, P


def to_momentum_attitude(
    av: AndoyerVariables | Annotated[RealLike, "*#batch 6"],
) -> tuple[Vec3, Mat33]:
    """`from_andoyer` for an `AndoyerVariables` or a stacked array `(..., 6)` in the order
    `(L, G, H, l, g, h)`."""
    if not isinstance(av, AndoyerVariables):
        av = AndoyerVariables.from_array(av)
    return from_andoyer(*av)


def to_andoyer(M_body: Vec3Like, P: Mat33Like) -> AndoyerVariables:
    """Andoyer–Deprit variables of a body angular momentum `M_body (..., 3)` and attitude
    `P (..., 3, 3)` (body → space); inverse of `from_andoyer` (Borisov–Mamaev (001); THEORY §5).

    With m = M/G, m_s = P m (the direction of M in space), γ = third row of P:

        L = M3,  G = |M|,  H = (P M)_3 = M·γ,
        l = atan2(M1, M2),  h = atan2(m_s1, −m_s2),
        g = atan2(m_s·(n_s × P n_b), n_s·P n_b),

    where n_s = (cos h, sin h, 0) is the space node line of Σ ⊥ M (the unit vector along OZ × M)
    and n_b = (cos l, −sin l, 0) the body one (along M × Oz): g is the angle from n_s to P n_b about
    M. Equivalently `g = atan2(G (γ1 M2 − γ2 M1), H L − G² γ3)`, both arguments carrying the factor
    G² sin I sin J; the source's `g = arcsin((M2γ1 − M1γ2)/√(M1² + M2²))` misses the factor
    1/sin I and loses the quadrant. Angles are in (−π, π].

    Singular sets (the map is discontinuous there): M ∥ body Oz (`|L| = G`, J ∈ {0, π}) leaves l
    undefined, M ∥ space OZ (`|H| = G`, I ∈ {0, π}) leaves h undefined. When the corresponding
    in-plane component is at the rounding level (≤ eps · G) the undefined angle is set to 0 and `g`
    takes the whole rotation about the common axis, so `from_andoyer` still reproduces `M_body` and
    `P` (to rounding) and values and gradients stay finite. Near these sets the angles l, h and g
    have derivatives of order 1/sin J or 1/sin I, as they must.

    On a pole, where the in-plane component is ≤ eps G, `|L|` (or `|H|`) is returned as exactly
    G. A zero or non-finite `M_body` (no angular momentum) and a non-finite `P` or one with
    det P ≤ 0 raise an error naming the argument, also under jit.
    Arguments broadcast over leading batch dimensions.
    """
    M = vector(M_body, 3, "M_body")
    M = _validation.validate_all(M, [_validation.finite_check("M_body", 1), _zero_momentum])
    P = _validation.check_matrix(matrix(P, "P"), "P")
    dtype = jnp.result_type(M, P)
    M, P = M.astype(dtype), P.astype(dtype)
    batch = jnp.broadcast_shapes(M.shape[:-1], P.shape[:-2])
    M = jnp.broadcast_to(M, (*batch, 3))
    P = jnp.broadcast_to(P, (*batch, 3, 3))

    G = jnp.sqrt(jnp.sum(M * M, axis=-1))
    m = M / G[..., None]
    ms = jnp.einsum("...ij,...j->...i", P, m)

    cl, sl, pole_b = _direction(m[..., 1], m[..., 0])
    ch, sh, pole_s = _direction(-ms[..., 1], ms[..., 0])
    # On a pole |L| (or |H|) equals G to within eps² G; make it exact, so that sin J (sin I)
    # = √((G − L)(G + L))/G comes back 0 and not ~√eps from a rounded last bit.
    L = jnp.where(pole_b, jnp.sign(M[..., 2]) * G, M[..., 2])
    H = jnp.where(pole_s, jnp.sign(ms[..., 2]) * G, G * ms[..., 2])
    zero = jnp.zeros_like(cl)
    n_b = jnp.stack([cl, -sl, zero], axis=-1)
    n_s = jnp.stack([ch, sh, zero], axis=-1)
    Pn_b = jnp.einsum("...ij,...j->...i", P, n_b)
    # (sin g, cos g) have unit length up to rounding: n_s and P n_b are unit vectors ⊥ m_s.
    cg = jnp.sum(n_s * Pn_b, axis=-1)
    sg = jnp.sum(ms * jnp.cross(n_s, Pn_b), axis=-1)

    return AndoyerVariables(
        L=L,
        G=G,
        H=H,
        l=jnp.arctan2(sl, cl),
        g=jnp.arctan2(sg, cg),
        h=jnp.arctan2(sh, ch),
    )


def gamma(L: ScalarLike, G: ScalarLike, H: ScalarLike, l: ScalarLike, g: ScalarLike) -> Vec3:
    """γ, the space axis OZ in body components (third row of P; Poisson variable), by the source's
    formulas (Borisov–Mamaev (001); THEORY §5), `sin τ = L/G`, `sin ζ = H/G`:

        γ1 = (sin ζ cos τ + sin τ cos ζ cos g) sin l + cos ζ sin g cos l,
        γ2 = (sin ζ cos τ + sin τ cos ζ cos g) cos l − cos ζ sin g sin l,
        γ3 = sin ζ sin τ − cos τ cos ζ cos g.

    (τ = π/2 − J, ζ = π/2 − I.) Independent of h. `M_body · γ = H`.
    """
    L, G, H, l, g = _checked(L, G, H, l, g, names=("L", "G", "H", "l", "g"))
    s_tau, c_tau = _cos_sin(L, G)
    s_zeta, c_zeta = _cos_sin(H, G)
    a = s_zeta * c_tau + s_tau * c_zeta * jnp.cos(g)
    b = c_zeta * jnp.sin(g)
    sl, cl = jnp.sin(l), jnp.cos(l)
    return jnp.stack(
        [a * sl + b * cl, a * cl - b * sl, s_zeta * s_tau - c_tau * c_zeta * jnp.cos(g)], axis=-1
    )


def free_body_hamiltonian(inertia: Vec3Like, L: ScalarLike, G: ScalarLike, l: ScalarLike) -> Scalar:
    """Kinetic energy of the free body in Andoyer–Deprit variables (principal moments
    `inertia = (I1, I2, I3)`, shape `(..., 3)`):

        T = ½ (G² − L²)(sin² l / I1 + cos² l / I2) + L² / (2 I3) = ½ M·I⁻¹M.

    `G` is an integral (Euler case); `l, L` carry the whole reduced motion, `g` evolves by
    quadrature and `h, H` are constant.
    """
    inertia = vector(inertia, 3, "inertia")
    L, G, l = _broadcast(L, G, l, names=("L", "G", "l"))
    I1, I2, I3 = inertia[..., 0], inertia[..., 1], inertia[..., 2]
    sl, cl = jnp.sin(l), jnp.cos(l)
    return 0.5 * (G * G - L * L) * (sl * sl / I1 + cl * cl / I2) + L * L / (2 * I3)
