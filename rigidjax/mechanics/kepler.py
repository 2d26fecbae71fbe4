"""Motion in a central field, the Kepler problem and Rutherford scattering (Zegrya–Parshin 004,
"Движение в центральном поле", "Задача Кеплера. Резерфордское рассеяние"; THEORY §7).

Conventions
-----------
* The potential is `U(r) = −α/r` with a SIGNED `alpha`: `α > 0` is attraction (gravity,
  `α = G m1 m2`), `α < 0` repulsion (like charges, the book's `U = +|α|/r`).
* `m` is the mass of the moving point; for two bodies it is the reduced mass
  `m = m1 m2/(m1 + m2)` and `r = r1 − r2` (004, two-body problem).
* Angular momentum `M = m r × v` (about the centre of the field).
* Laplace–Runge–Lenz vector in the book's normalisation (004 (10.10)):
  `A = v × M − α r/r`. It is conserved because `m v̇ = −α r/r³`, has length `|A| = |α| ε` and
  points from the centre to the pericentre (closest approach) for either sign of α. The other
  common normalisation `p × M − m α r/r` is `m A`.
* Orbit parameter and eccentricity (004 (10.6)): `p = M²/(m|α|)`, `ε = √(1 + 2EM²/(mα²))`;
  the orbit in polar angle φ measured from A is `r = p/(1 + ε cos φ)` (attraction, (10.23)) and
  `r = p/(ε cos φ − 1)` (repulsion, (10.51)).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Unpack

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import (
    as_float,
    check_positive,
    check_times,
    initial_vector,
    is_concrete,
    validate,
    vector,
    zero_vector,
)
from .._custom_types import RealLike, Scalar, Vec3
from .._integrate import SolveKwargs, SolveOptions, solve_saved
from .._trajectory import AbstractTrajectory

if TYPE_CHECKING:
    Potential = Callable[[Array], Array]
else:  # `simulate_central` checks it itself (a TypeError that names `potential`)
    Potential = object


__all__ = [
    "CentralTrajectory",
    "OrbitalElements",
    "TwoBodyTrajectory",
    "elements",
    "energy",
    "lrl_vector",
    "orbit_radius",
    "reduced_mass",
    "rutherford_angle",
    "rutherford_cross_section",
    "rutherford_impact_parameter",
    "simulate_central",
    "simulate_two_body",
]


def _check_alpha(alpha: Array) -> Array:
    return validate(
        alpha,
        lambda xp, v: ~((v != 0) & xp.isfinite(v)),
        "alpha must be non-zero and finite",
        lambda v: f", got {v}",
        hint=" (alpha > 0 attraction, alpha < 0 repulsion)",
    )


def reduced_mass(m1: RealLike, m2: RealLike) -> Scalar:
    """`m = m1 m2/(m1 + m2)`: the two-body problem reduces to one point of this mass moving in the
    central field U(|r1 − r2|) (Zegrya–Parshin 004)."""
    m1 = check_positive(as_float(m1, "m1"), "m1")
    m2 = check_positive(as_float(m2, "m2"), "m2")
    return m1 * m2 / (m1 + m2)


class OrbitalElements(eqx.Module):
    """Integrals and elements of the orbit in `U = −α/r` (α signed; see the module docstring).

    Bound orbits (`E < 0`, only for α > 0): ellipse with `a = α/(2|E|)`, `b = M/√(2m|E|)`,
    period `T = πα √(m/(2|E|³))` (004 (10.35), (10.39)), so `T²/a³ = 4π² m/α` (Kepler's third
    law), `r_min,max = p/(1 ± ε)`. Unbound orbits: `period = r_max = inf`; `a`, `b` are then the
    semi-axes of the hyperbola, and `r_min = p/(1 + ε)` (attraction) or `p/(ε − 1)` (repulsion).
    """

    energy: Scalar
    angular_momentum: Vec3
    lrl: Vec3
    p: Scalar
    eccentricity: Scalar
    alpha: Scalar
    mass: Scalar

    @property
    def M(self) -> Scalar:
        """|M|."""
        return jnp.linalg.norm(self.angular_momentum, axis=-1)

    @property
    def bound(self) -> Array:
        return self.energy < 0

    @property
    def semi_major_axis(self) -> Scalar:
        """`a = |α|/(2|E|)` (the real semi-axis of the hyperbola when E > 0)."""
        return jnp.abs(self.alpha) / (2 * jnp.abs(self.energy))

    @property
    def semi_minor_axis(self) -> Scalar:
        """`b = M/√(2m|E|)` (the imaginary semi-axis of the hyperbola when E > 0)."""
        return self.M / jnp.sqrt(2 * self.mass * jnp.abs(self.energy))

    @property
    def period(self) -> Scalar:
        """`T = π|α| √(m/(2|E|³))` for E < 0, inf otherwise (004 (10.39))."""
        E = jnp.abs(self.energy)
        T = jnp.pi * jnp.abs(self.alpha) * jnp.sqrt(self.mass / (2 * E**3))
        return jnp.where(self.bound, T, jnp.inf)

    @property
    def mean_motion(self) -> Scalar:
        """`n = 2π/T` (0 for unbound orbits)."""
        return 2 * jnp.pi / self.period

    @property
    def r_min(self) -> Scalar:
        """Pericentre distance: `p/(1 + ε)` (α > 0), `p/(ε − 1)` (α < 0)."""
        return self.p / (jnp.sign(self.alpha) * 1.0 + self.eccentricity)

    @property
    def r_max(self) -> Scalar:
        """Apocentre distance `p/(1 − ε)` for bound orbits, inf otherwise."""
        return jnp.where(self.bound, self.p / (1 - self.eccentricity), jnp.inf)

    @property
    def deflection_angle(self) -> Scalar:
        """Angle χ between the incoming and outgoing asymptotes of an unbound orbit:
        `sin(χ/2) = 1/ε`, i.e. `cot(χ/2) = √(ε² − 1)` (004 (10.53)–(10.55)); NaN when bound."""
        e = self.eccentricity
        return jnp.where(e > 1, 2 * jnp.arcsin(1 / jnp.where(e > 1, e, 2.0)), jnp.nan)

    def radius(self, phi: RealLike) -> Scalar:
        """`r(φ)`, φ the polar angle from the LRL vector (true anomaly); see `orbit_radius`."""
        return orbit_radius(phi, self.p, self.eccentricity, repulsive=None, alpha=self.alpha)

    def true_anomaly(self, r: RealLike) -> Scalar:
        """Polar angle φ of the position `r` measured from the LRL vector A in the sense of M
        (`φ ∈ (−π, π]`; undefined for a circular orbit, where A = 0)."""
        r = vector(r, 3, "r")
        A, Mv = self.lrl, self.angular_momentum
        y = jnp.sum(jnp.cross(A, r) * Mv, axis=-1) / self.M
        return jnp.arctan2(y, jnp.sum(A * r, axis=-1))


def energy(r: RealLike, v: RealLike, mass: RealLike, alpha: RealLike) -> Scalar:
    """`E = m v²/2 − α/r`."""
    r, v = vector(r, 3, "r"), vector(v, 3, "v")
    m, alpha = as_float(mass, "mass"), as_float(alpha, "alpha")
    return 0.5 * m * jnp.sum(v * v, axis=-1) - alpha / jnp.linalg.norm(r, axis=-1)


def lrl_vector(r: RealLike, v: RealLike, mass: RealLike, alpha: RealLike) -> Vec3:
    """Laplace–Runge–Lenz vector `A = v × M − α r/r`, `M = m r × v` (004 (10.10));
    `|A| = |α| ε`, pointing to the pericentre. Multiply by m for the `p × M − mα r̂` form."""
    r, v = vector(r, 3, "r"), vector(v, 3, "v")
    m, alpha = as_float(mass, "mass"), as_float(alpha, "alpha")
    M = m[..., None] * jnp.cross(r, v)
    return jnp.cross(v, M) - alpha[..., None] * r / jnp.linalg.norm(r, axis=-1, keepdims=True)


def elements(
    r: RealLike, v: RealLike, mass: RealLike = 1.0, alpha: RealLike = 1.0
) -> OrbitalElements:
    """Orbital elements of the state `(r, v)` (shapes `(..., 3)`) of a point of mass `mass` in
    `U = −α/r` (α signed: > 0 attraction, < 0 repulsion). Formulas of Zegrya–Parshin 004 §10:
    `E = m v²/2 − α/r`, `M = m r × v`, `p = M²/(m|α|)`, `ε = √(1 + 2EM²/(mα²))`,
    `A = v × M − α r/r`.
    """
    r, v = vector(r, 3, "r"), vector(v, 3, "v")
    dtype = jnp.result_type(r.dtype, v.dtype)
    m = check_positive(as_float(mass, "mass").astype(dtype), "mass")
    alpha = _check_alpha(as_float(alpha, "alpha").astype(dtype))
    if is_concrete(r):  # traced: NaN elements
        validate(
            r,
            lambda xp, v: ~(xp.linalg.norm(v, axis=-1) > 0),
            "r must be non-zero (the point is at the centre of the field)",
        )
    E = energy(r, v, m, alpha)
    Mv = m[..., None] * jnp.cross(r, v)
    M2 = jnp.sum(Mv * Mv, axis=-1)
    p = M2 / (m * jnp.abs(alpha))
    e2 = 1 + 2 * E * M2 / (m * alpha**2)
    eps = jnp.sqrt(jnp.maximum(e2, 0))  # rounding can make a circular orbit's e² ≈ −1e-16
    A = lrl_vector(r, v, m, alpha)
    shape = E.shape
    return OrbitalElements(
        energy=E,
        angular_momentum=Mv,
        lrl=A,
        p=p,
        eccentricity=eps,
        alpha=jnp.broadcast_to(alpha, shape),
        mass=jnp.broadcast_to(m, shape),
    )


def orbit_radius(
    phi: RealLike,
    p: RealLike,
    eccentricity: RealLike,
    repulsive: bool | None = False,
    *,
    alpha: RealLike | None = None,
) -> Scalar:
    """Conic in polar form about the centre, φ measured from the pericentre:
    `r = p/(1 + ε cos φ)` (attraction, 004 (10.23)) or `r = p/(ε cos φ − 1)` (repulsion, (10.51)).
    With `repulsive=None` the branch is taken from the sign of `alpha`. Angles outside the
    asymptotes of a hyperbola give a non-positive denominator and return NaN."""
    phi = as_float(phi, "phi")
    p, e = as_float(p, "p"), as_float(eccentricity, "eccentricity")
    if repulsive is None:
        if alpha is None:
            raise ValueError("orbit_radius: give repulsive=True/False or alpha")
        s = jnp.sign(as_float(alpha, "alpha"))
    else:
        s = -1.0 if repulsive else 1.0
    den = s + e * jnp.cos(phi)
    return jnp.where(den > 0, p / jnp.where(den > 0, den, 1.0), jnp.nan)


def rutherford_impact_parameter(
    chi: RealLike, mass: RealLike, v_inf: RealLike, alpha: RealLike
) -> Scalar:
    """Rutherford's formula `ρ = (|α|/(m v∞²)) cot(χ/2)` (004 (10.57)): the impact parameter that
    gives the deflection χ ∈ (0, π); the same for attraction and repulsion."""
    chi = as_float(chi, "chi")
    k = jnp.abs(as_float(alpha, "alpha")) / (as_float(mass, "mass") * as_float(v_inf, "v_inf") ** 2)
    return k / jnp.tan(chi / 2)


def rutherford_angle(rho: RealLike, mass: RealLike, v_inf: RealLike, alpha: RealLike) -> Scalar:
    """Deflection angle from the impact parameter, the inverse of Rutherford's formula:
    `χ = 2 arctan(|α|/(m v∞² ρ))` (χ → π as ρ → 0, χ → 0 as ρ → ∞)."""
    rho = as_float(rho, "rho")
    k = jnp.abs(as_float(alpha, "alpha")) / (as_float(mass, "mass") * as_float(v_inf, "v_inf") ** 2)
    return 2 * jnp.arctan2(k, rho)


def rutherford_cross_section(
    chi: RealLike, mass: RealLike, v_inf: RealLike, alpha: RealLike
) -> Scalar:
    """Differential cross-section `dσ/do = (α/(2 m v∞²))² / sin⁴(χ/2)`, which follows from
    `dσ = 2πρ |dρ/dχ| dχ` and `do = 2π sin χ dχ` with Rutherford's ρ(χ)."""
    chi = as_float(chi, "chi")
    k = as_float(alpha, "alpha") / (2 * as_float(mass, "mass") * as_float(v_inf, "v_inf") ** 2)
    return k**2 / jnp.sin(chi / 2) ** 4


# ---------------------------------------------------------------------------------------------
# Integration of m r̈ = −∂U/∂r
# ---------------------------------------------------------------------------------------------


def _force(r: Array, alpha: Array | None, potential: Potential | None) -> Array:
    """`−∂U/∂r` for `U = −α/r` (closed form) or a user `U(|r|)` (by autodiff)."""
    rn = jnp.sqrt(jnp.sum(r * r, axis=-1, keepdims=True))
    if potential is None:
        assert alpha is not None  # `_field_args` gives exactly one of the two
        return -alpha * r / rn**3
    dU = jax.grad(lambda s: jnp.asarray(potential(s), r.dtype).reshape(()))(rn[..., 0])
    return -dU * r / rn


class _CentralField(eqx.Module):
    potential: Potential | None = eqx.field(static=True)

    def __call__(self, t, y, args):
        r, v = y
        m, alpha = args
        return v, _force(r, alpha, self.potential) / m


class _TwoBodyField(eqx.Module):
    potential: Potential | None = eqx.field(static=True)

    def __call__(self, t, y, args):
        r1, v1, r2, v2 = y
        m1, m2, alpha = args
        F1 = _force(r1 - r2, alpha, self.potential)  # force on 1 from 2; Newton's third law
        return v1, F1 / m1, v2, -F1 / m2


class CentralTrajectory(AbstractTrajectory):
    """Solution of `simulate_central`: times `ts (T,)`, positions `r (T, 3)` and velocities
    `v (T, 3)` relative to the centre of the field."""

    r: Float[Array, "T 3"]
    v: Float[Array, "T 3"]


class TwoBodyTrajectory(AbstractTrajectory):
    """Solution of `simulate_two_body`: `r1, v1, r2, v2 (T, 3)` in the inertial frame."""

    r1: Float[Array, "T 3"]
    v1: Float[Array, "T 3"]
    r2: Float[Array, "T 3"]
    v2: Float[Array, "T 3"]

    @property
    def relative(self) -> tuple[Array, Array]:
        """`(r1 − r2, v1 − v2)`: the coordinate of the reduced problem."""
        return self.r1 - self.r2, self.v1 - self.v2

    def centre_of_mass(self, m1: RealLike, m2: RealLike) -> tuple[Array, Array]:
        """`(R, V)` of the centre of mass: `(m1 r1 + m2 r2)/(m1 + m2)`."""
        m1, m2 = as_float(m1, "m1"), as_float(m2, "m2")
        M = m1 + m2
        return (m1 * self.r1 + m2 * self.r2) / M, (m1 * self.v1 + m2 * self.v2) / M


def _field_args(alpha, potential, dtype):
    if (alpha is None) == (potential is None):
        raise ValueError("give exactly one of alpha (for U = −α/r) or potential (a callable U(r))")
    if potential is not None:
        if not callable(potential):
            raise TypeError(f"potential must be a callable U(r) of the distance, got {potential!r}")
        out = jax.eval_shape(potential, jax.ShapeDtypeStruct((), dtype))
        if jnp.shape(out) != ():
            raise ValueError(
                "potential must return a scalar U(r) of the scalar distance r, got shape "
                f"{jnp.shape(out)}"
            )
        return None
    alpha = as_float(alpha, "alpha").astype(dtype)
    if alpha.shape != ():
        raise ValueError(f"alpha must be a scalar (vmap for batches), got shape {alpha.shape}")
    return _check_alpha(alpha)


def simulate_central(
    r0: RealLike,
    v0: RealLike,
    ts: RealLike,
    *,
    mass: RealLike = 1.0,
    alpha: RealLike | None = None,
    potential: Potential | None = None,
    options: SolveOptions | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> CentralTrajectory:
    """Integrate `m r̈ = −∂U/∂r` for a point in a central field (Zegrya–Parshin 004), from
    `(r0, v0)` at `ts[0]`, saving at `ts`.

    Exactly one of `alpha` (`U = −α/r`, α signed: > 0 attraction, < 0 repulsion; force
    `−α r/r³` in closed form) or `potential` (a callable `U(r)` of the scalar distance, force
    `−U'(r) r/r` by autodiff; keep it the same Python object between calls to reuse the
    compilation) is required. `mass` and `alpha` are traced (no recompilation when they change);
    `jax.vmap` over initial states, masses or α for batches. Defaults: Tsit5 with unrolled stages
    (`ExplicitRK`) and a PID controller at `rtol = atol = 1e-12` in float64 (1e-6 in float32).
    """
    options = SolveOptions.of(options, solve_kwargs)
    ts = check_times(as_float(ts, "ts"))
    dtype = ts.dtype
    r0, v0 = initial_vector(r0, 3, "r0", dtype), initial_vector(v0, 3, "v0", dtype)
    r0 = validate(
        r0,
        zero_vector,
        "r0 must be non-zero",
        lambda r: f", got {r}",
        hint=": the central force is singular at the centre r = 0; start the point away from it",
    )
    m = check_positive(as_float(mass, "mass").astype(dtype), "mass")
    if m.shape != ():
        raise ValueError(f"mass must be a scalar (vmap for batches), got shape {m.shape}")
    alpha = _field_args(alpha, potential, dtype)
    (r, v), stats, result = solve_saved(
        diffrax.ODETerm(_CentralField(potential)),
        ts,
        (r0, v0),
        options,
        args=(m, alpha),
        tight=True,
    )
    return CentralTrajectory(ts=ts, r=r, v=v, stats=stats, result=result)


def simulate_two_body(
    r1: RealLike,
    v1: RealLike,
    r2: RealLike,
    v2: RealLike,
    ts: RealLike,
    *,
    m1: RealLike,
    m2: RealLike,
    alpha: RealLike | None = None,
    potential: Potential | None = None,
    options: SolveOptions | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> TwoBodyTrajectory:
    """Two point masses interacting through `U(|r1 − r2|)` (`−α/r` or `potential`), both
    integrated in the inertial frame: `m1 r̈1 = −∂U/∂r1`, `m2 r̈2 = −∂U/∂r2`. The relative
    coordinate `r1 − r2` then moves like one point of the reduced mass `m1 m2/(m1 + m2)` in the
    central field (004), and the centre of mass uniformly. Options as in `simulate_central`."""
    options = SolveOptions.of(options, solve_kwargs)
    ts = check_times(as_float(ts, "ts"))
    dtype = ts.dtype
    y0 = tuple(
        initial_vector(x, 3, n, dtype)
        for x, n in zip((r1, v1, r2, v2), ("r1", "v1", "r2", "v2"), strict=True)
    )
    m1 = check_positive(as_float(m1, "m1").astype(dtype), "m1")
    m2 = check_positive(as_float(m2, "m2").astype(dtype), "m2")
    alpha = _field_args(alpha, potential, dtype)
    ys, stats, result = solve_saved(
        diffrax.ODETerm(_TwoBodyField(potential)),
        ts,
        y0,
        options,
        args=(m1, m2, alpha),
        tight=True,
    )
    return TwoBodyTrajectory(
        ts=ts, r1=ys[0], v1=ys[1], r2=ys[2], v2=ys[3], stats=stats, result=result
    )
