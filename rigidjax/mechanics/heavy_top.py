"""The heavy rigid body about a fixed point: Euler–Poisson equations, integrals, classical cases.

Variables (Borisov–Mamaev, 001, "Euler–Poisson variables"; THEORY conventions): the body
angular velocity Ω, the angular momentum `M = IΩ` about the fixed point O, and
`γ = Pᵀ e_Z` — the space vertical (the fixed Z axis, pointing UP) in body axes, the third row of
P (P maps body to space). `I` is the inertia tensor about O (Steiner: `I_O = I_C + m(a²E − aa)`,
Zegrya–Parshin 004), `r_c` the body position of the centre of mass relative to O.

**Equations.** Gravity `−m g e_Z` acts at the centre of mass `P r_c`. Its moment about O in space
is `(P r_c) × (−m g e_Z)`; in body axes (`Pᵀ(a × b) = Pᵀa × Pᵀb`) this is
`r_c × (−m g γ) = m g γ × r_c`. Euler's equations (004) and the Poisson equation
(`Ṗ = P(Ω × E)` ⇒ `Ṗᵀ e_Z = −Ω × Pᵀ e_Z`) give

    I Ω̇ + Ω × IΩ = m g γ × r_c,        γ̇ = γ × Ω,

and optionally the attitude `q̇ = ½ q ∘ (0, Ω)` (001; THEORY §3), from which `γ = P(q)ᵀ e_Z`.

**Integrals.** Energy `E = ½ Ω·IΩ + m g r_c·γ` (the potential is `m g Z_c`,
`Z_c = e_Z·P r_c = r_c·γ`); area integral `M·γ = IΩ·γ` (the vertical component of the angular
momentum: gravity has no vertical moment); geometric `|γ|² = 1`. With a fourth integral the
system is integrable:

- **Lagrange** (`I1 = I2`, `r_c = (0, 0, l)`): `M3 = I3 Ω3` (the third Euler equation reads
  `I3 Ω̇3 = (I1 − I2)Ω1Ω2 + m g (γ × r_c)_3 = 0`). The upright "sleeping" top (`γ = e3`, l > 0)
  is stable iff `I3² Ω3² > 4 I1 m g l` (Maievskii criterion), I1 about the fixed point.
- **Kovalevskaya** (`I1 = I2 = 2 I3`, `r_c = (x0, 0, 0)` in the equatorial plane):
  `K = (Ω1² − Ω2² − ν γ1)² + (2 Ω1 Ω2 − ν γ2)²`, `ν = m g x0 / I3`.
  Derivation of the normalisation: with `I = c (2, 2, 1)` the equations above read
  `2Ω̇1 = Ω2Ω3`, `2Ω̇2 = −Ω1Ω3 + ν γ3`, `Ω̇3 = −ν γ2` with `ν = m g x0 / c = m g x0 / I3`;
  with `z = Ω1 + iΩ2`, `w = γ1 + iγ2` one finds `ż = −(i/2)Ω3 z + (iν/2)γ3`,
  `ẇ = −iΩ3 w + iγ3 z`, hence `d(z² − νw)/dt = −iΩ3 (z² − νw)` and `K = |z² − νw|²` is
  constant. (Any other ν — e.g. `m g x0 / I1` — is not.) For a general equatorial
  `r_c = (x0, y0, 0)` (the axes turned about e3) `K = |z² − (m g / I3)(x0 + i y0) w|²`.

Sources: Borisov & Mamaev, 001 (Euler–Poisson variables, quaternions); Zegrya & Parshin,
004 (Euler's equations, inertia about a point); the Lagrange/Kovalevskaya integrals and the
Maievskii criterion are the classical ones (not in the sources; verified numerically in
tests/test_heavy_top.py).
"""

from __future__ import annotations

from typing import Unpack

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._checks import (
    as_float,
    check_finite,
    check_times,
    check_unit_norm,
    initial_vector,
    norm_tolerance,
    validate,
    vector,
)
from .._custom_types import RealLike, Scalar, Vec3
from .._integrate import SolveKwargs, SolveOptions
from .._trajectory import AbstractTrajectory
from ..kinematics.formulations import Quaternion
from ..models.solve import solve_tree
from ..rotations import quat
from ..solvers.exact_free_body import ExactFreeBody
from ..solvers.splitting import LiePoissonSplitting
from .body import RigidBody, euler_rhs
from .dynamics import simulate

__all__ = [
    "HeavyTop",
    "HeavyTopTrajectory",
    "area_integral",
    "drift",
    "energy",
    "euler_poisson_rhs",
    "geometric_integral",
    "kovalevskaya_integral",
    "lagrange_integral",
    "simulate_heavy_top",
    "sleeping_top_critical_spin",
    "vertical_from_quat",
]


class HeavyTop(eqx.Module):
    """A heavy rigid body with one fixed point O.

    `inertia`: about O, principal moments `(3,)` or a symmetric tensor `(3, 3)` in body axes
    (validated like `RigidBody`: positive definite, triangle inequality); `mass > 0`; `com`: the
    centre of mass relative to O in body axes `(3,)`; `g`: gravitational acceleration (gravity is
    `−g e_Z` in space). Leading batch dimensions are allowed for the integrals;
    `simulate_heavy_top` takes one top (use `jax.vmap` for batches).
    """

    body: RigidBody
    com: Float[Array, "*batch 3"]
    g: Float[Array, "*batch"]

    def __init__(self, inertia: RealLike, mass: RealLike, com: RealLike, g: RealLike = 9.81):
        self.body = RigidBody(inertia, mass)
        dtype = self.body.inertia.dtype
        self.com = check_finite(vector(com, 3, "com").astype(dtype), "com")
        self.g = check_finite(as_float(g, "g").astype(dtype), "g")

    @property
    def inertia(self) -> Float[Array, "*batch 3 3"]:
        return self.body.inertia

    @property
    def mass(self) -> Float[Array, "*batch"]:
        return self.body.mass

    @property
    def gravity_moment(self) -> Vec3:
        """`m g r_c` (Borisov–Mamaev's `μ r`): the torque is `γ × (m g r_c)`."""
        return (self.mass * self.g)[..., None] * self.com

    def operator(self) -> tuple[Array, Array]:
        """`(I, I⁻¹)` for `rigidjax.body.euler_rhs` (moments or tensors, see `RigidBody`)."""
        return self.body.operator()

    def torque(self, gamma: RealLike) -> Vec3:
        """Moment of gravity about O in body axes, `m g γ × r_c`."""
        gamma = vector(gamma, 3, "gamma")
        return jnp.cross(gamma, self.gravity_moment)


def euler_poisson_rhs(top: HeavyTop, omega: RealLike, gamma: RealLike) -> tuple[Vec3, Vec3]:
    """`(Ω̇, γ̇)` of the Euler–Poisson equations `I Ω̇ + Ω × IΩ = m g γ × r_c`, `γ̇ = γ × Ω`."""
    omega = vector(omega, 3, "omega")
    gamma = vector(gamma, 3, "gamma")
    I, I_inv = top.operator()
    return euler_rhs(I, I_inv, omega, top.torque(gamma)), jnp.cross(gamma, omega)


def vertical_from_quat(q: RealLike) -> Vec3:
    """`γ = P(q)ᵀ e_Z`: the space vertical in body axes (the third row of P)."""
    q = vector(q, 4, "q")
    e_z = jnp.zeros(q.shape[:-1] + (3,), q.dtype).at[..., 2].set(1)
    return quat.rotate(quat.conj(q), e_z)


# --------------------------------------------------------------------------- integrals


def _expand(x: Array, core: int, like: Array) -> Array:
    """Insert unit axes after the batch dimensions of a top parameter `x` (core rank `core`) so
    it broadcasts against `like (..., [T,] 3)` (as `rigidjax.invariants`)."""
    extra = like.ndim - 1 - (x.ndim - core)
    return x.reshape(x.shape[: x.ndim - core] + (1,) * max(extra, 0) + x.shape[x.ndim - core :])


def _momentum(top: HeavyTop, omega: Array) -> Array:
    I = _expand(top.inertia, 2, omega)
    return jnp.einsum("...ij,...j->...i", I, omega)


def energy(top: HeavyTop, omega: RealLike, gamma: RealLike) -> Scalar:
    """`E = ½ Ω·IΩ + m g r_c·γ` (kinetic + potential `m g Z_c`, Z up)."""
    omega = vector(omega, 3, "omega")
    gamma = vector(gamma, 3, "gamma")
    mu_r = _expand(top.gravity_moment, 1, omega)
    return 0.5 * jnp.sum(_momentum(top, omega) * omega, -1) + jnp.sum(mu_r * gamma, -1)


def area_integral(top: HeavyTop, omega: RealLike, gamma: RealLike) -> Scalar:
    """`M·γ = IΩ·γ`: the vertical component of the angular momentum about O."""
    omega = vector(omega, 3, "omega")
    gamma = vector(gamma, 3, "gamma")
    return jnp.sum(_momentum(top, omega) * gamma, -1)


def geometric_integral(gamma: RealLike) -> Scalar:
    """`|γ|²` (= 1 on every motion)."""
    gamma = vector(gamma, 3, "gamma")
    return jnp.sum(gamma * gamma, -1)


def _is_lagrange(top: HeavyTop, rtol: float) -> Bool[Array, "*batch"]:
    I, c = top.inertia, top.com
    s = jnp.max(jnp.abs(I), axis=(-2, -1))
    off = jnp.abs(I - I * jnp.eye(3, dtype=I.dtype))
    ok_I = (jnp.max(off, axis=(-2, -1)) <= rtol * s) & (
        jnp.abs(I[..., 0, 0] - I[..., 1, 1]) <= rtol * s
    )
    ok_c = jnp.max(jnp.abs(c[..., :2]), -1) <= rtol * jnp.max(jnp.abs(c), -1)
    return ok_I & ok_c


def _is_kovalevskaya(top: HeavyTop, rtol: float) -> Bool[Array, "*batch"]:
    I, c = top.inertia, top.com
    s = jnp.max(jnp.abs(I), axis=(-2, -1))
    off = jnp.abs(I - I * jnp.eye(3, dtype=I.dtype))
    ok_I = (
        (jnp.max(off, axis=(-2, -1)) <= rtol * s)
        & (jnp.abs(I[..., 0, 0] - I[..., 1, 1]) <= rtol * s)
        & (jnp.abs(I[..., 0, 0] - 2 * I[..., 2, 2]) <= rtol * s)
    )
    ok_c = jnp.abs(c[..., 2]) <= rtol * jnp.max(jnp.abs(c), -1)
    return ok_I & ok_c


def _require(ok: Array, x: Array, msg: str) -> Array:
    """`x`, with an error `msg` where the case test `ok` fails (see `validate`)."""
    return validate(ok, lambda xp, v: ~v, msg, on=x)


def lagrange_integral(
    top: HeavyTop, omega: RealLike, *, check: bool = True, rtol: float = 1e-9
) -> Scalar:
    """`M3 = (IΩ)_3` (= I3 Ω3): conserved for the Lagrange top (`I1 = I2` with the tensor
    diagonal, centre of mass on the symmetry axis e3). `check=True` raises for other tops (within
    `rtol`); `check=False` evaluates it anyway (e.g. to show it is not conserved)."""
    omega = vector(omega, 3, "omega")
    M3 = _momentum(top, omega)[..., 2]
    if check:
        M3 = _require(
            _is_lagrange(top, rtol),
            M3,
            "lagrange_integral: not a Lagrange top (need a diagonal inertia tensor with I1 = I2 "
            "and com = (0, 0, l)); pass check=False to evaluate M3 anyway",
        )
    return M3


def kovalevskaya_integral(
    top: HeavyTop,
    omega: RealLike,
    gamma: RealLike,
    *,
    check: bool = True,
    rtol: float = 1e-9,
) -> Scalar:
    """Kovalevskaya's integral `K = (Ω1² − Ω2² − ν γ1)² + (2Ω1Ω2 − ν γ2)²`, `ν = m g x0 / I3`,
    for `I1 = I2 = 2 I3` (diagonal tensor) and `r_c = (x0, 0, 0)`; for a general equatorial
    `r_c = (x0, y0, 0)`, `K = |z² − (m g/I3)(x0 + i y0) w|²` with `z = Ω1 + iΩ2`,
    `w = γ1 + iγ2` (derivation in the module docstring). `check=True` raises for other tops;
    `check=False` evaluates the same expression (with I3 = I[2, 2]) for any top."""
    omega = vector(omega, 3, "omega")
    gamma = vector(gamma, 3, "gamma")
    mu_r = top.gravity_moment / top.inertia[..., 2, 2][..., None]  # (m g / I3) r_c
    a = _expand(mu_r[..., 0], 0, omega[..., 0:1])
    b = _expand(mu_r[..., 1], 0, omega[..., 0:1])
    w1, w2 = omega[..., 0], omega[..., 1]
    g1, g2 = gamma[..., 0], gamma[..., 1]
    # z² − (a + ib) w
    re = w1 * w1 - w2 * w2 - (a * g1 - b * g2)
    im = 2 * w1 * w2 - (a * g2 + b * g1)
    K = re * re + im * im
    if check:
        K = _require(
            _is_kovalevskaya(top, rtol),
            K,
            "kovalevskaya_integral: not a Kovalevskaya top (need a diagonal inertia tensor with "
            "I1 = I2 = 2 I3 and com = (x0, y0, 0)); pass check=False to evaluate K anyway",
        )
    return K


def sleeping_top_critical_spin(top: HeavyTop, *, check: bool = True) -> Scalar:
    """Critical spin of the upright ("sleeping") Lagrange top, `Ω3* = 2 √(I1 m g l) / I3`
    (`l = r_c,3`; 0 when the centre of mass is below O): upright spin is linearly stable iff
    `|Ω3| > Ω3*`, the Maievskii criterion `I3² Ω3² > 4 I1 m g l` (I1 about the fixed point)."""
    I = top.inertia
    mgl = top.mass * top.g * top.com[..., 2]
    out = 2 * jnp.sqrt(jnp.maximum(I[..., 0, 0] * mgl, 0)) / I[..., 2, 2]
    if check:
        out = _require(
            _is_lagrange(top, 1e-9),
            out,
            "sleeping_top_critical_spin: not a Lagrange top (diagonal inertia, I1 = I2, "
            "com = (0, 0, l))",
        )
    return out


# --------------------------------------------------------------------------- integration


class HeavyTopTrajectory(AbstractTrajectory):
    """Solution of `simulate_heavy_top`: times `ts (T,)`, body angular velocity `omega (T, 3)`,
    the integrated vertical `gamma (T, 3)` and, when the attitude was integrated, the unit
    quaternion `quat (T, 4)` (as integrated: its sign is continuous in time and `quat[0] = q0`;
    P body → space), else None."""

    omega: Float[Array, "T 3"]
    gamma: Float[Array, "T 3"]
    quat: Float[Array, "T 4"] | None

    @property
    def gamma_from_quat(self) -> Float[Array, "T 3"]:
        """`P(q)ᵀ e_Z` from the integrated attitude (compare with `gamma`)."""
        if self.quat is None:
            raise ValueError("no attitude was integrated: pass q0 to simulate_heavy_top")
        return vertical_from_quat(self.quat)

    @property
    def matrix(self) -> Float[Array, "T 3 3"]:
        if self.quat is None:
            raise ValueError("no attitude was integrated: pass q0 to simulate_heavy_top")
        return quat.to_matrix(self.quat)


_QUATERNION = Quaternion(frame="body")  # q̇ = ½ q ∘ (0, Ω) and its step-end normalisation


class _Field(eqx.Module):
    """`(t, y, (I, I⁻¹, m g r_c)) -> ẏ`, `y = (Ω, γ)` or `(Ω, γ, q)`: the Euler–Poisson
    equations (`euler_poisson_rhs`) with the top's operators computed once, not per step."""

    def __call__(self, t, y, args):
        I, I_inv, mu = args
        domega = euler_rhs(I, I_inv, y[0], jnp.cross(y[1], mu))
        dgamma = jnp.cross(y[1], y[0])
        if len(y) == 2:
            return domega, dgamma
        return domega, dgamma, _QUATERNION.vector_field(y[2], y[0])


def _unit(x: Array, name: str, hint: str = "") -> Array:
    """`x` checked to be a unit vector (within `norm_tolerance`) and then normalised exactly."""
    x = check_unit_norm(x, name, hint)
    return x / jnp.linalg.norm(x, axis=-1, keepdims=True)


class _GravityTorque(eqx.Module):
    """`torque(t, Ω, q) = γ(q) × m g r_c` (body axes) for `simulate` (a function of q only)."""

    gravity_moment: Array

    def __call__(self, t, omega, q):
        return jnp.cross(vertical_from_quat(q), self.gravity_moment)


def _quat_from_vertical(gamma: Array) -> Array:
    """A unit quaternion with `P(q)ᵀ e_Z = γ` (`P γ = e_Z`): the shortest rotation taking the unit
    γ to e_Z, `q ∝ (1 + γ·e_Z, γ × e_Z)`; half a turn about x for γ = −e_Z."""
    one = jnp.ones_like(gamma[..., 2])
    q = jnp.stack([one + gamma[..., 2], gamma[..., 1], -gamma[..., 0], 0 * one], -1)
    n = jnp.linalg.norm(q, axis=-1, keepdims=True)
    down = n < 1e-8
    flip = jnp.stack([0 * one, one, 0 * one, 0 * one], -1)
    return jnp.where(down, flip, q / jnp.where(down, 1, n))


def _simulate_split(
    top: HeavyTop,
    omega0: Array,
    gamma0: Array,
    q0: Array | None,
    ts: Array,
    options: SolveOptions,
) -> HeavyTopTrajectory:
    """`simulate_heavy_top` with `LiePoissonSplitting`: the attitude q is integrated (from `q0`,
    or from a quaternion with `P(q)ᵀ e_Z = gamma0`) and `γ = P(q)ᵀ e_Z` read off it, so
    `|γ| = 1` to rounding."""
    if isinstance(options.solver, ExactFreeBody):
        raise ValueError(
            "ExactFreeBody integrates the torque-free body; gravity is a torque of the attitude: "
            "use solver=rigidjax.LiePoissonSplitting() with dt0"
        )
    if not top.body.diagonal:
        raise ValueError(
            "LiePoissonSplitting needs the top in principal axes: give HeavyTop(principal "
            "moments (3,), ...) with com, omega0 and gamma0/q0 in those axes"
        )
    start = _quat_from_vertical(gamma0) if q0 is None else q0
    traj = simulate(
        top.body, omega0, start, ts, torque=_GravityTorque(top.gravity_moment), options=options
    )
    return HeavyTopTrajectory(
        ts=ts,
        omega=traj.omega,
        gamma=vertical_from_quat(traj.quat),
        quat=None if q0 is None else traj.quat,
        stats=traj.stats,
        result=traj.result,
    )


def simulate_heavy_top(
    top: HeavyTop,
    omega0: RealLike,
    gamma0: RealLike | None = None,
    ts: RealLike | None = None,
    *,
    q0: RealLike | None = None,
    options: SolveOptions | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> HeavyTopTrajectory:
    """Integrate the Euler–Poisson equations `I Ω̇ + Ω × IΩ = m g γ × r_c`, `γ̇ = γ × Ω`
    (see the module docstring) from `Ω(ts[0]) = omega0`, `γ(ts[0]) = gamma0`, saving at `ts`.

    Give `gamma0` (a unit vector: the vertical in body axes) or the attitude `q0` (unit
    quaternion, P body → space); with `q0` the attitude `q̇ = ½ q ∘ (0, Ω)` is integrated too
    (renormalised after each step) and `gamma0 = P(q0)ᵀ e_Z` (if both are given they must
    agree). γ is always integrated by the Poisson equation, so `traj.gamma_from_quat` is an
    independent cross-check and `|γ| = 1` a measure of the error.

    With `solver=rigidjax.LiePoissonSplitting()` (and `dt0`; a top in principal axes) the exact
    free flow and the gravity kick are composed symmetrically: the attitude is integrated and γ
    read off it (`|γ| = 1` and `M·γ` to rounding, bounded energy error).

    Defaults: Tsit5 with unrolled stages (`ExplicitRK`; any explicit Diffrax Runge–Kutta solver
    is unrolled likewise) with `diffrax.PIDController` at `rtol = atol = 1e-10` in float64 (1e-6
    in float32); the dtype is that of `ts`. One top per call: `jax.vmap` for batches.
    """
    options = SolveOptions.of(options, solve_kwargs)
    if not isinstance(top, HeavyTop):
        raise TypeError(
            f"top must be a rigidjax.HeavyTop, got {type(top).__name__}: e.g. "
            "simulate_heavy_top(HeavyTop(inertia, mass, com, g), omega0, ...)"
        )
    if ts is None:
        raise ValueError("ts (the output times) is required")
    ts = check_times(as_float(ts, "ts"))
    dtype = ts.dtype
    if top.inertia.ndim != 2:
        raise ValueError(
            f"simulate_heavy_top takes one top (batch shape ()), got batch shape "
            f"{top.body.batch_shape}; use jax.vmap over the top for batches"
        )
    top = jax.tree_util.tree_map(lambda x: x.astype(dtype), top)
    omega0 = initial_vector(omega0, 3, "omega0", dtype)

    if q0 is not None:
        q0 = _unit(initial_vector(q0, 4, "q0", dtype), "q0")
        gamma_q = vertical_from_quat(q0)
        if gamma0 is not None:
            g = vector(gamma0, 3, "gamma0").astype(dtype)
            tol = norm_tolerance(dtype)
            gamma_q = validate(
                g - gamma_q,
                lambda xp, d: xp.max(xp.abs(d)) > tol,
                "gamma0 disagrees with q0: gamma0 must equal P(q0)^T e_Z (or give only one)",
                lambda d: f"; P(q0)^T e_Z = {gamma_q}, gamma0 = {g}",
                on=gamma_q,
            )
        gamma0 = gamma_q
    elif gamma0 is None:
        raise ValueError("give the initial vertical gamma0 (body axes) or the attitude q0")
    gamma0 = _unit(
        initial_vector(gamma0, 3, "gamma0", dtype),
        "gamma0",
        "; normalise it (the space vertical e_Z in body axes, gamma = P^T e_Z)",
    )

    if isinstance(options.solver, ExactFreeBody | LiePoissonSplitting):
        return _simulate_split(top, omega0, gamma0, q0, ts, options)
    ys, stats, result = solve_tree(
        _Field(),
        ts,
        (omega0, gamma0) if q0 is None else (omega0, gamma0, q0),
        (*top.operator(), top.gravity_moment),
        options,
        unit=() if q0 is None else (2,),
        name="heavy top",
    )
    q = None if q0 is None else ys[2]  # step-end states: unit, with a continuous sign
    return HeavyTopTrajectory(ts=ts, omega=ys[0], gamma=ys[1], quat=q, stats=stats, result=result)


def drift(top: HeavyTop, traj: HeavyTopTrajectory) -> dict[str, Array]:
    """Largest deviation from the initial value along `traj` of each integral, made relative to
    a scale of its terms: energy / (½ max Ω·IΩ + m g |r_c|); area / max |IΩ|; `| |γ|² − 1 |`;
    and, when the top is a Lagrange / Kovalevskaya one, M3 / max|IΩ| and
    K / max (|z|² + ν|w|)² (with `z = Ω1 + iΩ2`, `w = γ1 + iγ2`, ν = m g |r_c| / I3).
    One concrete (non-traced, unbatched) top: the case detection is done in Python."""
    om, ga = traj.omega, traj.gamma
    M = jnp.linalg.norm(_momentum(top, om), axis=-1)
    kin = 0.5 * jnp.sum(_momentum(top, om) * om, -1)
    mgr = top.mass * top.g * jnp.linalg.norm(top.com)

    def dev(x):
        return jnp.max(jnp.abs(x - x[..., :1]), axis=-1)

    out = {
        "energy": dev(energy(top, om, ga)) / (jnp.max(kin, -1) + mgr),
        "area": dev(area_integral(top, om, ga)) / jnp.max(M, -1),
        "geometric": jnp.max(jnp.abs(geometric_integral(ga) - 1), -1),
    }
    if bool(_is_lagrange(top, 1e-9)):
        out["lagrange"] = dev(lagrange_integral(top, om)) / jnp.max(M, -1)
    if bool(_is_kovalevskaya(top, 1e-9)):
        nu = mgr / top.inertia[..., 2, 2]
        z2 = jnp.sum(om[..., :2] ** 2, -1)
        w = jnp.linalg.norm(ga[..., :2], axis=-1)
        out["kovalevskaya"] = dev(kovalevskaya_integral(top, om, ga)) / jnp.max(
            (z2 + nu * w) ** 2, -1
        )
    return out
