"""The exact free rigid body as a Diffrax solver (`ExactFreeBody`), and the vector field of a
rigid body in principal axes that it and `LiePoissonSplitting` integrate (`RigidBodyField`).

Each step of `ExactFreeBody` is the Euler–Poinsot flow of `(Ω, q)` from the step's start state
(`rigidjax.analytic.free_body_flow`: Jacobi elliptic functions for Ω, the elliptic integral of the
third kind for the precession angle), so the result is exact to rounding for any step size: an
output interval needs one step. Uses the closed forms of `rigidjax.analytic`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
from jaxtyping import Array, PyTree

from .._checks import check_frame
from .._custom_types import Args, DenseInfo, RealScalarLike, Y
from ..analytic.poinsot_attitude import free_body_flow
from ._stateless import AbstractStatelessSolver

__all__ = [
    "AbstractFlowSolver",
    "ExactFreeBody",
    "RigidBodyField",
    "Torque",
    "field_of",
    "flow_from_start",
    "free_flow",
    "tree_add",
]

Torque = Callable[..., Array]  # torque(t, Ω (3,), q (4,)) -> K (3,)


def _rotate_inv(q: Array, v: Array) -> Array:
    """`Pᵀ v` for the unit quaternion q (P body → space): the space vector v in body axes."""
    w, u = q[..., :1], -q[..., 1:]
    t = 2 * jnp.cross(u, v)
    return v + w * t + jnp.cross(u, t)


def _quat_rate(q: Array, omega: Array) -> Array:
    """`q̇ = ½ q ∘ (0, Ω)` (body angular velocity; Hamilton product, scalar first)."""
    q0, qv = q[..., :1], q[..., 1:]
    return 0.5 * jnp.concatenate(
        [-jnp.sum(qv * omega, -1, keepdims=True), q0 * omega + jnp.cross(qv, omega)], -1
    )


class RigidBodyField(eqx.Module):
    """Vector field of a rigid body in principal axes for `ExactFreeBody` and
    `LiePoissonSplitting`: state `y = (Ω (..., 3), q (..., 4))` (body angular velocity, unit
    quaternion, P body → space; any leading batch dimensions) and `args` the principal moments
    `I (..., 3)` (broadcasting against the state). `torque(t, Ω, q) -> K (3,)` is the torque on
    ONE body (mapped over the batch), in body axes or, with `torque_frame="space"`, in space axes;
    None for the free body. `LiePoissonSplitting` needs a torque of the attitude (and time) only.

    Calling it gives Euler's equations `I Ω̇ + Ω × IΩ = K` and `q̇ = ½ q ∘ (0, Ω)` (the solvers
    use it only for Diffrax's bookkeeping). Subclasses may carry an extra state
    `y = (Ω, q, x)` for `LiePoissonSplitting` by overriding `kick` and `drift`
    (`rigidjax.satellite` does, for the orbit)."""

    torque: Torque | None = None
    torque_frame: str = eqx.field(static=True, default="body")

    def __check_init__(self) -> None:
        check_frame(self.torque_frame, "torque_frame")

    def torque_body(self, t: RealScalarLike, omega: Array, q: Array) -> Array:
        """The torque in body axes for a batch of states `(..., 3)`, `(..., 4)`."""
        if self.torque is None:
            return jnp.zeros_like(omega)
        K = jnp.vectorize(functools.partial(self.torque, t), signature="(3),(4)->(3)")(omega, q)
        K = K.astype(omega.dtype)
        return _rotate_inv(q, K) if self.torque_frame == "space" else K

    def kick(self, t: RealScalarLike, y: tuple, args: Args) -> tuple[Array, PyTree]:
        """The part of the vector field that `LiePoissonSplitting` integrates by a kick:
        `(Ω̇, ẋ)` with Ω̇ = I⁻¹ K(t, q) and q (and the kick's own position variables) held fixed,
        so that one Euler step is its exact flow; `ẋ` None without an extra state."""
        return self.torque_body(t, y[0], y[1]) / args, None

    def drift(self, t: RealScalarLike, y: tuple, args: Args) -> PyTree:
        """The rate of the extra state x during the free flow (its Euler step must be exact);
        None without an extra state."""
        return None

    def __call__(self, t: RealScalarLike, y: tuple, args: Args) -> tuple:
        omega, q = y[0], y[1]
        I = args
        domega_kick, dx_kick = self.kick(t, y, args)
        out = (domega_kick - jnp.cross(omega, I * omega) / I, _quat_rate(q, omega))
        if len(y) == 3:
            out = (*out, tree_add(dx_kick, self.drift(t, y, args)))
        return out


def tree_add(a: PyTree, b: PyTree) -> PyTree:
    """`a + b` leaf by leaf, None standing for zero."""
    if a is None:
        return b
    if b is None:
        return a
    return jtu.tree_map(lambda u, v: u + v, a, b)


def field_of(terms: diffrax.AbstractTerm, solver: str) -> tuple[RigidBodyField, RealScalarLike]:
    """The `RigidBodyField` of `terms` (a `diffrax.ODETerm`, possibly wrapped by Diffrax for the
    direction of integration) and that direction (±1), or a clear error."""
    direction = 1
    while not hasattr(terms, "vector_field") and hasattr(terms, "term"):
        direction = direction * getattr(terms, "direction", 1)
        terms = terms.term  # pyright: ignore[reportAttributeAccessIssue]
    field = getattr(terms, "vector_field", None)
    if not isinstance(field, RigidBodyField):
        raise TypeError(
            f"{solver} integrates a rigid body: use it through rigidjax.simulate (or "
            "simulate_heavy_top, satellite.simulate_satellite), or give diffrax.diffeqsolve a "
            "diffrax.ODETerm(rigidjax.solvers.RigidBodyField(...)) with y = (omega, q) and "
            f"args = the principal moments; got the vector field {type(field).__name__}"
        )
    return field, direction


def free_flow(inertia: Array, omega: Array, q: Array, h: RealScalarLike) -> tuple[Array, Array]:
    """The exact free flow of a batch `(Ω (..., 3), q (..., 4))` over the time step h, with the
    quaternion renormalised (a rounding-level correction)."""
    flow = jnp.vectorize(free_body_flow, signature="(3),(3),(4),()->(3),(4)")
    omega1, q1 = flow(inertia, omega, q, jnp.asarray(h, omega.dtype))
    omega1 = jnp.broadcast_to(omega1, omega.shape)
    q1 = jnp.broadcast_to(q1, q.shape)
    return omega1, q1 / jnp.linalg.norm(q1, axis=-1, keepdims=True)


@jax.jit
def flow_from_start(inertia: Array, omega0: Array, q0: Array, ts: Array) -> tuple[Array, Array]:
    """The exact free flow of a batch `(Ω0 (B, 3), q0 (B, 4))` (moments `inertia (B, 3)` or
    `(3,)`) from `ts[0]` to every time `ts (T,)` in one step each: `(Ω (T, B, 3), q (T, B, 4))`,
    q renormalised (a rounding-level correction) and continuous in time."""
    flow = jnp.vectorize(free_body_flow, signature="(3),(3),(4),()->(3),(4)")
    dts = (ts - ts[0])[:, None]
    omega, q = flow(inertia[None], omega0[None], q0[None], dts)
    return omega, q / jnp.linalg.norm(q, axis=-1, keepdims=True)


class AbstractFlowSolver(AbstractStatelessSolver):
    """A fixed-step solver made of exact flows (`ExactFreeBody`, `LiePoissonSplitting`): no
    error estimate, no solver state, linear interpolation between step ends."""

    term_structure: ClassVar = diffrax.ODETerm
    interpolation_cls: ClassVar[Callable[..., diffrax.LocalLinearInterpolation]] = (
        diffrax.LocalLinearInterpolation
    )

    def error_order(self, terms: PyTree[diffrax.AbstractTerm]) -> RealScalarLike | None:
        return None


class ExactFreeBody(AbstractFlowSolver):
    """The exact flow of the torque-free rigid body as a Diffrax solver: each step maps the
    state `(Ω, q)` at its start to the Euler–Poinsot solution at its end
    (`rigidjax.analytic.free_body_flow`: Jacobi elliptic functions for Ω, Carlson's integral of
    the third kind for the precession angle, stable formulas in every regime — polhodes about
    the largest and the smallest axis, the separatrix itself, symmetric tops, the sphere), so
    results are exact to rounding for any step size, close to the separatrix too (ψ: 4e-14
    against a 40-digit quadrature for I = (1, 2, 3), Ω0 = (δ, 1, δ) over 4 s, δ = 1e-4 … 1e-14),
    and on it (to 16 ulp: the elementary closed form). Differentiable with respect to the
    moments, Ω0 and q0. Use it through `rigidjax.simulate(body, omega0, q0, ts,
    solver=ExactFreeBody())` (body in principal axes, no torque): by default every output time
    is reached by one exact step from `ts[0]` (`flow_from_start`, no Diffrax loop: the fastest
    to run, compile and differentiate); with `dt0` (and `diffrax.ConstantStepSize`) Diffrax
    steps by at most `dt0`. With `diffrax.diffeqsolve`
    the term must be `diffrax.ODETerm(RigidBodyField())`, `y = (Ω, q)` and `args` the principal
    moments. No error estimate: fixed steps only."""

    def order(self, terms: PyTree[diffrax.AbstractTerm]) -> int | None:
        return None

    def _advance(
        self, terms: diffrax.AbstractTerm, t0: RealScalarLike, t1: RealScalarLike, y0: Y, args: Args
    ) -> tuple[Y, None, DenseInfo]:
        field, direction = field_of(terms, "ExactFreeBody")
        if field.torque is not None:
            raise ValueError(
                "ExactFreeBody integrates the torque-free rigid body; with a torque that depends "
                "on the attitude only use rigidjax.LiePoissonSplitting(), otherwise a "
                "Runge–Kutta solver"
            )
        if len(y0) != 2:
            raise ValueError("ExactFreeBody integrates the state y = (omega, q)")
        y1 = free_flow(args, y0[0], y0[1], direction * (t1 - t0))
        return y1, None, dict(y0=y0, y1=y1)
