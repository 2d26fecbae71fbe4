"""`_modes.both_modes` on a small function whose fast implementation has a reverse mode only
(a `jax.custom_vjp`, standing in for a kernel): every derivative of every mode and order, under
`jit` and `vmap` in both orders, equals the pure function's, and reverse mode runs the fast
adjoint (never the pure function's)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax._modes import both_modes

CALLS = {"bwd": 0}


@jax.custom_vjp
def _fast(x, a):
    return jnp.sin(x) * a


def _fwd(x, a):
    return _fast(x, a), (x, a)


def _bwd(residuals, g):
    CALLS["bwd"] += 1
    x, a = residuals
    return jnp.cos(x) * a * g, jnp.sum(jnp.sin(x) * g)


_fast.defvjp(_fwd, _bwd)


def _pure(x, a, n):
    return jnp.sin(x) * a * (n - 2)


_F = both_modes(lambda x, a, n: (_fast(x, a), n * 2), _pure, _pure)


def _loss(x, a):
    return jnp.sum(_F(x, a, jnp.int32(3))[0] ** 3)


def _reference(x, a):
    return jnp.sum((jnp.sin(x) * a) ** 3)


X, A = jnp.array([0.3, 0.5, 0.9]), jnp.array(1.7)


@pytest.mark.parametrize("mode", [jax.grad, jax.jacfwd, jax.jacrev, jax.hessian])
@pytest.mark.parametrize("jit", [False, True])
def test_every_mode(mode, jit):
    got = mode(_loss, argnums=(0, 1))
    got = jax.jit(got) if jit else got
    want = mode(_reference, argnums=(0, 1))(X, A)
    for g, w in zip(jax.tree.leaves(got(X, A)), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-14, atol=1e-14)


def test_reverse_mode_runs_the_fast_adjoint():
    before = CALLS["bwd"]
    jax.grad(_loss)(X, A)
    assert CALLS["bwd"] == before + 1


def test_vmap_and_second_order_in_any_order():
    Xs = jnp.stack([X, 2 * X])
    cases = [
        (jax.vmap(jax.grad(_loss), (0, None)), jax.vmap(jax.grad(_reference), (0, None))),
        (jax.vmap(jax.jacfwd(_loss), (0, None)), jax.vmap(jax.jacfwd(_reference), (0, None))),
        (
            jax.grad(lambda a, x: jnp.sum(jax.vmap(_loss, (0, None))(x, a))),
            jax.grad(lambda a, x: jnp.sum(jax.vmap(_reference, (0, None))(x, a))),
        ),
        (jax.vmap(jax.hessian(_loss), (0, None)), jax.vmap(jax.hessian(_reference), (0, None))),
        (jax.jacrev(jax.jacfwd(_loss)), jax.hessian(_reference)),
    ]
    for k, (got, want) in enumerate(cases):
        args = (A, Xs) if k == 2 else (X, A) if k == 4 else (Xs, A)
        np.testing.assert_allclose(got(*args), want(*args), rtol=1e-13, atol=1e-14)
