"""Runge–Kutta–Munthe-Kaas (RKMK) integration on SO(3) × ℝⁿ as a Diffrax solver.

Zhilin's local rotation vector per step: over a step from `R0`, write `R(t) = exp(θ(t)) R0`
(space/left frame) or `R(t) = R0 exp(θ(t))` (body/right frame). Then θ(t0) = 0 and
`θ̇ = Z(θ) ω` (left) or `θ̇ = Zᵀ(θ) Ω` (right) (Zhilin 3.14.15, 3.14.21–22): an ODE on ℝ³ that
stays far from the singularity |θ| = 2π for any reasonable step. Any explicit Runge–Kutta tableau
applied to it keeps its classical order, and the new state `exp(Θ) R0` is a rotation to rounding
error after any number of steps (Munthe-Kaas 1998; Iserles et al. 2000).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ClassVar, Literal

import diffrax
import equinox as eqx
import jax.numpy as jnp
import jax.tree_util as jtu
from jaxtyping import Array

from ..rotations import so3
from . import _stages

Frame = Literal["space", "body"]


def _move(R0: Array, theta: Array, frame: Frame) -> Array:
    E = so3.exp(theta)
    return E @ R0 if frame == "space" else R0 @ E


def _reorthonormalize(R: Array) -> Array:
    """One Newton step of the polar decomposition, `R (3E − RᵀR)/2`: removes the rounding error
    that products of exact rotations accumulate (quadratically small; a no-op in exact arithmetic),
    so the state stays orthogonal to ~1e-16 for any number of steps."""
    return R @ (3 * jnp.eye(3, dtype=R.dtype) - jnp.swapaxes(R, -1, -2) @ R) / 2


def _dexpinv(theta: Array, w: Array, frame: Frame) -> Array:
    """θ̇ = Z(θ) ω (left) or Zᵀ(θ) Ω = Z(−θ) Ω (right), Zhilin (3.14.21)–(3.14.22)."""
    return jnp.einsum("...ij,...j->...i", so3.Z(theta if frame == "space" else -theta), w)


class _LieInterpolation(diffrax.AbstractLocalInterpolation):
    """Dense output: the tableau's own continuous extension applied to the local rotation vector
    θ(t) (and to x), mapped through `exp`, so interpolated attitudes are rotations too."""

    t0: Array
    t1: Array
    R0: Array
    local: diffrax.AbstractLocalInterpolation
    frame: Frame = eqx.field(static=True)

    @classmethod
    def build(cls, *, t0, t1, R0, y0, y1, k, frame, local_cls):
        return cls(t0, t1, R0, local_cls(t0=t0, t1=t1, y0=y0, y1=y1, k=k), frame)

    def evaluate(self, t0, t1=None, left=True):
        if t1 is not None:
            return jtu.tree_map(lambda a, b: a - b, self.evaluate(t1), self.evaluate(t0))
        theta, x = self.local.evaluate(t0, left=left)
        # the tableau interpolants carry NumPy float64 coefficients: keep the state's dtype
        theta = theta.astype(self.R0.dtype)
        return _move(self.R0, theta, self.frame), x


class LieTerm(diffrax.AbstractTerm):
    """Vector field on SO(3) × ℝⁿ: `vector_field(t, (R, x), args) -> (w, ẋ)`, `w` the angular
    velocity of R (its Lie-algebra element), `ẋ` shaped like x. Used with `RKMK`."""

    vector_field: Callable

    def vf(self, t, y, args):
        return self.vector_field(t, y, args)

    def contr(self, t0, t1, **kwargs):
        return t1 - t0

    def prod(self, vf, control):
        return jtu.tree_map(lambda v: control * v, vf)


class RKMK(diffrax.AbstractSolver):
    """Geometric (Lie-group) Runge–Kutta solver for `y = (R, x)`, R ∈ SO(3), x any PyTree.
    R may carry leading batch dimensions `(..., 3, 3)` (a batch integrated with one step size).

    The `LieTerm`'s vector field returns `(w, ẋ)` where `w` is the angular velocity
    of R: space ω (`Ṙ = ω × R`) for `frame="space"`, body Ω (`Ṙ = R (Ω × E)`) for `frame="body"`.
    `method` supplies the explicit Butcher tableau (default Dormand–Prince 5(4)); the embedded
    error estimate works with `diffrax.PIDController`, and dense output applies the tableau's own
    continuous extension to the local rotation vector, so saved attitudes are rotations as well.
    """

    method: diffrax.AbstractRungeKutta = diffrax.Dopri5()
    frame: Frame = eqx.field(static=True, default="space")

    term_structure: ClassVar = LieTerm

    def __check_init__(self):
        if self.frame not in ("space", "body"):
            raise ValueError(f"frame must be 'space' or 'body', got {self.frame!r}")
        _stages.tableau_of(self.method)

    @property
    def interpolation_cls(self):
        return functools.partial(
            _LieInterpolation.build, frame=self.frame, local_cls=self.method.interpolation_cls
        )

    def order(self, terms):
        return self.method.order(terms)

    def error_order(self, terms):
        return self.method.error_order(terms)

    def init(self, terms, t0, t1, y0, args):
        return None

    def func(self, terms, t0, y0, args):
        R, _ = y0
        w, xdot = terms.vf(t0, y0, args)
        W = so3.hat(w)
        return (W @ R if self.frame == "space" else R @ W), xdot

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        del solver_state, made_jump
        tab = _stages.tableau_of(self.method)
        R0, x0 = y0
        h = t1 - t0

        def stage(t, inc):
            # inc = (θ, Δx): local rotation vector and increment of x at this stage
            if inc is None:
                theta, x = jnp.zeros_like(R0[..., 0]), x0
            else:
                theta, x = inc[0], jtu.tree_map(lambda a, b: a + b, x0, inc[1])
            w, kx = terms.vf(t, (_move(R0, theta, self.frame), x), args)
            return _dexpinv(theta, w, self.frame), kx

        ks = _stages.stages(tab, t0, h, stage)
        Theta, dx = _stages.increment(h, tab.b_sol, ks)
        R1 = _reorthonormalize(_move(R0, Theta, self.frame))
        x1 = jtu.tree_map(lambda a, b: a + b, x0, dx)
        theta_err, x_err = _stages.increment(h, tab.b_error, ks)
        E_err = so3.hat(theta_err)
        R_err = E_err @ R1 if self.frame == "space" else R1 @ E_err
        # Stage increments in local coordinates, as the tableau's own dense output expects them.
        dense_info = dict(
            R0=R0, y0=(jnp.zeros_like(Theta), x0), y1=(Theta, x1), k=_stages.stacked(h, ks)
        )
        return (R1, x1), (R_err, x_err), dense_info, None, diffrax.RESULTS.successful
