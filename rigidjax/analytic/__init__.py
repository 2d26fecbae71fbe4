"""Closed-form solutions: Jacobi elliptic functions and Carlson's integrals (`elliptic`), the
free rigid body (`euler_poinsot`, `poinsot_attitude`), the free symmetric top and rotation about
a fixed axis (`regular_precession`)."""

from . import elliptic, euler_poinsot, poinsot_attitude, regular_precession
from .elliptic import am, cn, dn, ellipj, ellipk, ellipkinc, ellipkm1, ellippi, sn
from .euler_poinsot import (
    FreeBodyParameters,
    flip_period,
    free_rigid_body,
    free_rigid_body_parameters,
    time_of_first_flip,
)
from .poinsot_attitude import free_body_flow, free_rigid_body_attitude
from .regular_precession import (
    SymmetricTopPrecession,
    fixed_axis_rotation,
    symmetric_top,
    symmetric_top_attitude,
    symmetric_top_precession,
)

__all__ = [
    "FreeBodyParameters",
    "SymmetricTopPrecession",
    "am",
    "cn",
    "dn",
    "elliptic",
    "ellipj",
    "ellipk",
    "ellipkinc",
    "ellipkm1",
    "ellippi",
    "euler_poinsot",
    "poinsot_attitude",
    "regular_precession",
    "fixed_axis_rotation",
    "flip_period",
    "free_body_flow",
    "free_rigid_body",
    "free_rigid_body_attitude",
    "free_rigid_body_parameters",
    "sn",
    "symmetric_top",
    "symmetric_top_attitude",
    "symmetric_top_precession",
    "time_of_first_flip",
]
