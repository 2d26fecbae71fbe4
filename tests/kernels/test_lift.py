"""Concrete constants lifted out of the C++ (`kernels._lift`): a torque with a new gain, called
eagerly, reuses the kernel built for the last gain (the same C++), and its results are those of
its own gain (never the last one's), against SciPy's `solve_ivp`."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax.kernels import _lift
from rigidjax.kernels import model as model_kernel
from rigidjax.mechanics._rigid_model import rigid_body_model

UNIT = ((3, 4),)  # the quaternion's components


def _hoisted(torque, dtype=jnp.float64):
    model = rigid_body_model(torque)
    return model_kernel.hoist(model.field, model.size, model.params, dtype)


def test_folded_constants():
    """0, the powers of two (±1, 0.5, the smallest normal) and non-finite values stay in the
    C++; any other value is lifted."""
    tiny = float(np.finfo(np.float64).tiny)
    for x in (0.0, -0.0, 1.0, -1.0, 0.5, 2.0, -4.0, 2.0**-30, tiny, np.inf, -np.inf, np.nan):
        assert _lift.folded(x), x
    for x in (0.3, -0.1, 3.0, 1.5, 1e-4, 398600.4418, np.nextafter(2.0, 3.0)):
        assert not _lift.folded(x), x


def test_new_literal_same_source():
    """`lambda t, w, q: -k * w` (the literal `-k`) for two gains: one C++ source (forward and
    reverse mode), the gain in the runtime constants; its reverse mode writes no cotangent
    of a concrete constant (none is asked for), and under `jax.jit` (a traced gain) it does."""
    a, b = (_hoisted(lambda t, w, q, k=k: -k * w) for k in (0.1, 0.2))
    assert a.source(UNIT) == b.source(UNIT)
    np.testing.assert_array_equal(a.c, [-0.1])
    np.testing.assert_array_equal(b.c, [-0.2])
    assert f"pb[{a.p}]" not in a.source(UNIT)

    def traced(k):
        h = _hoisted(lambda t, w, q: -k * w)
        assert f"pb[{h.p}]" in h.source(UNIT)
        return h.c

    jax.jit(traced)(0.1)


class _Gains(eqx.Module):
    k: jax.Array

    def __call__(self, t, w, q):
        return -self.k * w


def test_module_leaves_lifted_by_element():
    """A torque module's array leaves: the elements that are not folded are lifted, so gains
    (0, 0.3, 1) and (0, 0.7, 1) share a source, and (0.2, 0.3, 1), whose first gain is no
    longer the folded 0, has its own."""
    one, two, three = (
        _hoisted(_Gains(jnp.array(k))) for k in ([0.0, 0.3, 1.0], [0.0, 0.7, 1.0], [0.2, 0.3, 1.0])
    )
    assert one.source(UNIT) == two.source(UNIT) != three.source(UNIT)
    np.testing.assert_array_equal(one.c, [0.3])
    np.testing.assert_array_equal(three.c, [0.2, 0.3])


def _reference(k, I, w0, q0, ts):
    """Euler's equations with the torque −k Ω and q̇ = q ⊗ (0, Ω)/2, by SciPy (DOP853)."""

    def f(t, s):
        w, q = s[:3], s[3:]
        dw = (np.cross(I * w, w) - k * w) / I
        a, v = q[0], q[1:]
        return np.concatenate([dw, [-0.5 * v @ w], 0.5 * (a * w + np.cross(v, w))])

    sol = solve_ivp(f, (ts[0], ts[-1]), np.concatenate([w0, q0]), "DOP853", ts, rtol=1e-12,
                    atol=1e-12)  # fmt: skip
    return sol.y.T


@pytest.mark.parametrize("solver", [rj.RK4(), diffrax.Tsit5()], ids=["rk4", "tsit5"])
def test_eager_gains_each_their_own(solver):
    """Eager `simulate` calls with three gains in turn (the kernel of the first reused): each
    matches SciPy with its own gain, and the gains give different motions."""
    I = np.array([1.0, 2.0, 3.0])
    body = rj.RigidBody(jnp.asarray(I))
    w0, q0 = (
        np.array([0.3, 0.2, -0.1]),
        Rotation.from_rotvec([0.1, 0.2, 0.3]).as_quat()[[3, 0, 1, 2]],
    )
    ts = np.linspace(0.0, 2.0, 5)
    step = (
        dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=1e-3)
        if isinstance(solver, rj.RK4)
        else dict(rtol=1e-11, atol=1e-11)
    )
    finals = []
    for k in (0.3, 0.7, 0.45):
        tr = rj.simulate(body, w0, q0, ts, torque=lambda t, w, q, k=k: -k * w, solver=solver,
                         **step)  # fmt: skip
        want = _reference(k, I, w0, q0, ts)
        np.testing.assert_allclose(tr.omega, want[:, :3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(tr.quat, want[:, 3:], rtol=0, atol=1e-9)
        finals.append(np.asarray(tr.omega[-1]))
    assert min(np.abs(finals[0] - finals[1]).max(), np.abs(finals[1] - finals[2]).max()) > 1e-3


def test_saturation_bounds_lifted():
    """The bounds of `jnp.clip` (arguments of a jitted function) are lifted with the gain: a
    saturated torque with new bounds and gain shares the source; an exponent (`pow`) stays
    folded, for the scalar program's `x ** n * sqrt(x)`."""
    a, b = (
        _hoisted(lambda t, w, q, k=k, m=m: jnp.clip(-k * w, -m, m))
        for k, m in ((0.3, 0.05), (0.7, 0.2))
    )
    assert a.source(UNIT) == b.source(UNIT)
    np.testing.assert_array_equal(b.c, [-0.7, -0.2, 0.2])
    powers = [_hoisted(lambda t, w, q, e=e: -(w**e)) for e in (1.5, 2.5)]
    assert powers[0].c.size == 0 and powers[0].source(UNIT) != powers[1].source(UNIT)


def test_gradient_beside_lifted_literals():
    """A traced gain beside lifted literals (`-k Ω − 0.3 Ω³`, `0.3` without a cotangent):
    `jax.grad` through the kernel's reverse mode equals central differences of eager calls
    (each a new literal `k`, one kernel)."""
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
    w0, ts = jnp.array([0.3, 0.2, -0.1]), jnp.linspace(0.0, 1.0, 3)
    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01)

    def loss(k):
        tr = rj.simulate(body, w0, None, ts, torque=lambda t, w, q: -k * w - 0.3 * w**3, **fixed)
        return jnp.sum(tr.omega[-1] * jnp.array([1.0, -2.0, 3.0])) + tr.quat[-1, 1]

    h = 1e-5
    central = (loss(0.2 + h) - loss(0.2 - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(loss)(0.2), central, rtol=1e-8)
