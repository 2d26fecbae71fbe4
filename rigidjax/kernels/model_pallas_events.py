"""Events in the Pallas kernels (`model_pallas_adaptive`, at adaptive or each body's fixed steps):
after each step the event's condition is compared with its value at the step's start, as
Diffrax decides a crossing, and where a body crossed, the time is located on the step by the
Illinois method, each value one step of the method (`model_adaptive.h`'s `Locate`, the CPU
kernel's), all the block's crossing bodies together."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .model_pallas import Spec, step


def _sign(x):
    return (x > 0).astype(jnp.int32) - (x < 0).astype(jnp.int32)


def crossed(direction, g0, g1):
    """Whether the condition's change from g0 to g1 is an event in `direction` (0 either, 1
    rising, −1 falling), as Diffrax decides it (`model_adaptive.h`'s `Crossed`)."""
    s0, s1 = _sign(g0), _sign(g1)
    rising, falling = (s0 <= 0) & (s1 > 0), (s0 > 0) & (s1 <= 0)
    return jnp.where(direction == 0, s0 != s1, jnp.where(direction > 0, rising, falling))


def locate(spec: Spec, p, c, y: tuple, t, h, g0, g1, hit) -> tuple[Array, tuple]:
    """The events of the bodies `hit` on their steps of size `h` from `y` at `t` (the
    condition `g0` there, `g1` at the step's end): the time, located by the Illinois method
    on τ ↦ G(t + τ, the step of size τ from y) (Dowell & Jarratt, BIT 11, 1971; each value
    one step of the method, `model_adaptive.h`'s `Locate`), and the state there; the bodies
    iterate together, each until its bracket is below 4 ulp of the time, a root, or 200
    iterations."""
    G = spec.hoisted.event_components
    assert G is not None
    dtype = y[0].dtype
    tiny = 4 * jnp.finfo(dtype).eps * jnp.maximum(jnp.abs(t) + h, 1)
    zero = jnp.zeros_like(h)

    def active(s):
        i, a, b, _, _, _, _, done = s
        return ~done & (i < 200) & (b - a > tiny)

    def more(s):
        return jnp.max(active(s).astype(jnp.int32)) > 0

    def one(s):
        i, a, b, fa, fb, side, m, done = s
        go = active(s)
        mid = (a * fb - b * fa) / (fb - fa)
        mid = jnp.where((mid > a) & (mid < b), mid, 0.5 * (a + b))
        fm = G(t + mid, step(spec, p, c, t, mid, y), p, c)[0]
        root = fm == 0
        same = _sign(fm) == _sign(fb)
        nb, nfb = jnp.where(same, mid, b), jnp.where(same, fm, fb)
        nfa = jnp.where(same & (side == -1), 0.5 * fa, fa)
        na, nfa = jnp.where(same, a, mid), jnp.where(same, nfa, fm)
        nfb = jnp.where(~same & (side == 1), 0.5 * nfb, nfb)
        move = go & ~root
        return (
            i + 1,
            jnp.where(move, na, a),
            jnp.where(move, nb, b),
            jnp.where(move, nfa, fa),
            jnp.where(move, nfb, fb),
            jnp.where(move, jnp.where(same, -1, 1), side),
            jnp.where(go, jnp.where(root, mid, nb), m),
            done | (go & root),
        )

    side = jnp.zeros(h.shape, jnp.int32)
    start = (jnp.int32(0), zero, h, g0, g1, side, jnp.where(g0 == 0, zero, h), ~hit | (g0 == 0))
    m = jax.lax.while_loop(more, one, start)[6]
    u = step(spec, p, c, t, m, y)
    return t + m, tuple(jnp.where(m == 0, a, b) for a, b in zip(y, u, strict=True))


def watched(spec: Spec, direction, terminate, p, c, y, t, size, u, take, new, watch) -> tuple:
    """After an attempt of `size` from `y` at `t` to `u` (taken where `take`; `new` the states
    after it): the event where the condition crossed on a taken step (its time located on the
    step, `locate`, behind a branch taken only where some body crossed), a terminating one's
    state held; returns `(new, watch)`, `watch` the event's `(condition, time, stopped)`."""
    G = spec.hoisted.event_components
    assert G is not None
    g, when, stopped = watch
    g1 = G(t + size, u, p, c)[0]
    hit = take & jnp.isinf(when) & crossed(direction, g, g1)

    def located():
        return locate(spec, p, c, y, t, size, g, g1, hit)

    def missed():
        return jnp.full_like(when, jnp.inf), y

    t_hit, v = jax.lax.cond(jnp.max(hit.astype(jnp.int32)) > 0, located, missed)
    stop = hit & terminate
    new = tuple(jnp.where(stop, a, x) for a, x in zip(v, new, strict=True))
    g = jnp.where(take & ~stop, g1, g)
    return new, (g, jnp.where(hit, t_hit, when), stopped | stop)
