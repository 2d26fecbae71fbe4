"""A Diffrax solver wrapper that maps the state at the end of every step (projection, chart
switch), telling the inner solver when the map changed the state so that FSAL reuse is skipped."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeAlias

import diffrax
import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, PyTree

from .._custom_types import VF, Args, BoolScalarLike, DenseInfo, RealScalarLike, Y

__all__ = ["StepEndMap"]

_Terms: TypeAlias = PyTree[diffrax.AbstractTerm]
_State: TypeAlias = tuple[PyTree, Bool[Array, ""]]
"""The inner solver's state and whether the last step end's map jumped."""


class StepEndMap(diffrax.AbstractSolver[_State]):
    """Wrap `solver`; after each accepted or rejected step apply `fn(y1) -> (y1', jumped)`.

    `jumped` (a boolean scalar) says that `y1'` differs from `y1` by more than rounding (e.g. the
    rotation vector was replaced by its shadow): the next step is then told `made_jump=True`, so a
    first-same-as-last solver re-evaluates the vector field instead of reusing a stale stage.
    Dense output (`SaveAt(ts=...)`) interpolates the inner solver's unmapped step, so callers map
    saved values again (e.g. normalise saved quaternions).
    """

    solver: diffrax.AbstractSolver
    fn: Callable[[Y], tuple[Y, Bool[Array, ""]]]  # a PyTree where it holds arrays

    @classmethod
    def wrap(
        cls,
        solver: diffrax.AbstractSolver,
        fn: Callable[[Y], tuple[Y, Bool[Array, ""]]],
        adjoint: diffrax.AbstractAdjoint,
    ) -> StepEndMap:
        """Wrap `solver`, choosing its `scan_kind` for `adjoint` as Diffrax does for an unwrapped
        Runge–Kutta solver (`"lax"` for `ForwardMode`, which cannot differentiate the bounded
        loop's custom VJP; `"bounded"` for `RecursiveCheckpointAdjoint`)."""
        if isinstance(solver, diffrax.AbstractRungeKutta) and solver.scan_kind is None:
            kind = {diffrax.ForwardMode: "lax", diffrax.RecursiveCheckpointAdjoint: "bounded"}
            if type(adjoint) in kind:
                solver = eqx.tree_at(
                    lambda s: s.scan_kind, solver, kind[type(adjoint)], is_leaf=lambda x: x is None
                )
        return cls(solver, fn)

    # Properties where Diffrax declares ClassVars, as Diffrax's own wrappers (`HalfSolver`) do.
    @property
    def term_structure(  # pyright: ignore[reportIncompatibleVariableOverride]
        self,
    ) -> PyTree[type[diffrax.AbstractTerm]]:
        return self.solver.term_structure

    @property
    def interpolation_cls(  # pyright: ignore[reportIncompatibleMethodOverride]
        self,
    ) -> Callable[..., diffrax.AbstractLocalInterpolation]:
        return self.solver.interpolation_cls

    def order(self, terms: _Terms) -> int | None:
        return self.solver.order(terms)

    def error_order(self, terms: _Terms) -> RealScalarLike | None:
        return self.solver.error_order(terms)

    def strong_order(self, terms: _Terms) -> RealScalarLike | None:
        return self.solver.strong_order(terms)

    def init(
        self, terms: _Terms, t0: RealScalarLike, t1: RealScalarLike, y0: Y, args: Args
    ) -> _State:
        return self.solver.init(terms, t0, t1, y0, args), jnp.array(False)

    def step(
        self,
        terms: _Terms,
        t0: RealScalarLike,
        t1: RealScalarLike,
        y0: Y,
        args: Args,
        solver_state: _State,
        made_jump: BoolScalarLike,
    ) -> tuple[Y, Y | None, DenseInfo, _State, diffrax.RESULTS]:
        inner_state, jumped = solver_state
        y1, y_err, dense_info, inner_state, result = self.solver.step(
            terms, t0, t1, y0, args, inner_state, jnp.logical_or(made_jump, jumped)
        )
        y1, jumped = self.fn(y1)
        return y1, y_err, dense_info, (inner_state, jumped), result

    def func(self, terms: _Terms, t0: RealScalarLike, y0: Y, args: Args) -> VF:
        return self.solver.func(terms, t0, y0, args)
