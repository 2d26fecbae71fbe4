"""A rigid satellite on a Kepler orbit under the gravity-gradient torque; libration about the
local-vertical/local-horizontal (LVLH) equilibrium.

Model (orbit and attitude integrated together with `rigidjax.sixdof.simulate_6dof`)
-----------------------------------------------------------------------------------
* The centre of mass moves in the point-mass field of the Earth, `m R̈ = −μ m R/R³` (the Kepler
  problem of Zegrya–Parshin 004 with α = μ m; the O(size²/R²) gravity-gradient force on the orbit
  is neglected, so the orbit is exactly Keplerian).
* The torque about the centre of mass is the gravity-gradient torque, to leading order in
  size/R (expand U = −Σ μ m_i/|R + ρ_i| to second order; K = Σ ρ_i × f_i):

      K = (3μ/R³) n × (I n)       (body axes),

  `n` the unit vector from the Earth's centre to the satellite in body axes, `I` the inertia
  tensor about the centre of mass. It is quadratic in n, so the sign of n does not matter.

LVLH frame and angles
---------------------
Right-handed orbital frame `(x, y, z)`: `z` = nadir (−R/R), `y` = negative orbit normal
(−h/|h|, h = R × V), `x = y × z` (along-track; the velocity direction on a circular orbit). It
rotates with angular velocity `ω_o = h/R²` (space), i.e. `(0, −n, 0)` in its own axes for a
circular orbit of mean motion `n = √(μ/a³)`. The body attitude relative to LVLH is
`C = Lᵀ P = exp(α × E)`; its rotation vector `α = (φ, θ, ψ)` gives roll φ (about x), pitch θ
(about y, the orbit normal) and yaw ψ (about z) to first order (pitch exactly for planar motion).

Linearised libration about `C = E` for a circular orbit, principal axes along LVLH with moments
`I_x, I_y, I_z` (derivation: `Ω = ω_o + ω_o × α + α̇` to first order, `n_body = (θ, −φ, −1)`,
then Euler's equations):

    pitch:  I_y θ̈ + 3n²(I_x − I_z) θ = 0            ⇒  ω_pitch² = 3n² (I_x − I_z)/I_y
    roll:   I_x φ̈ − n(I_x − I_y + I_z) ψ̇ + 4n²(I_y − I_z) φ = 0
    yaw:    I_z ψ̈ + n(I_x − I_y + I_z) φ̇ + n²(I_y − I_x) ψ = 0

so roll/yaw frequencies solve `ω⁴ − ω² n² (1 + 3k₁ + k₁k₃) + 4k₁k₃ n⁴ = 0` with
`k₁ = (I_y − I_z)/I_x`, `k₃ = (I_y − I_x)/I_z` (agrees with the standard result, e.g. Wie,
*Space Vehicle Dynamics and Control*). Pitch is stable for `I_x > I_z`; all three for
`I_y > I_x > I_z` (the Lagrange region).
"""

from __future__ import annotations

from typing import Unpack

import diffrax
import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import (
    as_float,
    check_finite,
    check_positive,
    check_times,
    is_concrete,
    validate,
    vector,
    zero_vector,
)
from .._custom_types import RealLike, Vec3
from .._integrate import SolveKwargs, SolveOptions, solve_saved
from ..rotations import quat, so3
from ..solvers.exact_free_body import ExactFreeBody, RigidBodyField
from ..solvers.splitting import LiePoissonSplitting
from ._paths import fixed_steps
from .body import RigidBody
from .inertia import diagonal
from .sixdof import SixDofTrajectory, Wrench, initial_state, simulate_6dof

__all__ = [
    "circular_orbit",
    "gravity_gradient_torque",
    "lvlh_angles",
    "lvlh_matrix",
    "lvlh_rate",
    "lvlh_state",
    "mean_motion",
    "pitch_frequency",
    "roll_yaw_frequencies",
    "simulate_satellite",
]


def mean_motion(mu: RealLike, a: RealLike) -> Array:
    """`n = √(μ/a³)` (Kepler's third law `T²/a³ = 4π²/μ` of 004 with α/m = μ)."""
    mu = check_positive(as_float(mu, "mu"), "mu")
    return jnp.sqrt(mu / check_positive(as_float(a, "a"), "a") ** 3)


def circular_orbit(mu: RealLike, radius: RealLike) -> tuple[Vec3, Vec3]:
    """`(R0, V0)` of a circular orbit in the space XY plane: `R0 = (r, 0, 0)`,
    `V0 = (0, √(μ/r), 0)` (orbit normal +Z)."""
    mu = check_positive(as_float(mu, "mu"), "mu")
    r = check_positive(as_float(radius, "radius"), "radius")
    z = jnp.zeros_like(r)
    return jnp.stack([r, z, z], -1), jnp.stack([z, jnp.sqrt(mu / r), z], -1)


def gravity_gradient_torque(mu: RealLike, R: RealLike, q: RealLike, inertia: RealLike) -> Vec3:
    """`K = (3μ/R³) n × (I n)` in body axes, `n = Pᵀ R/R` the Earth→satellite direction in body
    axes, `R` the satellite position in space axes, `q` the attitude (body → space) and `inertia`
    the tensor `(3, 3)` (or principal moments `(3,)` along the body axes) about the COM."""
    R = validate(
        check_finite(vector(R, 3, "R"), "R"),
        zero_vector,
        "R must be a non-zero position (the gradient falls off as 1/|R|³)",
    )
    return _gravity_gradient(mu, R, q, inertia)


def _gravity_gradient(mu: RealLike, R: Array, q: RealLike, inertia: RealLike) -> Vec3:
    """`gravity_gradient_torque` without the check of `R` (the models' fields: the orbit's
    `R` is non-zero by construction, and a check there would run at every step)."""
    I = as_float(inertia, "inertia")
    if I.shape[-1:] == (3,) and I.shape[-2:] != (3, 3):
        I = I[..., :, None] * jnp.eye(3, dtype=I.dtype)
    r2 = jnp.sum(R * R, axis=-1, keepdims=True)
    n = quat.rotate(quat.conj(vector(q, 4, "q")), R) * (1 / jnp.sqrt(r2))  # one division
    In = jnp.einsum("...ij,...j->...i", I, n)
    return 3 * as_float(mu, "mu")[..., None] / r2**1.5 * jnp.cross(n, In)


def lvlh_matrix(R: RealLike, V: RealLike) -> Float[Array, "*batch 3 3"]:
    """LVLH frame as a rotation `L` (columns: along-track x, negative orbit normal y, nadir z, in
    space axes), so `L` maps LVLH → space components."""
    R, V = vector(R, 3, "R"), vector(V, 3, "V")
    h = jnp.cross(R, V)
    # |R × V| against |R||V|: no frame for R = 0, V = 0 or V along R (a radial or no orbit)
    h = validate(
        jnp.stack(
            jnp.broadcast_arrays(jnp.sum(h * h, -1), jnp.sum(R * R, -1) * jnp.sum(V * V, -1))
        ),
        lambda xp, s: ~(s[0] > (64 * xp.finfo(s.dtype).eps) ** 2 * s[1]),
        "the LVLH frame needs R and V finite, non-zero and not parallel (an orbit with an "
        "angular momentum R × V ≠ 0)",
        on=h,
    )
    z = -R / jnp.linalg.norm(R, axis=-1, keepdims=True)
    y = -h / jnp.linalg.norm(h, axis=-1, keepdims=True)
    x = jnp.cross(y, z)
    return jnp.stack([x, y, z], axis=-1)


def lvlh_rate(R: RealLike, V: RealLike) -> Vec3:
    """Angular velocity of the LVLH frame in space axes on a Kepler orbit: `h/R²`, h = R × V (the
    frame turns about the fixed orbit normal with the polar-angle rate φ̇ = |h|/R²)."""
    R, V = vector(R, 3, "R"), vector(V, 3, "V")
    return jnp.cross(R, V) / jnp.sum(R * R, axis=-1, keepdims=True)


def lvlh_state(
    R: RealLike,
    V: RealLike,
    rotvec: RealLike | None = None,
    omega_rel: RealLike | None = None,
) -> tuple[Float[Array, "*batch 4"], Vec3]:
    """Initial attitude `(q, Ω)` of a body whose axes are turned by the rotation vector `rotvec`
    (roll, pitch, yaw; LVLH axes) from LVLH: `P = L exp(rotvec × E)`, and whose body angular
    velocity is that of LVLH plus `omega_rel` (body axes): `Ω = Cᵀ Lᵀ ω_o + Ω_rel`.
    With both None it is the LVLH equilibrium of a body with principal axes along LVLH."""
    L = lvlh_matrix(R, V)
    dtype = L.dtype
    a = jnp.zeros(3, dtype) if rotvec is None else vector(rotvec, 3, "rotvec").astype(dtype)
    C = so3.exp(a)
    P = L @ C
    w_o = jnp.einsum("...ji,...j->...i", P, lvlh_rate(R, V))  # Pᵀ ω_o
    if omega_rel is not None:
        w_o = w_o + vector(omega_rel, 3, "omega_rel").astype(dtype)
    return quat.from_matrix(P), w_o


def lvlh_angles(R: RealLike, V: RealLike, q: RealLike) -> Vec3:
    """Rotation vector `(φ, θ, ψ)` of the body relative to LVLH, `C = Lᵀ P(q)`: roll, pitch,
    yaw to first order (the pitch angle exactly for motion in the orbit plane)."""
    L = lvlh_matrix(R, V)
    return so3.log(jnp.swapaxes(L, -1, -2) @ quat.to_matrix(q))


def _moments(inertia) -> Array:
    """`(I_x, I_y, I_z)` along the body axes from a RigidBody, moments (3,) or a tensor (3, 3)
    that must be diagonal (principal axes along LVLH)."""
    I = inertia.inertia if isinstance(inertia, RigidBody) else as_float(inertia, "inertia")
    if I.shape == (3,):
        return I
    if I.shape != (3, 3):
        raise ValueError(f"inertia must be moments (3,) or a tensor (3, 3), got {I.shape}")
    if is_concrete(I):  # a traced tensor is taken as diagonal

        def off(xp, I):
            return xp.max(xp.abs(I - I * xp.eye(3)))

        validate(
            I,
            lambda xp, I: off(xp, I) > 1e-12 * xp.max(xp.abs(xp.diagonal(I))),
            "the libration formulas need principal axes along LVLH (x along-track, y orbit "
            "normal, z nadir): the inertia tensor must be diagonal",
            lambda I: f", off-diagonal {off(np, I):.3g}",
        )
    return diagonal(I)


def pitch_frequency(inertia: RealLike | RigidBody, n: RealLike) -> Array:
    """Small pitch libration frequency on a circular orbit of mean motion n:
    `ω_pitch = n √(3 (I_x − I_z)/I_y)` (x along-track, y orbit normal, z nadir). Raises for a
    concrete inertia with `I_x ≤ I_z` (the pitch equilibrium is then unstable)."""
    I = _moments(inertia)
    if is_concrete(I):  # traced: NaN
        validate(
            I,
            lambda xp, I: ~(I[0] > I[2]),
            "pitch equilibrium is unstable for I_x ≤ I_z",
            lambda I: f" (I_x = {I[0]}, I_z = {I[2]})",
            hint=": no libration frequency",
        )
    Ix, Iy, Iz = I[0], I[1], I[2]
    return as_float(n, "n") * jnp.sqrt(3 * (Ix - Iz) / Iy)


def roll_yaw_frequencies(inertia: RealLike | RigidBody, n: RealLike) -> tuple[Array, Array]:
    """The two coupled roll/yaw libration frequencies (ascending), the roots of
    `ω⁴ − ω² n² (1 + 3k₁ + k₁k₃) + 4k₁k₃ n⁴ = 0`, `k₁ = (I_y − I_z)/I_x`, `k₃ = (I_y − I_x)/I_z`.
    NaN where the roll/yaw motion is unstable (complex roots)."""
    Ix, Iy, Iz = _moments(inertia)
    n = as_float(n, "n")
    k1, k3 = (Iy - Iz) / Ix, (Iy - Ix) / Iz
    b = 1 + 3 * k1 + k1 * k3
    c = 4 * k1 * k3
    disc = b * b - 4 * c
    ok = (disc >= 0) & (c > 0) & (b > 0)
    sd = jnp.sqrt(jnp.where(ok, disc, 0.0))
    lo = jnp.where(ok, jnp.sqrt((b - sd) / 2), jnp.nan)
    hi = jnp.where(ok, jnp.sqrt((b + sd) / 2), jnp.nan)
    return n * lo, n * hi


class _SatelliteLoads(eqx.Module):
    """Point-mass gravity on the COM plus (optionally) the gravity-gradient torque."""

    mu: Array
    mass: Array
    inertia: Array
    gravity_gradient: bool = eqx.field(static=True, default=True)

    def __call__(self, t, state) -> Wrench:
        R = state.R
        r2 = jnp.sum(R * R)
        F = -(self.mu * self.mass / r2**1.5) * R  # one division, not one per component
        if self.gravity_gradient:
            K = _gravity_gradient(self.mu, R, state.q, self.inertia)
        else:
            K = jnp.zeros_like(R)
        return Wrench(F, K)


class _SplitSatellite(RigidBodyField):
    """The satellite for `LiePoissonSplitting`: state `(Ω, q, (R, V))`, args the principal
    moments. `H = T_rot(M) + m V²/2 + U(R, q)`: the free part is the exact free rigid body and
    the free translation `R ← R + h V`; the kick is `V ← V − h μ R/R³` with
    `M ← M + h (3μ/R³) n × I n` (R and q fixed). Both Euler steps are exact flows."""

    mu: Array = eqx.field(kw_only=True)
    gravity_gradient: bool = eqx.field(static=True, kw_only=True)

    def kick(self, t, y, args):
        omega, q, (R, V) = y
        r2 = jnp.sum(R * R, -1, keepdims=True)
        if self.gravity_gradient:
            domega = _gravity_gradient(self.mu, R, q, args) / args
        else:
            domega = jnp.zeros_like(omega)
        return domega, (jnp.zeros_like(R), -self.mu * R / r2**1.5)

    def drift(self, t, y, args):
        R, V = y[2]
        return V, jnp.zeros_like(V)


def _simulate_split(body, R0, V0, q0, omega0, ts, mu, gravity_gradient, options):
    """`simulate_satellite` with `LiePoissonSplitting` (see `_SplitSatellite`)."""
    if isinstance(options.solver, ExactFreeBody):
        raise ValueError(
            "ExactFreeBody integrates the torque-free body alone; the satellite's orbit and "
            "gravity-gradient torque need solver=rigidjax.LiePoissonSplitting() with dt0"
        )
    if body.batch_shape != ():
        raise ValueError(
            f"simulate_satellite integrates one body; got a batch {body.batch_shape} (use jax.vmap)"
        )
    if not body.diagonal:
        raise ValueError(
            "LiePoissonSplitting needs the body in principal axes: give RigidBody(principal "
            "moments (3,)) and q0, omega0 for those axes"
        )
    ts = check_times(ts)
    s = initial_state(R0, V0, q0, omega0, ts.dtype)
    field = _SplitSatellite(mu=mu, gravity_gradient=gravity_gradient)
    ys, stats, result = solve_saved(
        diffrax.ODETerm(field),
        ts,
        (s.omega, s.q, (s.R, s.V)),
        fixed_steps(options),
        args=body.operator()[0].astype(ts.dtype),
    )
    omega, q, (R, V) = ys
    return SixDofTrajectory(ts=ts, R=R, V=V, quat=q, omega=omega, stats=stats, result=result)


def simulate_satellite(
    body: RigidBody,
    R0: RealLike,
    V0: RealLike,
    q0: RealLike | None,
    omega0: RealLike,
    ts: RealLike,
    mu: RealLike,
    *,
    gravity_gradient: bool = True,
    options: SolveOptions | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> SixDofTrajectory:
    """Orbit and attitude of a rigid satellite integrated together (`simulate_6dof` with the
    force `−μ m R/R³` on the COM and the gravity-gradient torque `3μ/R³ n × I n`; see the module
    docstring). States and options as in `rigidjax.sixdof.simulate_6dof`; `mu` = GM of the
    central body (traced: no recompilation when it changes). `lvlh_state` builds initial
    conditions near the LVLH equilibrium, `lvlh_angles(traj.R, traj.V, traj.quat)` reads the
    roll/pitch/yaw librations back. With `solver=rigidjax.LiePoissonSplitting()` and `dt0`
    (body in principal axes) the free rigid body and free translation are split from the
    gravity kick (a Störmer–Verlet orbit and the exact free attitude; `|q| = 1` to rounding and
    no secular energy drift)."""
    options = SolveOptions.of(options, solve_kwargs)
    if not isinstance(body, RigidBody):
        raise TypeError(f"body must be a rigidjax.RigidBody, got {type(body).__name__}")
    ts = as_float(ts, "ts")
    mu = check_positive(as_float(mu, "mu").astype(ts.dtype), "mu")
    if mu.shape != ():
        raise ValueError(f"mu must be a scalar, got shape {mu.shape}")
    if isinstance(options.solver, ExactFreeBody | LiePoissonSplitting):
        return _simulate_split(body, R0, V0, q0, omega0, ts, mu, gravity_gradient, options)
    loads = _SatelliteLoads(
        mu, body.mass.astype(ts.dtype), body.inertia.astype(ts.dtype), gravity_gradient
    )
    return simulate_6dof(
        body,
        R0,
        V0,
        q0,
        omega0,
        ts,
        loads,
        options=options,
    )
