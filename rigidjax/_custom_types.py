"""The type aliases of rigidjax, in one place (as Diffrax's `_custom_types`).

Shapes are jaxtyping's: `*#batch` stands for any number of leading batch dimensions, which
broadcast between the arguments of a function and give the batch shape of its result (so a
`(3,)` vector and a `(5, 3)` batch of vectors go together; `(2, 3)` and `(5, 3)` do not).

**Results** (`Scalar`, `Vec3`, `Quat`, `Mat33`, `CMat22`) are JAX arrays, and the runtime
checker (the jaxtyping import hook with beartype, `--jaxtyping-packages=rigidjax,beartype.beartype`
in the tests) checks their dtype kind, trailing shape and the agreement of the batch shapes.

**Arguments** (`...Like`) are anything `jax.numpy.asarray` takes: JAX and NumPy arrays, NumPy and
Python scalars, and (nested) lists and tuples of them. The shapes in their definitions below say
what the functions accept; the functions validate their arguments themselves and raise a
`ValueError` (or `TypeError`) that names the argument and the expected shape or values, also
under `jit` (see `rigidjax._checks`). That check is part of the API and is tested, so at run time
these aliases only check that an argument is array-like: a runtime shape check here would
pre-empt the function's own error by a less specific `jaxtyping.TypeCheckError`. The same holds
for `Frame`, `EulerSeq` and `AxisLike`, whose values the functions validate. Arguments of other
shapes are written `Annotated[RealLike, "*#batch N 4"]`. Arguments that a function does not
validate itself (arrays passed between the library's own functions, e.g. `body.euler_rhs`) are
annotated with the result aliases or inline jaxtyping types, which the runtime checker enforces.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeAlias

import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Complex, Float, Int, Num, PyTree, Real, Shaped

__all__ = [
    "Args",
    "AxisLike",
    "BoolScalarLike",
    "CMat22",
    "CMat22Like",
    "DavenportAxesLike",
    "DenseInfo",
    "EulerSeq",
    "Frame",
    "InertiaLike",
    "Mat33",
    "Mat33Like",
    "Quat",
    "QuatLike",
    "RealLike",
    "RealScalarLike",
    "Scalar",
    "ScalarLike",
    "TimesLike",
    "VF",
    "Vec3",
    "Vec3Like",
    "Y",
]

# --------------------------------------------------------------------------- results

Scalar: TypeAlias = Float[Array, "*#batch"]
"""A scalar per batch element (shape = the batch shape; `()` for one body/rotation)."""
Vec3: TypeAlias = Float[Array, "*#batch 3"]
"""3-vectors: rotation vectors, angular velocities and momenta, Euler angles, principal moments."""
Quat: TypeAlias = Float[Array, "*#batch 4"]
"""Quaternions, scalar-first `(λ0, λ1, λ2, λ3)`."""
Mat33: TypeAlias = Float[Array, "*#batch 3 3"]
"""3×3 matrices: rotation tensors, inertia tensors, Jacobians."""
CMat22: TypeAlias = Complex[Array, "*#batch 2 2"]
"""Complex 2×2 matrices (Cayley–Klein, SU(2), `r·σ`)."""

# --------------------------------------------------------------------------- arguments

if TYPE_CHECKING:
    # What a static checker sees (to it jaxtyping's `Real[X, "..."]` is `X`); the shapes are
    # written out for the reader.
    _Nested: TypeAlias = "Sequence[ArrayLike | _Nested]"

    RealLike: TypeAlias = Real[ArrayLike, "..."] | _Nested
    ScalarLike: TypeAlias = Real[ArrayLike, "*#batch"] | _Nested
    TimesLike: TypeAlias = Real[ArrayLike, " T"] | Real[ArrayLike, ""] | _Nested
    Vec3Like: TypeAlias = Real[ArrayLike, "*#batch 3"] | _Nested
    QuatLike: TypeAlias = Real[ArrayLike, "*#batch 4"] | _Nested
    Mat33Like: TypeAlias = Real[ArrayLike, "*#batch 3 3"] | _Nested
    CMat22Like: TypeAlias = Num[ArrayLike, "*#batch 2 2"] | _Nested
    AxisLike: TypeAlias = Int[ArrayLike, "*#batch"] | _Nested
    Frame: TypeAlias = Literal["space", "body"]
    EulerSeq: TypeAlias = str
else:
    _Input = ArrayLike | Sequence[Any]

    RealLike = _Input
    ScalarLike = _Input
    TimesLike = _Input
    Vec3Like = _Input
    QuatLike = _Input
    Mat33Like = _Input
    CMat22Like = _Input
    AxisLike = _Input
    Frame = object
    EulerSeq = object

InertiaLike: TypeAlias = Vec3Like | Mat33Like
"""Principal moments `(..., 3)` or an inertia tensor `(..., 3, 3)`."""
DavenportAxesLike: TypeAlias = Mat33Like | Annotated[RealLike, "*#batch 2 3"]
"""Axes `(m, e, n)` or `(m, n)` of generalized Euler angles, as rows (`rigidjax.euler`)."""

# --------------------------------------------------------------------------- solvers (as Diffrax)

if TYPE_CHECKING:
    RealScalarLike: TypeAlias = int | float | Array | np.ndarray
    BoolScalarLike: TypeAlias = bool | Array | np.ndarray
else:
    RealScalarLike = Real[ArrayLike, ""]
    BoolScalarLike = Bool[ArrayLike, ""]

Y: TypeAlias = PyTree[Shaped[ArrayLike, "?*y"], "Y"]
"""An ODE state: any PyTree of arrays (the same structure and shapes for `y0`, `y1`, `y_err`)."""
VF: TypeAlias = PyTree[Shaped[ArrayLike, "?*vf"], "VF"]
"""The value of a vector field."""
Args: TypeAlias = PyTree[Any]
"""The `args` of `diffrax.diffeqsolve`."""
DenseInfo: TypeAlias = dict[str, PyTree[Array]]
"""What a solver step hands to its dense-output interpolation."""
