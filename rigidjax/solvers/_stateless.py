"""The base of the solvers that carry nothing from one step to the next (`ExplicitRK`, `RKMK`,
`ExactFreeBody`, `LiePoissonSplitting`): Diffrax's `init`, `step` and `func` written once, each
solver's own step in `_advance`."""

from __future__ import annotations

import abc

import diffrax

from .._custom_types import VF, Args, BoolScalarLike, DenseInfo, RealScalarLike, Y


class AbstractStatelessSolver(diffrax.AbstractSolver[None]):
    """A solver with no solver state: `init` gives None, `step` ignores `made_jump` (no stage is
    reused from the previous step, so a jump needs nothing), runs `_advance` and reports success,
    and `func` is the term's vector field."""

    @abc.abstractmethod
    def _advance(
        self, terms: diffrax.AbstractTerm, t0: RealScalarLike, t1: RealScalarLike, y0: Y, args: Args
    ) -> tuple[Y, Y | None, DenseInfo]:
        """One step from `y0` at `t0` to `t1`: `(y1, y_err, dense_info)`, `y_err` None for a
        solver without an error estimate."""

    def init(
        self, terms: diffrax.AbstractTerm, t0: RealScalarLike, t1: RealScalarLike, y0: Y, args: Args
    ) -> None:
        return None

    def step(
        self,
        terms: diffrax.AbstractTerm,
        t0: RealScalarLike,
        t1: RealScalarLike,
        y0: Y,
        args: Args,
        solver_state: None,
        made_jump: BoolScalarLike,
    ) -> tuple[Y, Y | None, DenseInfo, None, diffrax.RESULTS]:
        del solver_state, made_jump
        y1, y_err, dense_info = self._advance(terms, t0, t1, y0, args)
        return y1, y_err, dense_info, None, diffrax.RESULTS.successful

    def func(self, terms: diffrax.AbstractTerm, t0: RealScalarLike, y0: Y, args: Args) -> VF:
        return terms.vf(t0, y0, args)
