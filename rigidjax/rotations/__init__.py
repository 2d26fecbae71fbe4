"""Rotation maps: rotation tensor and vector (`so3`), quaternions (`quat`), Euler and Davenport
angles (`euler`), the Gibbs vector (`gibbs`), modified Rodrigues parameters (`mrp`) and
Andoyer–Deprit variables (`andoyer`). Pure functions with leading batch dimensions.

Completed against SciPy's `Rotation`: `quat.align_vectors` (`align`), `RotationSpline`
(`spline`), multi-key `Slerp` (`slerp`), `quat.power`/`magnitude`/`approx_equal` (`powers`),
`quat.rotation_group`/`reduce` (`groups`), `quat.from_scipy`/`to_scipy`/`from_jaxlie`/`to_jaxlie`
(`interop`)."""

from . import (
    align,
    andoyer,
    average,
    cayley_klein,
    davenport,
    euler,
    gibbs,
    groups,
    interop,
    mrp,
    powers,
    quat,
    slerp,
    so3,
    spline,
)
from .slerp import Slerp
from .spline import RotationSpline

__all__ = [
    "RotationSpline",
    "Slerp",
    "align",
    "andoyer",
    "average",
    "cayley_klein",
    "davenport",
    "euler",
    "gibbs",
    "groups",
    "interop",
    "mrp",
    "powers",
    "quat",
    "slerp",
    "so3",
    "spline",
]
