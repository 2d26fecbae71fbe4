"""Rodrigues–Hamilton parameters (unit quaternions), scalar-first `(λ0, λ1, λ2, λ3)`.

Conventions (THEORY §3): Hamilton product, `λ0 = cos(θ/2)`, `λ = sin(θ/2) m`; `q` and `−q` are
the same rotation. Functions that map a quaternion to a rotation accept any non-zero `q` and treat
it as `q/|q|` (like SciPy).

Bad input is an error naming the argument: a zero or non-finite quaternion, a non-finite or
improper (det ≤ 0) matrix passed as a rotation. On concrete input (also the primal of an eager
`grad`/`jacfwd`/`jacrev`) it is a `ValueError` with the offending value and the fix; under
`jit`/`vmap` the same message comes from an `equinox.error_if` at run time. `from_matrix` and
`to_matrix` run as one compiled program per shape (`rotations._compiled`): their first eager
call, and that of their derivatives, costs one compilation. The algebra used inside integrators
(`mul`, `rotate`, `normalize`, `to_matrix`, `inv`) keeps a single check of `|q| > 0`, finite;
`from_matrix`, `to_rotvec`, `angle` and the other conversions check their arguments fully.

The primitives live in `rotations._quat_core`, which the modules below import too (none of them
imports this one); also here, from modules of their own: `mean` (`average`), `align_vectors`
(`align`), `power`, `magnitude`, `approx_equal` (`powers`), `rotation_group`, `reduce`
(`groups`), `from_scipy`, `to_scipy`, `from_jaxlie`, `to_jaxlie` (`interop`) and the
Cayley–Klein forms (`cayley_klein`).
"""

from ._quat_core import _from_rotvec as _from_rotvec  # kinematics' rotation-vector chart
from ._quat_core import (
    angle,
    canonical,
    conj,
    continuous,
    from_matrix,
    from_rotvec,
    from_xyzw,
    identity,
    inv,
    local,
    mul,
    norm2,
    normalize,
    random,
    retract,
    rotate,
    slerp,
    to_matrix,
    to_rotvec,
    to_xyzw,
)
from .align import align_vectors
from .average import mean
from .cayley_klein import (
    from_cayley_klein,
    from_su2,
    pauli,
    sigma_to_vec,
    su2_act,
    to_cayley_klein,
    to_su2,
    vec_to_sigma,
)
from .groups import reduce, rotation_group
from .interop import from_jaxlie, from_scipy, to_jaxlie, to_scipy
from .powers import approx_equal, magnitude, power

__all__ = [
    "align_vectors",
    "angle",
    "approx_equal",
    "canonical",
    "conj",
    "continuous",
    "from_cayley_klein",
    "from_jaxlie",
    "from_matrix",
    "from_rotvec",
    "from_scipy",
    "from_su2",
    "from_xyzw",
    "identity",
    "inv",
    "local",
    "magnitude",
    "mean",
    "mul",
    "norm2",
    "normalize",
    "pauli",
    "power",
    "random",
    "reduce",
    "retract",
    "rotate",
    "rotation_group",
    "sigma_to_vec",
    "slerp",
    "su2_act",
    "to_cayley_klein",
    "to_jaxlie",
    "to_matrix",
    "to_rotvec",
    "to_scipy",
    "to_su2",
    "to_xyzw",
    "vec_to_sigma",
]
