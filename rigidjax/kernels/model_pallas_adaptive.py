"""Any model's ODE `ẏ = f(t, y, p)` at adaptive steps of an embedded Runge–Kutta pair (Bosh3,
Tsit5, Dopri5, Dopri8) as one Pallas kernel, each body its own step size: the GPU counterpart of
the adaptive CPU kernel (`model_adaptive.h`), step for step Diffrax's `PIDController` on one
body (its RMS error norm, coefficients, initial-step heuristic and the clipping of the last step
to each output time), so that a body's trajectory is the same alone, in any batch, under
`jax.vmap`, on the CPU kernel and on the Diffrax path (to rounding).

A program takes a block of `model_pallas.BLOCK` bodies, one per GPU thread, and keeps their
states in registers over all intervals. Within an output interval the block loops while any of
its bodies has steps left; each loop is one attempt of every body still integrating, whose
results a finished body ignores (its time, state and controller are its own, masked). So a
block costs its slowest body's attempts, and a batch each of its blocks' own:

    attempt   u = y + h Σ b_l k_l (unit groups normalised, then the step-end map),
              err = h Σ e_l k_l,  ε = RMS_j err_j / (atol + rtol max(|y_j|, |u_j|))
    accept    ε < 1;  h' = h · clip(safety ε^−β1 ε_prev^−β2 ε_prev2^−β3,
              accepted: [1, factormax], rejected: [factormin, safety]), min(h', dtmax)
    the end   a proposal within 100 ulp of the interval's end t1 becomes t1 (accepted) or
              halves the rest (rejected)
    intervals from the previous interval's mean accepted step (the first from dt0 or the
              heuristic of Hairer, Nørsett & Wanner, *Solving ODEs I*, II.4); at most
              max_steps attempts each; a non-finite state is not integrated further

(Söderlind, "Digital filters in adaptive time-stepping", ACM TOMS 29, 2003, in Diffrax's form.)
The controller's values are `kernels.adaptive.CONTROLS`. A jump map (a sampled, held command)
and an event's condition (`locate`) are written into the kernel as in the CPU kernel. Its
reverse mode is `model_pallas_adaptive_back.run_back`; the derivatives it does not give (the
output times', a jump map's or an event's, forward mode) go through the Diffrax path (the
caller's custom rule), as the CPU kernel's do for output times and events.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple, cast

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton
from jaxtyping import Array, Float

from .._integrate import fixed_step_count
from ..solvers import _stages
from . import adaptive, tableau
from .model import Hoisted, Schedule
from .model_pallas import (
    BLOCK,
    Spec,
    Unit,
    _compare,
    _joining,
    _padded,
    _parameters,
    _per_body,
    _sample,
    stages,
    step,
    step_end,
)
from .model_pallas_events import watched


def floors(ts: Float[Array, " T"]) -> Float[Array, " K"]:
    """Each interval's end less 100 ulp (Diffrax's `t1_clip_floor`, `model_adaptive.h`'s
    `Below`): a proposed step end beyond it is clipped to the end."""
    return jax.lax.fori_loop(0, 100, lambda _, b: jnp.nextafter(b, -jnp.inf), ts[1:])


def _rms(terms: list) -> Array:
    s = terms[0] * terms[0]
    for x in terms[1:]:
        s = s + x * x
    return jnp.sqrt(s / len(terms))


def attempt(spec: Spec, p, c, t, h, y: tuple, rtol, atol) -> tuple[tuple, Array]:
    """One attempt of size `h` from `y` at `t`: its end (unit groups normalised, the step-end
    map) and its scaled error (RMS over the components; a NaN error is ∞, a NaN end counts as
    `y`)."""
    ks = stages(spec, p, c, t, h, y)
    inc = _stages.increment(h, spec.tab.b_sol, ks)
    u = step_end(spec, p, c, t + h, [a + b for a, b in zip(y, inc, strict=True)])
    err = _stages.increment(h, np.asarray(spec.tab.b_error), ks)
    nan = functools.reduce(jnp.logical_or, [jnp.isnan(x) for x in u])
    q = [
        jnp.where(jnp.isnan(e), jnp.inf, e)
        / (atol + jnp.maximum(jnp.abs(a), jnp.abs(jnp.where(nan, a, b))) * rtol)
        for e, a, b in zip(err, y, u, strict=True)
    ]
    return u, _rms(q)


def initial_step(spec: Spec, p, c, t, y: tuple, rtol, atol, inv_order) -> Array:
    """Diffrax's `_select_initial_step` (Hairer, Nørsett & Wanner, II.4) from `y` at `t`."""
    fn = spec.hoisted.components
    f0 = fn(t, y, p, c)
    scale = [atol + jnp.abs(a) * rtol for a in y]
    d0 = _rms([a / s for a, s in zip(y, scale, strict=True)])
    d1 = _rms([f / s for f, s in zip(f0, scale, strict=True)])
    h0 = jnp.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * (d0 / d1))
    f1 = fn(t + h0, tuple(a + h0 * f for a, f in zip(y, f0, strict=True)), p, c)
    d2 = _rms([(b - a) / s for a, b, s in zip(f0, f1, scale, strict=True)]) / h0
    most = jnp.maximum(d1, d2)
    h1 = jnp.where(most <= 1e-15, jnp.maximum(1e-6, h0 * 1e-3), jnp.power(0.01 / most, inv_order))
    return jnp.minimum(100 * h0, h1)


def _power(x, e):
    """`x^e`, or 1 for a coefficient 0 (as Diffrax skips it)."""
    return jnp.where(e == 0, 1, jnp.power(x, e))


class _Controls(NamedTuple):
    """The controller's values as a kernel reads them (`kernels.adaptive.CONTROLS`)."""

    rtol: Array
    atol: Array
    safety: Array
    fmin: Array
    fmax: Array
    dtmax: Array
    dt0: Array
    c1: Array
    c2: Array
    c3: Array
    inv_order: Array
    max_steps: Array
    direction: Array
    terminate: Array

    @classmethod
    def read(cls, ref) -> _Controls:
        values = [ref[i] for i in range(14)]
        values[11] = values[11].astype(jnp.int32)
        values[13] = values[13] != 0
        return cls(*values)


def _attempts(spec: Spec, ctl: _Controls, p, c, b, floor) -> tuple[Callable, Callable]:
    """`(going, one)` of an output interval ending at `b` (per body; `floor`: 100 ulp below
    it): whether each body still integrates, and one attempt of every body (masked where not)
    on the loop state `(y, tprev, tnext, inv1, inv2, attempts, accepted, watch)`, `watch` the
    event's `(condition, time, stopped)` (`locate`)."""
    events = spec.hoisted.events

    def going(s):
        return (s[1] < b) & (s[5] < ctl.max_steps) & ~s[7][2]

    def one(s):
        y, tprev, tnext, inv1, inv2, n, taken, watch = s
        go = going(s)
        size = tnext - tprev
        u, eps = attempt(spec, p, c, tprev, size, y, ctl.rtol, ctl.atol)
        ok = eps < 1
        inv = 1 / eps
        f = ctl.safety * _power(inv, ctl.c1) * _power(inv1, ctl.c2) * _power(inv2, ctl.c3)
        lo, hi = jnp.where(ok, 1, ctl.fmin), jnp.where(ok, ctl.fmax, ctl.safety)
        dt = jnp.minimum(size * jnp.minimum(jnp.maximum(f, lo), hi), ctl.dtmax)
        inv = jnp.where((inv == 0) | jnp.isinf(inv), 1, inv)
        t0 = jnp.where(ok, tnext, tprev)
        t1 = t0 + dt
        last = jnp.minimum(t0, b)
        proposed = jnp.where(t1 > floor, jnp.where(ok, b, last + 0.5 * (b - last)), t1)
        take = go & ok
        new = tuple(jnp.where(take, v, x) for v, x in zip(u, y, strict=True))
        if events:
            new, watch = watched(
                spec, ctl.direction, ctl.terminate, p, c, y, tprev, size, u, take, new, watch
            )
        return (
            new,
            jnp.where(go, last, tprev),
            jnp.where(go, proposed, tnext),
            jnp.where(take, inv, inv1),
            jnp.where(take, inv1, inv2),
            n + go.astype(jnp.int32),
            taken + take.astype(jnp.int32),
            watch,
        )

    return going, one


def _fixed(spec: Spec, ctl: _Controls, p, c, y: tuple, a, b, watch) -> tuple:
    """Each body's fixed steps over `[a, b]` (`b` per body; `model_adaptive.h`'s `Fixed`): the
    fewest equal steps of at most dt0 (`fixed_step_count`, the fixed-step kernel's), step s at
    `a + s h`, at most max_steps of them, the event watched after each as on adaptive steps;
    returns the states, the steps taken, `watch` and whether the interval's end was reached
    (or the body stopped)."""
    width = b - a
    steps = fixed_step_count(width, ctl.dt0)
    h = width / steps
    count = jnp.where(a < b, jnp.minimum(steps, ctl.max_steps.astype(h.dtype)), 0)
    count = count.astype(jnp.int32)

    def one(i, s):
        y, n, watch = s
        go = (i < count) & ~watch[2]
        t = a + i.astype(h.dtype) * h
        u = step(spec, p, c, t, h, y)
        new = tuple(jnp.where(go, v, x) for v, x in zip(u, y, strict=True))
        if spec.hoisted.events:
            new, watch = watched(
                spec, ctl.direction, ctl.terminate, p, c, y, t, h, u, go, new, watch
            )
        return new, n + go.astype(jnp.int32), watch

    start = (y, jnp.zeros(h.shape, jnp.int32), watch)
    y, n, watch = jax.lax.fori_loop(0, jnp.max(count), one, start)
    return y, n, watch, ~(a < b) | (steps <= ctl.max_steps) | watch[2]


def _start(ctl: _Controls, y: tuple, a, b, h, watch) -> tuple:
    """The loop state of an interval from `a` (`_attempts`): the first attempt of size h
    (at most dtmax, clipped to the end), the error history 1."""
    zero, none = jnp.zeros_like(y[0]), jnp.zeros(y[0].shape, jnp.int32)
    first = jnp.minimum(a + jnp.minimum(h, ctl.dtmax), b)
    return (y, a + zero, first, zero + 1, zero + 1, none, none, watch)


def _finite(y: tuple) -> Array:
    return functools.reduce(jnp.logical_and, [jnp.isfinite(x) for x in y])


def _kernel(spec: Spec, K: int, N: int, P: int, Pc: int, adjoint: bool):
    """The kernel of one block over K output intervals: the states at the K + 1 output times,
    and per body its attempts, accepted and rejected steps, output times reached and result
    (0 successful, 1 max_steps reached, 2 non-finite), as the CPU kernel's. A model with a
    jump map takes `jump (K,)` and `save (K + 1,)` (`model.Schedule`, as `model_pallas`'s
    kernel: slot 0 of the states and records a dummy) and starts every interval from dt0 or
    the initial-step heuristic, as the CPU kernel. A model with an event's condition watches
    it after each accepted step (`locate`), writes each body's first event time (∞: none)
    and, where the event terminates, holds the body from the event on (no later jump). With
    `adjoint`, also each interval's first step size and attempts per body (`run_back`'s)."""
    R0, NR = spec.record
    jumps, events = spec.hoisted.jumps, spec.hoisted.events
    G = spec.hoisted.event_components

    def kernel(ts_ref, floor_ref, ctl_ref, x0_ref, p_ref, *refs):
        names = ("jump", "save", "out", "rec") if jumps else ("out",)
        names += ("st",) + (("ev",) if events else ()) + (("hk", "nk") if adjoint else ())
        ref = dict(zip(names, refs, strict=True))
        ctl = _Controls.read(ctl_ref)
        p = tuple(p_ref[j] for j in range(P))
        c = tuple(p_ref[P + j] for j in range(Pc))
        y = tuple(x0_ref[j] for j in range(N))
        zero, none = jnp.zeros_like(y[0]), jnp.zeros(y[0].shape, jnp.int32)

        def save(k, y):
            at = ref["save"][k] if jumps else k
            for j in range(N):
                ref["out"][at, j] = y[j]

        def first_step(a, y):  # dt0, or the heuristic's (rounded as a step from a)
            guess = initial_step(spec, p, c, a, y, ctl.rtol, ctl.atol, ctl.inv_order)
            return jnp.where(jnp.isnan(ctl.dt0), (a + jnp.minimum(guess, ctl.dtmax)) - a, ctl.dt0)

        def interval(k, carry):
            y, h, attempts, accepted, valid, result, watch = carry
            stopped = watch[2]
            a, floor = ts_ref[k], floor_ref[k]
            if jumps:  # (a body stopped by its event: held)
                slot = ref["jump"][k]

                def jump(y):
                    u = spec.hoisted.jump_components(a, y, p, c)
                    return tuple(jnp.where(stopped, x, v) for x, v in zip(y, u, strict=True))

                y = jax.lax.cond(slot != 0, jump, lambda y: y, y)
                for j in range(NR):
                    ref["rec"][slot, j] = y[R0 + j]
                h = zero if spec.fixed else first_step(a, y)
            alive = _finite(y)
            b = jnp.where(alive & ~stopped, ts_ref[k + 1], a)
            if events:
                assert G is not None
                now = G(a, y, p, c)[0]
                watch = (jnp.where(stopped, watch[0], now), *watch[1:])
            if spec.fixed:
                y, n, watch, done = _fixed(spec, ctl, p, c, y, a, b, watch)
                taken = n
            else:
                going, one = _attempts(spec, ctl, p, c, b, floor)

                def more(s):
                    return jnp.max(going(s).astype(jnp.int32)) > 0

                s = jax.lax.while_loop(more, one, _start(ctl, y, a, b, h, watch))
                if adjoint:
                    ref["hk"][k] = h
                    ref["nk"][k] = s[5]
                y, tprev, n, taken, watch = s[0], s[1], s[5], s[6], s[7]
                done = ~(tprev < b) | watch[2]
            code = jnp.where(done, jnp.where(_finite(y), 0, 2), 1)
            h = jnp.where(alive, (b - a) / jnp.maximum(taken, 1).astype(h.dtype), h)
            result = jnp.where(result == 0, code, result)
            save(k + 1, y)
            return y, h, attempts + n, accepted + taken, valid + (result == 0), result, watch

        save(0, y)
        h = zero if jumps or spec.fixed else first_step(ts_ref[0], y)
        watch = (zero, zero + jnp.inf, none != 0)  # the condition, the event's time, stopped
        carry = (y, h, none, none, none + 1, none, watch)
        *_, attempts, accepted, valid, result, watch = jax.lax.fori_loop(0, K, interval, carry)
        for i, x in enumerate((attempts, accepted, attempts - accepted, valid, result)):
            ref["st"][i] = x
        if events:
            ref["ev"][0] = watch[1]

    return kernel


def run(
    spec: Spec,
    y0: Float[Array, "B N"],
    p: Float[Array, "P Bc"],
    ts: Float[Array, " T"],
    ctl: Float[np.ndarray, " 14"] | Float[Array, " 14"],
    *,
    interpret: bool = False,
    schedule: Schedule | None = None,
    adjoint: bool = False,
) -> tuple[Array, ...]:
    """The states `(B, S, N)` of B bodies at the output times `ts` under the controller `ctl`
    (`kernels.adaptive.controls`, with the event's direction and termination), the components
    `spec.record` after each recorded jump `(B, R, NR)` (a model with a jump map, its
    `schedule`, `model.Schedule`: the intervals that start with the jump map, the kept times;
    without one every time is kept and R = 0), per body `(B, 5)`: attempts, accepted and
    rejected steps, the leading output times reached and the result (0 successful, 1
    max_steps reached, 2 non-finite), for a model with an event's condition each body's
    first event time `(B,)` (∞: none), and with `adjoint` (`run_back`'s residuals) each
    interval's first step size `(B, K)` and attempts `(B, K)`. `p (P + Pc, B or 1)` as
    `model_pallas.run`; `interpret=True` runs Pallas' interpreter (any backend: the CPU
    tests). Under `jax.vmap` over the bodies the mapped bodies join one kernel call."""
    T = ts.shape[0]
    sizes = (T, 0) if schedule is None else (schedule.kept.size, schedule.at.size)
    call = functools.partial(_blocks, spec, sizes, adjoint, interpret=interpret)
    args = (ts, floors(ts), jnp.asarray(ctl, ts.dtype))
    if schedule is not None:
        args += (schedule.jump, schedule.save)
    outs = 3 + spec.hoisted.events + 2 * adjoint
    return cast(tuple, _joining(call, states=1, out_body_axes=(0,) * outs)(y0, p, *args))


def _blocks(
    spec: Spec, sizes: tuple[int, int], adjoint: bool, *arrays: Array, interpret: bool
) -> tuple:
    """`run` of one batch (`arrays`: its `y0, p, ts, floors, ctl` and, with a jump map, `jump,
    save`; `sizes`: the kept times and the records): the `pallas_call` over its blocks."""
    y0, p, ts, fl, ctl, *schedule = arrays
    B, N, T, dtype = y0.shape[0], y0.shape[1], ts.shape[0], y0.dtype
    P, (S, R), NR = spec.hoisted.p, sizes, spec.record[1]
    Bp = -(-B // BLOCK) * BLOCK
    pp = _parameters(p, B, Bp, dtype)
    jumps, events = bool(schedule), spec.hoisted.events
    shapes: list[tuple[int, ...]] = [(S + 1, N), (R + 1, max(NR, 1))] if jumps else [(S, N)]
    dtypes = [dtype] * len(shapes) + [jnp.int32]
    shapes.append((5,))
    if events:
        shapes.append((1,))
        dtypes.append(dtype)
    if adjoint:
        shapes += [(T - 1,), (T - 1,)]
        dtypes += [dtype, jnp.int32]
    outs = pl.pallas_call(
        _kernel(spec, T - 1, N, P, p.shape[0] - P, adjoint),
        out_shape=[jax.ShapeDtypeStruct((*s, Bp), d) for s, d in zip(shapes, dtypes, strict=True)],
        grid=(Bp // BLOCK,),
        in_specs=[
            pl.BlockSpec((T,), lambda i: (0,)),
            pl.BlockSpec((T - 1,), lambda i: (0,)),
            pl.BlockSpec(ctl.shape, lambda i: (0,)),
            pl.BlockSpec((N, BLOCK), lambda i: (0, i)),
            pl.BlockSpec((pp.shape[0], BLOCK), lambda i: (0, i)),
            *(pl.BlockSpec(a.shape, lambda i: (0,)) for a in schedule),
        ],
        out_specs=[_per_body(s) for s in shapes],
        compiler_params=pltriton.CompilerParams(num_warps=BLOCK // 32, num_stages=1),
        interpret=interpret,
    )(ts.astype(dtype), fl.astype(dtype), ctl.astype(dtype), _padded(y0, Bp), pp,
      *(a.astype(jnp.int32) for a in schedule))  # fmt: skip
    if jumps:
        ys, rec, st, *rest = outs
        ys, rec = ys[1:], rec[1:, :NR]
    else:
        (ys, st, *rest), rec = outs, jnp.zeros((0, 0, Bp), dtype)
    ys, rec = (jnp.moveaxis(a[..., :B], -1, 0) for a in (ys, rec))
    ev = [rest.pop(0)[0, :B]] if events else []
    return (ys, rec, st[:, :B].T, *ev, *(a[:, :B].T for a in rest))


def serves(
    hoisted: Hoisted,
    unit: Unit,
    solver: diffrax.AbstractSolver,
    record: tuple[int, int] = (0, 0),
    fixed: bool = False,
) -> bool:
    """Whether the kernel integrates `hoisted` (with a jump map: recording the components
    `record`) with `solver` (one of `tableau.ADAPTIVE`; with `fixed`, each body's fixed steps
    of one of `tableau.METHODS`: an event at fixed steps) on the default backend: a GPU,
    float32 or float64, and the kernel checked there (once per model, method and element
    type: a small batch compiled must give the interpreter's states and counts, else one
    warning and the Diffrax path)."""
    method = cast(type[diffrax.AbstractERK], type(solver))
    return (
        type(solver) in (tableau.METHODS if fixed else tableau.ADAPTIVE)
        and jax.default_backend() == "gpu"
        and hoisted.dtype.name in tableau.DTYPES
        and _checked(Spec(hoisted, unit, method, record, fixed))
    )


@functools.cache
def _checked(spec: Spec) -> bool:
    """Whether the compiled kernel runs here and agrees with Pallas' interpreter on two blocks
    of bodies (`model_pallas._sample`) over three intervals, one of them empty (a model with a
    jump map: jumps at the first and last, the second time not kept), at rtol = atol = 1e-6
    (fixed steps: of at most 0.01)."""
    y, p, _ = _sample(spec)
    ts = np.array([0.0, 0.03, 0.03, 0.3], y.dtype)
    dtype = spec.hoisted.dtype
    if spec.fixed:
        ctl = adaptive.fixed_controls(0.01, 1000, dtype)
    else:
        pid = diffrax.PIDController(rtol=1e-6, atol=1e-6)
        ctl = adaptive.controls(pid, spec.method(), None, 1000, dtype)
    fn = functools.partial(run, spec)
    if spec.hoisted.jumps:
        keep = np.array([True, False, True, True])
        schedule = Schedule.of(3, np.array([True, False, True]), keep, spec.record[1])
        fn = functools.partial(fn, schedule=schedule)
    return _compare("adaptive kernel", spec, fn, (y, p, ts, ctl))
