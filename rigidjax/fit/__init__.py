"""Fitting models to data: inertia identification from gyro and attitude measurements."""

from .identify import InertiaEstimate, identify_inertia

__all__ = ["InertiaEstimate", "identify_inertia"]
