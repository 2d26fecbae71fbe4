"""Fitting models to data: inertia identification from gyro and attitude measurements of one or
several experiments (`identify_inertia`), and the design of the excitation that makes the
inertia best identifiable (`design_excitation`)."""

from .design import (
    ExcitationDesign,
    PiecewiseConstantTorque,
    design_excitation,
    fisher_information,
    prbs,
)
from .identify import InertiaEstimate, identify_inertia
from .losses import LOSSES

__all__ = [
    "LOSSES",
    "ExcitationDesign",
    "InertiaEstimate",
    "PiecewiseConstantTorque",
    "design_excitation",
    "fisher_information",
    "identify_inertia",
    "prbs",
]
