"""The classical fourth-order Runge–Kutta method as a Diffrax solver (fixed steps)."""

from __future__ import annotations

from typing import ClassVar

import diffrax
import numpy as np
from jaxtyping import PyTree

__all__ = ["RK4"]


class RK4(diffrax.AbstractERK):
    """Classical RK4 (Kutta 1901): four stages, order 4, no embedded error estimate — use it with
    `diffrax.ConstantStepSize` (or `StepTo`). Dense output: cubic Hermite. The fixed-step method
    of choice for large batches, where it does the same work per step as a hand-written kernel."""

    tableau: ClassVar[diffrax.ButcherTableau | diffrax.MultiButcherTableau] = (
        diffrax.ButcherTableau(
            c=np.array([0.5, 0.5, 1.0]),
            b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
            b_error=np.zeros(4),
            a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])),
        )
    )
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

    def order(self, terms: PyTree[diffrax.AbstractTerm]) -> int:
        return 4
