"""The Darboux problem: the rotation P(t) from a given angular velocity (Zhilin 3.12–3.14)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Unpack, cast

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._checks import as_float, check_finite, check_times, matrix, norm_tolerance, validate
from .._custom_types import Frame, RealLike
from .._integrate import SolveKwargs, SolveOptions, solve_saved
from .._tolerances import default_controller
from ..models.solve import solve_tree
from ..rotations import so3
from ..solvers.rkmk import LieTerm
from .formulations import (
    AbstractKinematics,
    PoissonMatrix,
    Quaternion,
    RotationVector,
    check_omega,
    lookup,
)

__all__ = ["OmegaLike", "darboux", "omega_path"]

OmegaLike = Callable[[Array], Array] | diffrax.AbstractPath | tuple[ArrayLike, ArrayLike]


def _source(omega: OmegaLike) -> Callable[[Array], Array] | diffrax.AbstractPath:
    """`omega` as a callable or a Diffrax path (samples become a cubic Hermite path)."""
    if isinstance(omega, diffrax.AbstractPath):
        return omega
    if isinstance(omega, tuple):
        if len(omega) != 2:
            raise ValueError(
                "sampled omega_fn must be a pair (t_samples (N,), omega_samples (N, 3))"
            )
        t_s, w_s = as_float(omega[0], "omega t_samples"), as_float(omega[1], "omega samples")
        if t_s.ndim != 1 or w_s.shape != (t_s.shape[0], 3) or t_s.shape[0] < 2:
            raise ValueError(
                f"sampled omega_fn must be (t (N,), omega (N, 3)) with N ≥ 2, got shapes "
                f"{tuple(t_s.shape)} and {tuple(w_s.shape)}"
            )
        t_s = check_times(t_s, "omega t_samples")
        w_s = check_finite(w_s, "omega samples")
        coeffs = diffrax.backward_hermite_coefficients(t_s, w_s)
        return diffrax.CubicInterpolation(t_s, coeffs)
    if callable(omega):
        return omega
    raise TypeError(
        f"omega_fn must be a callable t -> (3,), a diffrax path or (t, omega), got {omega!r}"
    )


def _frame_and_seq(
    method: str | AbstractKinematics, frame: Frame | None, seq: str | None
) -> tuple[Frame, str]:
    """`frame` and `seq` with their defaults, or an instance's own (a conflict is an error: it
    was ignored, and the instance's frame integrated)."""
    if not isinstance(method, AbstractKinematics):
        return ("space" if frame is None else frame), ("ZXZ" if seq is None else seq)
    own_seq = getattr(method, "seq", None)
    for name, given, own in (("frame", frame, method.frame), ("seq", seq, own_seq)):
        if given is not None and own is not None and given != own:
            raise ValueError(
                f"{name}={given!r} disagrees with the method instance's {name}={own!r}: leave "
                f"{name} out (the instance's is used) or build the instance with it"
            )
    return method.frame, ("ZXZ" if own_seq is None else own_seq)


def omega_path(omega: OmegaLike) -> Callable[[Array], Array]:
    """A callable `t -> (3,)` from a callable, a Diffrax path, or sampled data `(t_k, ω_k)`.

    Samples (e.g. gyro readings) are interpolated by a C¹ cubic Hermite spline with backward
    differences (`diffrax.backward_hermite_coefficients`). Its second derivative jumps at the
    knots, which an adaptive controller does not see: `darboux` ends its adaptive steps at the
    sample times (of any Diffrax path with knots `ts`); a callable from this function carries no
    knots, so a solve of it should end steps there itself (`diffrax.ClipStepSizeController(...,
    step_ts=t_k)`) or take fixed steps that divide the sample spacing.
    """
    source = _source(omega)
    return source.evaluate if isinstance(source, diffrax.AbstractPath) else source


def _knots_as_step_ends(options: SolveOptions, path: diffrax.AbstractPath, dtype) -> SolveOptions:
    """`options` with the steps ending at the knots of an interpolated ω, where its higher
    derivatives jump unseen by an adaptive controller (601 samples at rtol = atol = 1e-10: an
    error of 1e-6 stepping across them). The default controller or a plain `PIDController` is
    wrapped in `diffrax.ClipStepSizeController(step_ts=knots)`; another is used as given."""
    knots = getattr(path, "ts", None)
    controller = options.stepsize_controller
    if knots is None or not (controller is None or type(controller) is diffrax.PIDController):
        return options
    if controller is None:
        controller = default_controller(dtype, options.rtol, options.atol)
    # (Diffrax's own __init__: the checker reads the fields as its parameters)
    clipped = _KnotClip(controller, step_ts=jnp.asarray(knots, dtype))  # pyright: ignore[reportCallIssue]
    return dataclasses.replace(options, stepsize_controller=clipped)


class _KnotClip(diffrax.ClipStepSizeController):
    """`diffrax.ClipStepSizeController` whose `step_ts` (sorted once, when it is built) are
    not sorted again by every `diffeqsolve`: Diffrax's `wrap` sorts them for each call, and
    `darboux` makes one call per output interval, so that sampled ω with as many outputs as
    samples took time quadratic in their number (1.2e4 samples, an output at each: 9 s a call;
    0.75 s with the knots sorted once, 0.31 s without the clipping)."""

    def wrap(self, direction):
        ts = cast(Array, self.step_ts)
        step_ts = jnp.where(direction > 0, ts, -ts[::-1])  # = sort(ts · direction)
        return eqx.tree_at(
            lambda c: (c.step_ts, c.controller), self, (step_ts, self.controller.wrap(direction))
        )


def _check_span(ts: Array, path: diffrax.AbstractPath) -> Array:
    """`ts`, checked to lie within the span `[t0, t1]` of a path (sampled ω is not extrapolated)."""
    t0, t1 = path.t0, path.t1

    def detail(t: np.ndarray) -> str:
        return (
            f": ts spans [{t[0]:.6g}, {t[-1]:.6g}], the samples [{float(t0):.6g}, {float(t1):.6g}]"
        )

    return validate(
        ts,
        lambda xp, t: (t[0] < t0) | (t[-1] > t1),
        "ts must lie within the times of the omega samples (they are interpolated, never "
        "extrapolated)",
        detail,
        hint="; trim ts to the sampled interval",
    )


class _KinematicsField(eqx.Module):
    """`(t, y) -> ẏ` of a kinematics formulation driven by `omega(t)` (a stable, hashable
    callable, so repeated solves with the same `omega` reuse one compilation)."""

    kin: AbstractKinematics
    omega: Callable

    def __call__(self, t, y, args):
        return self.kin.vector_field(y, check_omega(self.omega(t)).astype(y.dtype))


class _LieField(eqx.Module):
    """`(t, (R, None)) -> (ω, None)` for the RKMK solver."""

    omega: Callable

    def __call__(self, t, y, args):
        return check_omega(self.omega(t)).astype(y[0].dtype), None


def darboux(
    omega_fn: OmegaLike,
    ts: RealLike,
    P0: RealLike | None = None,
    frame: Frame | None = None,
    method: str | AbstractKinematics = "rotvec",
    *,
    seq: str | None = None,
    return_state: bool = False,
    options: SolveOptions | None = None,
    **solve_kwargs: Unpack[SolveKwargs],
) -> Float[Array, "T 3 3"] | tuple[Float[Array, "T 3 3"], Array]:
    """Solve `Ṗ = ω(t) × P` (`frame="space"`) or `Ṗ = P (Ω(t) × E)` (`frame="body"`) with
    `P(ts[0]) = P0` and return P at `ts` (Zhilin 3.12; the solution is unique and a rotation).

    `omega_fn`: a callable `t -> (3,)`, a Diffrax path, or samples `(t_k, ω_k)` (gyro data;
    see `omega_path`). `method`: `"rotvec"` (θ̇ = Z(θ) ω with shadow switching, Zhilin 3.14),
    `"quat"`, `"matrix"` (Poisson equation, drifts off SO(3)), `"euler"` (sequence `seq`, with a
    partner chart it switches to near gimbal lock: `EulerAngles`), `"cayley_klein"`,
    `"geometric"` (RKMK Lie-group solver, exactly on SO(3)), or an
    `AbstractKinematics` instance (which carries its frame and sequence: `frame` and `seq`, if
    given, must agree with them). `frame` defaults to `"space"`, `seq` to `"ZXZ"`. Solver
    defaults: Tsit5 with unrolled stages (`ExplicitRK`; RKMK-Dopri5 for `"geometric"`) with a
    PID controller at `rtol = atol = 1e-10` (1e-6 in float32). Steps end at every output time
    (and at the knots of sampled ω, see `omega_path`) and the values at `ts` are step-end
    states (`solve_saved`); `throw=False` is refused (only the rotations are returned, no
    failure status). `return_state=True` also returns the native states at `ts`
    (normalised quaternions, shadowed rotation vectors, ...). With a callable `omega_fn`,
    `"rotvec"`, `"quat"` and `"matrix"` are a model (`rigidjax.models`): at fixed
    steps of an explicit Runge–Kutta method they run on the CPU kernel written from the field,
    ω(t) and the shadow switch included (`"euler"` and `"cayley_klein"` use indexed updates,
    host checks and complex numbers, which the kernel cannot take).
    """
    options = SolveOptions.of(options, solve_kwargs)
    if not options.throw:
        raise ValueError(
            "darboux returns the rotations only, with no failure status: throw=False would "
            "return a failed solve's values unmarked; leave throw=True (a failure raises)"
        )
    frame, seq = _frame_and_seq(method, frame, seq)
    ts = check_times(as_float(ts, "ts"))
    P0 = jnp.eye(3, dtype=ts.dtype) if P0 is None else matrix(P0, "P0")
    if P0.shape != (3, 3):
        raise ValueError(f"P0 must have shape (3, 3) (vmap for batches), got {tuple(P0.shape)}")
    P0 = so3.check_rotation(P0.astype(ts.dtype), norm_tolerance(ts.dtype), "P0")
    source = _source(omega_fn)
    if isinstance(source, diffrax.AbstractPath):
        ts = _check_span(ts, source)
        w = source.evaluate
        options = _knots_as_step_ends(options, source, ts.dtype)
    else:
        w = source
    shape = jnp.shape(jax.eval_shape(w, jax.ShapeDtypeStruct((), ts.dtype)))
    if shape != (3,):  # (one body: a batch of ω would be a batch of problems)
        raise ValueError(f"omega_fn(t) must return shape (3,) (vmap for batches), got {shape}")

    if method == "geometric":
        solver = options.rkmk(frame)
        term = LieTerm(_LieField(w))
        y0 = (P0, None)
        step_end = None

        def to_matrix(y):
            return y[0]

    else:
        kin = lookup(method, frame, seq=seq, name="method")
        solver, step_end = None, kin.step_end
        term = diffrax.ODETerm(_KinematicsField(kin, w))
        y0 = kin.from_matrix(P0)
        to_matrix = jax.vmap(kin.to_matrix)
        if source is w and type(kin) in (Quaternion, PoissonMatrix, RotationVector):
            # a model (`solve_tree`): fixed explicit steps run on the CPU kernel written from
            # the field, ω(t) included; after every step the quaternion is renormalised, the
            # rotation vector replaced by its shadow where |θ| > π
            ys, _, _ = solve_tree(
                term.vector_field, ts, y0, (), options,
                unit=(0,) if type(kin) is Quaternion else (),
                end=kin.step_end if type(kin) is RotationVector else None,
                name="Darboux kinematics",
            )  # fmt: skip
            P = to_matrix(ys)
            return (P, ys) if return_state else P

    ys, _, _ = solve_saved(
        term,
        ts,
        y0,
        options,
        solver=solver,
        step_end=step_end,
    )
    P = to_matrix(ys)
    return (P, P if method == "geometric" else ys) if return_state else P
