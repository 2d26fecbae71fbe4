"""Stationary rotations of the free rigid body and their linear stability.

Sources: Zegrya–Parshin lectures (004, §12, (12.41)–(12.50)); exercises (002:
stationary solutions of Euler's equations and their first-approximation systems); THEORY §6.

**Stationary rotations.** Euler's equations without torque, `I Ω̇ + Ω × IΩ = 0`, have `Ω̇ = 0`
exactly when `Ω × IΩ = 0`, i.e. Ω is a principal axis: `Ω = Ω0 e_k` (in principal axes).

**Linearisation.** With `Ω = Ω0 e_k + δΩ` and `(i, j)` the other two axes, Euler's equations in
principal axes (`I_i Ω̇_i = (I_j − I_k) Ω_j Ω_k`, cyclic) give to first order

    δΩ̇_i = Ω0 (I_j − I_k)/I_i · δΩ_j,    δΩ̇_j = Ω0 (I_k − I_i)/I_j · δΩ_i,    δΩ̇_k = 0,

(for k = 2 this is (12.44) of 004), so the characteristic polynomial `det(λE − A)` of the
Jacobian `A` is

    λ (λ² + κ_k Ω0²),        κ_k = (I_k − I_i)(I_k − I_j) / (I_i I_j)                  (★)

(symmetric in i, j, so the order of the other two axes does not matter). Two general facts make
this form exact for ANY inertia tensor, not only in principal axes: `tr A = 0` (the Euler flow
is divergence free) and `det A = 0` (`A Ω0 e_k = 0`: a scaled stationary rotation is still
stationary). Hence the eigenvalues are `0, ±√(−κ_k) Ω0`:

- `κ_k > 0` (I_k the largest or the smallest moment): `λ = ±i Ω0 √κ_k`, small oscillations
  (the rotation is stable; the nonlinear motion stays close, by the energy and |M|² integrals);
- `κ_k < 0` (I_k the middle moment): `λ = ±p`, with, for I1 < I2 < I3 and k = 2,
  `p = Ω0 √((I3 − I2)(I2 − I1)/(I1 I3))` — 004 (12.49); perturbations grow as `e^{pt}` (12.50)
  (the "tennis-racket" / Dzhanibekov instability);
- `κ_k = 0` (I_k equals one of the other moments — a symmetric top rotating about an equatorial
  axis, or a spherical top), or `Ω0 = 0`: all eigenvalues vanish and the linearisation decides
  nothing. This module calls it **neutral**. (Spherical top: every rotation is stationary and
  perturbations stay constant. Symmetric top `I1 = I2` about e1: δΩ3 is constant and δΩ2 grows
  LINEARLY, `δΩ2 = Ω0 (I3 − I1)/I2 · δΩ3 · t`, no exponential growth; the nonlinear motion is a
  slow regular precession that carries Ω far from e1, so it is not Lyapunov stable.)

**Axes.** `inertia` is either the principal moments `(..., 3)` — then axis k is body e_k, in the
order given (they need not be sorted) — or a symmetric tensor `(..., 3, 3)` — then axis k is the
k-th principal axis in ASCENDING order of the moments (as `rigidjax.inertia.principal_axes`), so
for a tensor axis 1 is always the middle one. Functions broadcast over leading batch dimensions
of `inertia`, `axis` and `omega0` and are jit/vmap/grad friendly; `classify` is the only
Python-level (concrete-input) function, `stability_code` is its traceable twin.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from .._checks import as_float, check_shape, is_concrete, matrix, validate
from .._custom_types import (
    AxisLike,
    InertiaLike,
    Mat33,
    Mat33Like,
    Scalar,
    ScalarLike,
    Vec3,
    Vec3Like,
)
from .body import euler_rhs
from .inertia import as_tensor, check_inertia, diagonal, principal_axes

__all__ = [
    "characteristic_coefficients",
    "characteristic_polynomial",
    "classify",
    "eigenvalues",
    "growth_rate",
    "jacobian",
    "linearization",
    "middle_axis_growth_rate",
    "oscillation_frequency",
    "stability_coefficient",
    "stability_code",
    "stationary_rotation",
]

STABLE, NEUTRAL, UNSTABLE = 1, 0, -1
_NAMES = {STABLE: "stable", NEUTRAL: "neutral", UNSTABLE: "unstable"}


# --------------------------------------------------------------------------- input handling


def _inertia(inertia: InertiaLike) -> tuple[Mat33 | Vec3, bool]:
    """`(I, is_tensor)` after the validity checks of `rigidjax.inertia.check_inertia`."""
    I = as_float(inertia, "inertia")
    tensor = I.ndim >= 2 and I.shape[-2:] == (3, 3)
    if not tensor:
        check_shape(I, (3,), "inertia")
    T = check_inertia(as_tensor(I), "inertia")  # traced: the check rides on T, so use it
    return (T if tensor else diagonal(T)), tensor


def _axis(axis: AxisLike) -> Int[Array, "*#batch"]:
    a = jnp.asarray(axis)
    if not jnp.issubdtype(a.dtype, jnp.integer):
        raise TypeError(f"axis must be an integer 0, 1 or 2, got dtype {a.dtype}")
    if is_concrete(a):
        if not bool(jnp.all((a >= 0) & (a <= 2))):
            raise ValueError(f"axis must be 0, 1 or 2 (a principal axis), got {np.asarray(a)}")
        return a
    return validate(a, lambda xp, a: (a < 0) | (a > 2), "axis must be 0, 1 or 2")


def _core(tensor: bool) -> str:
    return "(3,3)" if tensor else "(3)"


def _frame(I: Array, tensor: bool) -> tuple[Array, Array, Array, Array]:
    """Single body: `(op, op_inv, moments, axes)` — the operator pair for `euler_rhs`, the
    principal moments and the principal axes as columns."""
    if tensor:
        moments, axes = principal_axes(I)
        return I, jnp.linalg.inv(I), moments, axes
    return I, 1 / I, I, jnp.eye(3, dtype=I.dtype)


def _others(moments: Array, k: Array) -> tuple[Array, Array, Array]:
    """`(I_k, I_i, I_j)` for a (possibly traced) axis index k, (i, j) = (k+1, k+2) mod 3."""
    return moments[k], moments[(k + 1) % 3], moments[(k + 2) % 3]


def _kappa(moments: Array, k: Array) -> Array:
    Ik, Ii, Ij = _others(moments, k)
    return (Ik - Ii) * (Ik - Ij) / (Ii * Ij)


# --------------------------------------------------------------------------- public API


def stationary_rotation(inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0) -> Vec3:
    """The stationary solution `Ω = Ω0 e_k` of the free Euler equations (body components):
    `omega0` times principal axis `axis` (see the module docstring for the axis convention)."""
    I, tensor = _inertia(inertia)
    w0 = as_float(omega0, "omega0").astype(I.dtype)
    return _stationary(I, _axis(axis), w0, tensor)


@partial(jax.jit, static_argnames="tensor")
def _stationary(I, k, w0, tensor):
    def one(I, k, w0):
        return w0 * _frame(I, tensor)[3][:, k]

    return jnp.vectorize(one, signature=f"{_core(tensor)},(),()->(3)")(I, k, w0)


def jacobian(inertia: InertiaLike, omega: Vec3Like) -> Mat33:
    """`∂Ω̇/∂Ω` of the torque-free Euler equations `Ω̇ = −I⁻¹(Ω × IΩ)` at any `omega`
    (`jax.jacfwd` of `rigidjax.body.euler_rhs`); general tensor or principal moments."""
    I, tensor = _inertia(inertia)
    omega = as_float(omega, "omega").astype(I.dtype)
    check_shape(omega, (3,), "omega")
    return _jacobian(I, omega, tensor)


@partial(jax.jit, static_argnames="tensor")
def _jacobian(I, omega, tensor):
    def one(I, w):
        op, op_inv, _, _ = _frame(I, tensor)
        return jax.jacfwd(lambda w: euler_rhs(op, op_inv, w, jnp.zeros_like(w)))(w)

    return jnp.vectorize(one, signature=f"{_core(tensor)},(3)->(3,3)")(I, omega)


def linearization(inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0) -> Mat33:
    """The matrix `A` of the first-approximation system `δΩ̇ = A δΩ` about the stationary
    rotation `Ω0 e_k` (body components; in principal axes the system of 002 / 004 (12.44))."""
    return jacobian(inertia, stationary_rotation(inertia, axis, omega0))


def characteristic_coefficients(A: Mat33Like) -> Float[Array, "*#batch 4"]:
    """Coefficients of `det(λE − A) = λ³ − tr A λ² + ½(tr²A − tr A²) λ − det A` of any 3×3
    matrix, highest power first (NumPy `np.roots` order)."""
    A = matrix(A, "A")
    tr = jnp.trace(A, axis1=-2, axis2=-1)
    tr2 = jnp.sum(A * jnp.swapaxes(A, -1, -2), axis=(-2, -1))
    return jnp.stack([jnp.ones_like(tr), -tr, 0.5 * (tr * tr - tr2), -jnp.linalg.det(A)], -1)


def stability_coefficient(inertia: InertiaLike, axis: AxisLike) -> Scalar:
    """`κ_k = (I_k − I_i)(I_k − I_j)/(I_i I_j)` of (★): > 0 stable (largest or smallest
    moment), < 0 unstable (middle moment), 0 degenerate (neutral)."""
    I, tensor = _inertia(inertia)
    return _stability_coefficient(I, _axis(axis), tensor)


@partial(jax.jit, static_argnames="tensor")
def _stability_coefficient(I, k, tensor):
    def one(I, k):
        return _kappa(_frame(I, tensor)[2], k)

    return jnp.vectorize(one, signature=f"{_core(tensor)},()->()")(I, k)


def characteristic_polynomial(
    inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0
) -> Float[Array, "*#batch 4"]:
    """Closed form (★) of the characteristic polynomial of `linearization(...)`:
    `λ³ + κ_k Ω0² λ`, as coefficients `[1, 0, κ_k Ω0², 0]` (highest power first)."""
    kappa = stability_coefficient(inertia, axis)
    w0 = as_float(omega0, "omega0").astype(kappa.dtype)
    c = kappa * w0 * w0
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack([one, zero, c, zero], -1)


def _half_trace_square(inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike) -> Scalar:
    """`s = ½ tr(A²) = −κ_k Ω0²` from the jacfwd linearisation A (the char. polynomial is
    `λ(λ² − s)` since tr A = det A = 0 at a stationary rotation)."""
    A = linearization(inertia, axis, omega0)
    return 0.5 * jnp.sum(A * jnp.swapaxes(A, -1, -2), axis=(-2, -1))


def _sqrt_pos(x: Scalar) -> Scalar:
    """`√max(x, 0)` with a finite (zero) gradient where x ≤ 0."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def eigenvalues(
    inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0
) -> Complex[Array, "*#batch 3"]:
    """Eigenvalues of the jacfwd linearisation about `Ω0 e_k`, as `(√s, 0, −√s)` with
    `s = ½ tr(A²) = −κ_k Ω0²` (exact because tr A = det A = 0 there; see the module docstring):
    `(p, 0, −p)` for the middle axis, `(iν, 0, −iν)` for a stable one. Works on any device
    (no general eigensolver) and under jit/vmap; the derivative is infinite where s = 0."""
    s = _half_trace_square(inertia, axis, omega0)
    cdtype = jnp.result_type(s.dtype, jnp.complex64)
    r = jnp.sqrt(s.astype(cdtype))
    return jnp.stack([r, jnp.zeros_like(r), -r], -1)


def growth_rate(inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0) -> Scalar:
    """Largest real part of the eigenvalues of the jacfwd linearisation about `Ω0 e_k`:
    `√max(½ tr A², 0)` — the exponential growth rate p of 004 (12.49)–(12.50) for the middle axis,
    0 for the others. jit/vmap/grad friendly (zero gradient where the axis is not unstable)."""
    return _sqrt_pos(_half_trace_square(inertia, axis, omega0))


def oscillation_frequency(inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0) -> Scalar:
    """Angular frequency `|Ω0| √κ_k` of small oscillations about a stable axis (the imaginary
    part of the eigenvalues; 0 for the middle and degenerate axes), from the jacfwd
    linearisation. For a symmetric top about its symmetry axis it is the body-frame precession
    rate `|Ω3 (I3 − I1)/I1|` of THEORY §6."""
    return _sqrt_pos(-_half_trace_square(inertia, axis, omega0))


def middle_axis_growth_rate(inertia: InertiaLike, omega0: ScalarLike = 1.0) -> Scalar:
    """004 (12.49) in closed form: `p = |Ω0| √((I3 − I2)(I2 − I1)/(I1 I3))` with the principal
    moments sorted `I1 ≤ I2 ≤ I3` (whatever order they are given in)."""
    I, tensor = _inertia(inertia)
    m = principal_axes(I)[0] if tensor else jnp.sort(I, axis=-1)
    I1, I2, I3 = m[..., 0], m[..., 1], m[..., 2]
    w0 = as_float(omega0, "omega0").astype(I.dtype)
    return jnp.abs(w0) * _sqrt_pos((I3 - I2) * (I2 - I1) / (I1 * I3))


def stability_code(
    inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0, rtol: float = 1e-9
) -> Int[Array, "*#batch"]:
    """Traceable classification: `1` stable (κ_k > 0), `-1` unstable (κ_k < 0), `0` neutral —
    `Ω0 = 0`, or I_k within `rtol · max moment` of another moment (symmetric / spherical
    degeneracy, where the linearisation has only zero eigenvalues)."""
    I, tensor = _inertia(inertia)
    w0 = as_float(omega0, "omega0").astype(I.dtype)
    return _stability_code(I, _axis(axis), w0, float(rtol), tensor)


@partial(jax.jit, static_argnames=("rtol", "tensor"))
def _stability_code(I, k, w0, rtol, tensor):
    def one(I, k, w0):
        m = _frame(I, tensor)[2]
        Ik, Ii, Ij = _others(m, k)
        tol = rtol * jnp.max(jnp.abs(m))
        degenerate = (jnp.abs(Ik - Ii) <= tol) | (jnp.abs(Ik - Ij) <= tol) | (w0 == 0)
        code = jnp.where(_kappa(m, k) > 0, STABLE, UNSTABLE)
        return jnp.where(degenerate, NEUTRAL, code).astype(jnp.int32)

    return jnp.vectorize(one, signature=f"{_core(tensor)},(),()->()")(I, k, w0)


def classify(
    inertia: InertiaLike, axis: AxisLike, omega0: ScalarLike = 1.0, rtol: float = 1e-9
) -> str | np.ndarray:
    """`"stable"`, `"unstable"` or `"neutral"` for the stationary rotation `Ω0 e_k` (linear
    stability, see `stability_code` and the module docstring for "neutral": the symmetric or
    spherical degenerate case, or Ω0 = 0). A string for one body, a NumPy array of strings for a
    batch. Needs concrete inputs; under jit/vmap use `stability_code`."""
    code = stability_code(inertia, axis, omega0, rtol)
    if not is_concrete(code):
        raise TypeError("classify needs concrete inputs; use stability_code under jit/vmap")
    code = np.asarray(code)
    if code.ndim == 0:
        return _NAMES[int(code)]
    return np.vectorize(_NAMES.__getitem__, otypes=[object])(code).astype(str)
