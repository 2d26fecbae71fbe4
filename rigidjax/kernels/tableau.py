"""The tableaux of the CPU kernels, written from the solvers' own Diffrax tableaux when a kernel is
built, so that the kernels and the Diffrax path cannot drift apart."""

from __future__ import annotations

import diffrax
import numpy as np
from jaxtyping import Float

from ..solvers.rk4 import RK4

METHODS: tuple[type[diffrax.AbstractERK], ...] = (
    RK4,
    diffrax.Heun,
    diffrax.Midpoint,
    diffrax.Ralston,
    diffrax.Bosh3,
    diffrax.Tsit5,
    diffrax.Dopri5,
    diffrax.Dopri8,
)
"""The solvers with a kernel (exactly these types: a subclass may change the tableau)."""
DTYPES = {"float64": "F64", "float32": "F32"}


def coefficients(method: type[diffrax.AbstractERK]) -> Float[np.ndarray, "rows stages"]:
    """The tableau of `method` as one `(S + 1, S)` array (S stages): rows `i < S` the stage
    coefficients `a_il`, row `S` the weights `b_l`; stages that never reach the solution (the
    first-same-as-last stage, which `ExplicitRK` evaluates only for the error estimate and
    dense output) are dropped."""
    a, keep = _tableau(method)
    return a[np.append(keep, a.shape[1])][:, keep]


ADAPTIVE: tuple[type[diffrax.AbstractERK], ...] = (
    diffrax.Bosh3,
    diffrax.Tsit5,
    diffrax.Dopri5,
    diffrax.Dopri8,
)
"""The embedded pairs with an adaptive kernel (`model_adaptive.h`)."""


def embedded(method: type[diffrax.AbstractERK]) -> Float[np.ndarray, "rows stages"]:
    """The whole tableau of an embedded pair as one `(S + 2, S)` array: rows `i < S` the stage
    coefficients, row `S` the weights `b_l`, row `S + 1` the error weights `e_l` (Diffrax's
    `b_error`); every stage kept (the last one of a first-same-as-last pair feeds the error)."""
    a = _tableau(method)[0]
    tab = method.tableau
    assert isinstance(tab, diffrax.ButcherTableau) and tab.b_error is not None
    return np.vstack([a, np.asarray(tab.b_error, dtype=float)[None]])


def all_stage_times(method: type[diffrax.AbstractERK]) -> Float[np.ndarray, " stages"]:
    """The stage times `c_i` of every stage."""
    tab = method.tableau
    assert isinstance(tab, diffrax.ButcherTableau)
    return np.concatenate([[float(tab.c1)], np.asarray(tab.c, dtype=float)])


def stage_times(method: type[diffrax.AbstractERK]) -> Float[np.ndarray, " stages"]:
    """The stage times `c_i` (stage i at `t + c_i h`) of the stages `coefficients` keeps."""
    return all_stage_times(method)[_tableau(method)[1]]


def _tableau(method: type[diffrax.AbstractERK]) -> tuple[np.ndarray, np.ndarray]:
    """The full `(S + 1, S)` coefficients and the indices of the stages that reach the
    solution."""
    tab = method.tableau
    assert isinstance(tab, diffrax.ButcherTableau)
    S = tab.num_stages
    a = np.zeros((S + 1, S))
    for i, row in enumerate(tab.a_lower):
        a[i + 1, : len(row)] = row
    a[S] = tab.b_sol
    live = np.zeros(S, bool)
    for i in reversed(range(S)):
        live[i] = a[S, i] != 0 or bool(np.any(live[i + 1 :] & (a[i + 1 : S, i] != 0)))
    return a, np.flatnonzero(live)
