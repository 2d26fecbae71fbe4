"""`rigidjax._compile`: the fits' compile options are known to this XLA, left out where unknown,
and give the same numbers as the default compile."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import _compile


def test_options_known_here_and_left_out_where_unknown(monkeypatch):
    """This XLA takes the options; one that does not know them compiles with its defaults (the
    same numbers), and errors of the program itself are not taken for that."""
    f = _compile.quick_compile_jit(lambda x: jnp.sin(x) * 2, small=True)
    np.testing.assert_array_equal(f(jnp.arange(3.0)), jnp.sin(jnp.arange(3.0)) * 2)
    assert f._options == _compile.SMALL_PROGRAM

    def fails(x):
        return jax.pure_callback(_raise, jax.ShapeDtypeStruct((), x.dtype), x)

    h = _compile.quick_compile_jit(fails)
    with pytest.raises(jax.errors.JaxRuntimeError, match="from the program"):
        jax.block_until_ready(h(jnp.zeros(())))
    assert h._options == _compile.QUICK_COMPILE
    monkeypatch.setattr(_compile, "QUICK_COMPILE", {"xla_no_such_option_in_any_xla": False})
    g = _compile.quick_compile_jit(lambda x: jnp.sin(x) * 2)
    np.testing.assert_array_equal(g(jnp.arange(3.0)), jnp.sin(jnp.arange(3.0)) * 2)
    assert g._options == {}


def _raise(x):
    raise ValueError("from the program")


def test_same_numbers_as_the_default_compile():
    """A forward-mode Jacobian with divisions, square roots and arctangents (what the fits'
    programs are made of), both ways, to rounding (equal here)."""

    def f(p, x):
        r = jnp.sqrt(x[:, 0] ** 2 + p[0] * x[:, 1] ** 2)
        return jnp.arctan2(r, x[:, 2] + p[1]) / (r + p[2]) + jnp.sum(jnp.tanh(x) * p[0], -1)

    x = jnp.asarray(np.random.default_rng(0).normal(size=(64, 3)))
    p = jnp.asarray([0.7, 1.3, 0.2])
    jac = jax.jacfwd(f)
    quick = _compile.quick_compile_jit(jac)
    np.testing.assert_allclose(quick(p, x), jax.jit(jac)(p, x), rtol=1e-14, atol=1e-15)
    assert quick._jitted is not None  # built at the first call
