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
from typing import ClassVar

import diffrax
import equinox as eqx
import jax.numpy as jnp
import jax.tree_util as jtu
from jaxtyping import PyTree

from .._checks import check_frame
from .._custom_types import (
    Args,
    DenseInfo,
    Frame,
    Mat33,
    RealScalarLike,
    Vec3,
    Y,
)
from ..rotations import so3
from . import _stages

__all__ = ["RKMK", "LieTerm"]


def _move(R0: Mat33, theta: Vec3, frame: Frame) -> Mat33:
    E = so3.exp(theta)
    return E @ R0 if frame == "space" else R0 @ E


def _reorthonormalize(R: Mat33) -> Mat33:
    """One Newton step of the polar decomposition, `R (3E − RᵀR)/2`: removes the rounding error
    that products of exact rotations accumulate (quadratically small; a no-op in exact arithmetic),
    so the state stays orthogonal to ~1e-16 for any number of steps."""
    return R @ (3 * jnp.eye(3, dtype=R.dtype) - jnp.swapaxes(R, -1, -2) @ R) / 2


def _dexpinv(theta: Vec3, w: Vec3, frame: Frame) -> Vec3:
    """θ̇ = Z(θ) ω (left) or Zᵀ(θ) Ω = Z(−θ) Ω (right), Zhilin (3.14.21)–(3.14.22)."""
    return jnp.einsum("...ij,...j->...i", so3.Z(theta if frame == "space" else -theta), w)


class _LieInterpolation(diffrax.AbstractLocalInterpolation):
    """Dense output: the tableau's own continuous extension applied to the local rotation vector
    θ(t) (and to x), mapped through `exp`, so interpolated attitudes are rotations too."""

    # Diffrax's `AbstractPath` declares t0, t1 as `AbstractVar`, which it shows to type checkers as
    # `ClassVar`; its own interpolations override them with fields exactly like this.
    t0: RealScalarLike  # pyright: ignore[reportIncompatibleVariableOverride]
    t1: RealScalarLike  # pyright: ignore[reportIncompatibleVariableOverride]
    R0: Mat33
    local: diffrax.AbstractLocalInterpolation
    frame: Frame = eqx.field(static=True)

    @classmethod
    def build(
        cls,
        *,
        t0: RealScalarLike,
        t1: RealScalarLike,
        R0: Mat33,
        y0: tuple[Vec3, Y],
        y1: tuple[Vec3, Y],
        k: tuple[PyTree, PyTree],
        frame: Frame,
        local_cls: Callable[..., diffrax.AbstractLocalInterpolation],
    ) -> _LieInterpolation:
        return cls(t0, t1, R0, local_cls(t0=t0, t1=t1, y0=y0, y1=y1, k=k), frame)

    def evaluate(
        self, t0: RealScalarLike, t1: RealScalarLike | None = None, left: bool = True
    ) -> tuple[Mat33, Y]:
        if t1 is not None:
            return jtu.tree_map(lambda a, b: a - b, self.evaluate(t1), self.evaluate(t0))
        theta, x = self.local.evaluate(t0, left=left)
        # the tableau interpolants carry NumPy float64 coefficients: keep the state's dtype
        theta = theta.astype(self.R0.dtype)
        return _move(self.R0, theta, self.frame), x


class LieTerm(diffrax.AbstractTerm[tuple[Vec3, PyTree], RealScalarLike]):
    """Vector field on SO(3) × ℝⁿ: `vector_field(t, (R, x), args) -> (w, ẋ)`, `w` the angular
    velocity of R (its Lie-algebra element), `ẋ` shaped like x. Used with `RKMK`."""

    vector_field: Callable[[RealScalarLike, tuple[Mat33, Y], Args], tuple[Vec3, PyTree]]

    def vf(self, t: RealScalarLike, y: tuple[Mat33, Y], args: Args) -> tuple[Vec3, PyTree]:
        return self.vector_field(t, y, args)

    def contr(self, t0: RealScalarLike, t1: RealScalarLike, **kwargs) -> RealScalarLike:
        return t1 - t0

    def prod(self, vf: tuple[Vec3, PyTree], control: RealScalarLike) -> tuple[Vec3, PyTree]:
        return jtu.tree_map(lambda v: control * v, vf)


class RKMK(_stages.AbstractTableauSolver):
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

    def __check_init__(self) -> None:
        check_frame(self.frame)

    # A property where Diffrax declares a ClassVar, as Diffrax's own wrappers (`HalfSolver`) do.
    @property
    def interpolation_cls(  # pyright: ignore[reportIncompatibleMethodOverride]
        self,
    ) -> Callable[..., _LieInterpolation]:
        return functools.partial(
            _LieInterpolation.build, frame=self.frame, local_cls=self.method.interpolation_cls
        )

    def func(
        self, terms: diffrax.AbstractTerm, t0: RealScalarLike, y0: tuple[Mat33, Y], args: Args
    ) -> tuple[Mat33, Y]:
        R, _ = y0
        w, xdot = terms.vf(t0, y0, args)
        W = so3.hat(w)
        return (W @ R if self.frame == "space" else R @ W), xdot

    def _advance(
        self,
        terms: diffrax.AbstractTerm,
        t0: RealScalarLike,
        t1: RealScalarLike,
        y0: tuple[Mat33, Y],
        args: Args,
    ) -> tuple[tuple[Mat33, Y], tuple[Mat33, Y], DenseInfo]:
        tab = _stages.tableau_of(self.method)
        R0, x0 = y0
        h = t1 - t0

        def stage(t: RealScalarLike, inc: tuple[Vec3, PyTree] | None) -> tuple[Vec3, PyTree]:
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
        return (R1, x1), (R_err, x_err), dense_info
