"""Conversion to and from other rotation libraries: SciPy's `Rotation` and jaxlie's `SO3`
(optional: imported only when called; rigidjax does not depend on jaxlie).

Both store unit quaternions: SciPy scalar-last `(x, y, z, w)` (`as_quat(scalar_first=True)`
gives rigidjax's order), jaxlie scalar-first in `SO3.wxyz`; the conversions copy the quaternion
and keep its sign.
"""

from __future__ import annotations

import importlib
from typing import Any

import jax.numpy as jnp
import numpy as np

from .._checks import vector
from .._custom_types import Quat, QuatLike
from . import _validation as _v
from ._quat_core import _unit

__all__ = ["from_jaxlie", "from_scipy", "to_jaxlie", "to_scipy"]


def from_scipy(rotation: Any) -> Quat:
    """Quaternions `(..., 4)` (scalar-first, float64 unless x64 is off) of a
    `scipy.spatial.transform.Rotation` (single or a batch of any shape)."""
    from scipy.spatial.transform import Rotation

    if not isinstance(rotation, Rotation):
        raise TypeError(
            "rotation must be a scipy.spatial.transform.Rotation, got "
            f"{type(rotation).__name__}; for a quaternion array use rigidjax.quat.from_xyzw"
        )
    return jnp.asarray(np.asarray(rotation.as_quat(scalar_first=True)))


def to_scipy(q: QuatLike) -> Any:
    """`scipy.spatial.transform.Rotation` of quaternions `q (..., 4)` (concrete, finite, non-zero;
    SciPy normalises them). Not traceable: SciPy works on NumPy arrays."""
    from scipy.spatial.transform import Rotation

    q = _v.check_quat(vector(q, 4, "q"), "q")
    return Rotation.from_quat(np.asarray(q, dtype=np.float64), scalar_first=True)


def _jaxlie() -> Any:
    try:
        return importlib.import_module("jaxlie")
    except ImportError as e:
        raise ImportError(
            "jaxlie is not installed: `pip install jaxlie` to convert to and from jaxlie.SO3 "
            "(rigidjax does not depend on it)"
        ) from e


def to_jaxlie(q: QuatLike) -> Any:
    """`jaxlie.SO3` of quaternions `q (..., 4)` (normalised; finite, non-zero), traceable."""
    return _jaxlie().SO3(wxyz=_unit(vector(q, 4, "q"), "q"))


def from_jaxlie(rotation: Any) -> Quat:
    """Quaternions `(..., 4)` (scalar-first, as stored) of a `jaxlie.SO3`, traceable."""
    SO3 = _jaxlie().SO3
    if not isinstance(rotation, SO3):
        raise TypeError(f"rotation must be a jaxlie.SO3, got {type(rotation).__name__}")
    return jnp.asarray(rotation.wxyz)
