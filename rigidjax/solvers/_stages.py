"""Explicit Runge–Kutta stages unrolled in Python, shared by `ExplicitRK` and `RKMK`.

Diffrax's generic Runge–Kutta loops over stages with `lax.scan`; on CPU, for batched states,
unrolled stages that XLA fuses into one loop body ran about twice as fast (benchmarks/).
"""

from __future__ import annotations

from collections.abc import Callable

import diffrax
import equinox as eqx
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jaxtyping import Array, Float, PyTree

from .._custom_types import RealScalarLike
from ._stateless import AbstractStatelessSolver


def tableau_of(method: diffrax.AbstractSolver) -> diffrax.ButcherTableau:
    """The Butcher tableau of an explicit Diffrax Runge–Kutta solver (clear error otherwise:
    the method reaches here as a `solver=` or as `ExplicitRK`'s or `RKMK`'s `method`)."""
    tab = getattr(type(method), "tableau", None)
    if not isinstance(tab, diffrax.ButcherTableau) or tab.implicit:
        why = "is implicit" if isinstance(tab, diffrax.ButcherTableau) else "has no Butcher tableau"
        raise ValueError(
            "the Runge–Kutta method (the solver, or the method of ExplicitRK and RKMK) must be "
            "one with an explicit Butcher tableau, such as diffrax.Tsit5(), diffrax.Dopri5() or "
            f"rigidjax.RK4(); {type(method).__name__} {why}"
        )
    return tab


def lincomb(coeffs: Float[np.ndarray, " k"], trees: list[PyTree]) -> PyTree:
    """Σ c_k trees[k], skipping zero coefficients (PyTrees, possibly None)."""
    pairs = [(float(c), t) for c, t in zip(coeffs, trees, strict=False) if c != 0]
    if not pairs:
        return jtu.tree_map(jnp.zeros_like, trees[0])

    def comb(*leaves):
        out = pairs[0][0] * leaves[0]
        for (c, _), leaf in zip(pairs[1:], leaves[1:], strict=True):
            out = out + c * leaf
        return out

    return jtu.tree_map(comb, *[t for _, t in pairs])


Lanes = RealScalarLike | Float[Array, " bodies"]
"""A time or step size: a scalar, or one per body (the adaptive Pallas kernel's, each body its
own step)."""


def increment(h: Lanes, coeffs: Float[np.ndarray, " k"], ks: list[PyTree]) -> PyTree:
    """h Σ c_k k_k (`h` a scalar, or one per body: the adaptive Pallas kernel's)."""
    return jtu.tree_map(lambda d: h * d, lincomb(coeffs, ks))


def stages(
    tab: diffrax.ButcherTableau,
    t0: Lanes,
    h: Lanes,
    stage: Callable[[Lanes, PyTree | None], PyTree],
) -> list[PyTree]:
    """Stage derivatives `k_i = stage(t0 + c_i h, h Σ_j a_ij k_j)`; the first stage gets `None`
    as its (zero) increment. `t0` and `h` are scalars, or one per body (the adaptive Pallas
    kernel's, each body its own step)."""
    ks: list[PyTree] = []
    for i in range(tab.num_stages):
        if i == 0:
            ks.append(stage(t0 + float(tab.c1) * h, None))
        else:
            inc = increment(h, tab.a_lower[i - 1], ks)
            ks.append(stage(t0 + float(tab.c[i - 1]) * h, inc))
    return ks


def stacked(h: RealScalarLike, ks: list[PyTree]) -> PyTree:
    """Stage increments `h k_i` stacked on a leading axis, as Diffrax's dense outputs take them."""
    return jtu.tree_map(lambda *leaves: h * jnp.stack(leaves), *ks)


class AbstractTableauSolver(AbstractStatelessSolver):
    """A solver that runs the stages of the explicit Runge–Kutta `method` itself (`ExplicitRK`,
    `RKMK`): validation, order and embedded-error order come from `method`; no solver state."""

    method: eqx.AbstractVar[diffrax.AbstractRungeKutta]

    def __check_init__(self) -> None:
        tableau_of(self.method)

    def order(self, terms: PyTree[diffrax.AbstractTerm]) -> int | None:
        return self.method.order(terms)

    def error_order(self, terms: PyTree[diffrax.AbstractTerm]) -> RealScalarLike | None:
        return self.method.error_order(terms)
