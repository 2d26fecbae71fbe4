"""Every model, every backend, every mode (issue 34): `jax.jacfwd` (forward mode) equals
`jax.jacrev` (reverse mode) to 1e-9 and central differences, with default options; a model the
kernel cannot take (an indexed update, a `while_loop`, a host callback, complex numbers) runs on
the Diffrax path with one warning naming the primitive, equal to its supported twin, and is
differentiable in both modes too; `lax.cond` and `lax.switch` run on the kernel."""

import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.solvers import ExplicitRK
from tests.helpers import rigid_body_dop853

TS = jnp.linspace(0.0, 1.0, 3)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.1)
Q0 = rj.quat.from_rotvec(jnp.array([0.1, 0.2, 0.3]))
W0 = jnp.array([0.3, 0.5, -0.2])


def _agree(f, x, atol=1e-7):
    """jacfwd = jacrev (1e-9) = central differences (`atol`)."""
    forward, reverse = jax.jacfwd(f)(x), jax.jacrev(f)(x)
    np.testing.assert_allclose(forward, reverse, rtol=0, atol=1e-9)
    eps = 1e-6
    basis = np.eye(x.size).reshape(x.size, *x.shape)
    central = np.stack([(f(x + eps * e) - f(x - eps * e)) / (2 * eps) for e in basis], -1)
    np.testing.assert_allclose(forward, central, rtol=0, atol=atol)


def _end(traj):
    return jnp.concatenate([traj.omega[-1], traj.quat[-1]])


@pytest.mark.slow  # ~17 s: forward mode compiles the Diffrax path beside the kernel
def test_kernel_torque_gain_and_initial_state():
    """The CPU kernel with a torque whose gain is closed over (lifted into the kernel's
    parameters): derivatives w.r.t. the gain and the initial rate."""
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))

    def f(x):
        gain, w0 = x[0], x[1:]
        torque = lambda t, w, q: -gain * w + 0.1 * rj.quat.to_matrix(q)[:, 2]  # noqa: E731
        return _end(rj.simulate(body, w0, Q0, TS, torque=torque, **FIXED))

    _agree(f, jnp.concatenate([jnp.array([0.2]), W0]))


@pytest.mark.slow
def test_full_tensor_adaptive():
    """A full inertia tensor at the default tolerances (the Diffrax path: `solve_saved`'s rule,
    its field's closure converted)."""

    def f(w0):
        inertia = jnp.array([[2.0, 0.1, 0.0], [0.1, 3.0, 0.0], [0.0, 0.0, 4.0]])
        return _end(rj.simulate(rj.RigidBody(inertia), w0, Q0, TS))

    _agree(f, W0)


@pytest.mark.slow
def test_heavy_top_sixdof_darboux():
    """The heavy top (kernel), the 6-DOF body with a wrench (kernel) and `darboux`."""
    top = rj.HeavyTop([1.0, 1.4, 1.9], 1.0, [0.1, -0.05, 0.2])

    def heavy(w0):
        gamma0 = jnp.array([0.0, 0.6, 0.8])
        traj = rj.simulate_heavy_top(top, w0, gamma0, TS, **FIXED)
        return traj.omega[-1]

    _agree(heavy, W0)

    def sixdof(w0):
        body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))

        def wrench(t, state):
            return -0.1 * state.V, -0.2 * state.omega

        R0, V0 = jnp.zeros(3), jnp.array([1.0, 0.0, 0.0])
        traj = rj.sixdof.simulate_6dof(body, R0, V0, Q0, w0, TS, wrench, **FIXED)
        return jnp.concatenate([traj.R[-1], traj.omega[-1]])

    _agree(sixdof, W0)

    def darboux(a):
        return rj.darboux(lambda t: a * jnp.array([1.0, t, t * t]), TS, method="quat").reshape(-1)

    _agree(darboux, jnp.array([0.1, 0.2, 0.3]))


def _indexed(w):
    return jnp.zeros(3).at[jnp.array([0, 1, 2])].add(-0.1 * w)


def _loop(w):
    def body(c):  # one pass, multiplying by 1 (a carry the loop really updates)
        return c[0] + 1, c[1] * (c[0] + 1).astype(w.dtype)

    return jax.lax.while_loop(lambda c: c[0] < 1, body, (0, -0.1 * w))[1]


def _host(w):
    shape = jax.ShapeDtypeStruct((3,), w.dtype)
    return jax.pure_callback(lambda w: -0.1 * np.asarray(w), shape, w, vmap_method="sequential")


def _complex(w):
    return jnp.real((-0.1 * w).astype(jnp.complex128) * (1.0 + 0.0j))


UNSUPPORTED = {
    "scatter-add": lambda t, w, q: _indexed(w),
    "while": lambda t, w, q: _loop(w),
    "pure_callback": lambda t, w, q: _host(w),
    "complex": lambda t, w, q: _complex(w),
}


@pytest.mark.parametrize("primitive", list(UNSUPPORTED))
def test_fallback_equals_its_twin(primitive):
    """A torque with a primitive the kernel cannot take: one warning naming it; the values of
    the same torque written with supported operations, to rounding."""
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        got = rj.simulate(body, W0, Q0, TS, torque=UNSUPPORTED[primitive], **FIXED)
    named = [r for r in record if "fast path" in str(r.message)]
    assert len(named) == 1 and primitive.split("-")[0] in str(named[0].message)
    twin = rj.simulate(body, W0, Q0, TS, torque=lambda t, w, q: -0.1 * w, **FIXED)
    np.testing.assert_allclose(got.omega, twin.omega, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got.quat, twin.quat, rtol=0, atol=1e-14)


def _regime(t):
    return jnp.clip(jnp.floor(2 * t).astype(jnp.int32), 0, 2)


def _switch(t, w, q):
    """Three regimes of t by `lax.switch`; the first is NaN where it is not taken (t > ½), and
    so is its derivative."""
    branches = [lambda: -0.1 * w * jnp.sqrt(0.5 - t), lambda: 0.2 * w[::-1], lambda: w * q[0]]
    return jax.lax.switch(_regime(t), branches)


def _switch_twin(t, w, q):
    k = _regime(t)
    first = -0.1 * w * jnp.sqrt(jnp.maximum(0.5 - t, 0.0))
    return jnp.where(k == 0, first, jnp.where(k == 1, 0.2 * w[::-1], w * q[0]))


@pytest.mark.parametrize("steps", ["fixed", "adaptive"])
def test_cond_and_switch_run_on_the_kernel(steps):
    """A torque with `lax.switch` (and `lax.cond`, its two-branch case) takes the fast path: no
    warning, the values of its `jnp.where` twin and of the Diffrax path on the same steps
    (`ExplicitRK`, which takes no kernel), and SciPy's; an untaken branch's NaN does not leak."""
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
    kw = FIXED if steps == "fixed" else dict(rtol=1e-10, atol=1e-10)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        got = rj.simulate(body, W0, Q0, TS, torque=_switch, **kw)
    assert not [r for r in record if "fast path" in str(r.message)], record
    twin = rj.simulate(body, W0, Q0, TS, torque=_switch_twin, **kw)
    np.testing.assert_allclose(got.omega, twin.omega, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got.quat, twin.quat, rtol=0, atol=1e-14)
    slow = rj.simulate(body, W0, Q0, TS, torque=_switch, solver=ExplicitRK(diffrax.Tsit5()), **kw)
    np.testing.assert_allclose(got.omega, slow.omega, rtol=0, atol=1e-13)
    np.testing.assert_allclose(got.quat, slow.quat, rtol=0, atol=1e-13)
    if steps == "adaptive":  # SciPy's DOP853, restarted where the regime changes (t = ½)
        first = rigid_body_dop853(
            [1, 2, 3], W0, Q0, [0.0, 0.5], lambda t, w, q: -0.1 * w * (0.5 - t) ** 0.5
        )
        w, q = first[0][-1], first[1][-1]
        second = rigid_body_dop853([1, 2, 3], w, q, [0.5, 1.0], lambda t, w, q: 0.2 * w[::-1])
        np.testing.assert_allclose(got.omega, np.stack([W0, w, second[0][-1]]), rtol=0, atol=1e-8)
        np.testing.assert_allclose(got.quat, np.stack([Q0, q, second[1][-1]]), rtol=0, atol=1e-8)


@pytest.mark.slow
def test_switch_in_every_mode():
    """Derivatives through the kernel's `lax.switch` (its reverse program reads uninitialised
    residuals of the untaken branches): jacfwd = jacrev = central differences."""
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))

    def f(w0):
        return rj.simulate(body, w0, Q0, TS, torque=_switch, **FIXED).omega[-1]

    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        _agree(f, W0)
    assert not [r for r in record if "fast path" in str(r.message)], record


def _omega(t, a):
    """ω(t) through an indexed update (a scatter: no scalar form, so no kernel)."""
    angles = jnp.array([0.0, 0.2, 0.3]).at[0].set(t)
    return rj.euler.to_matrix(angles, "ZXZ") @ a


@pytest.mark.parametrize(
    "method",  # ~7-10 s each: the other two kinematics with the slow tests
    ["quat", *(pytest.param(m, marks=pytest.mark.slow) for m in ("rotvec", "matrix"))],
)
def test_fallback_without_parameters(method):
    """`darboux` with `ω(t)` built through an indexed update (no kernel, and a model without
    parameters) at fixed steps: one warning per solve, and the attitude of an
    adaptive solve at tight tolerances (itself a fallback, with its own warning)."""
    a0 = jnp.array([0.1, 0.2, 0.3])
    with pytest.warns(RuntimeWarning, match="scatter") as fixed_warnings:
        fixed = rj.darboux(lambda t: _omega(t, a0), TS, P0=jnp.eye(3), method=method, **FIXED)
    with pytest.warns(RuntimeWarning, match="scatter") as tight_warnings:
        tight = rj.darboux(lambda t: _omega(t, a0), TS, P0=jnp.eye(3), rtol=1e-12, atol=1e-12)
    assert len(fixed_warnings) == 1 and len(tight_warnings) == 1
    np.testing.assert_allclose(fixed, tight, rtol=0, atol=1e-8)


@pytest.mark.slow
def test_fallback_in_every_mode():
    """The same fallback differentiated w.r.t. a closed-over amplitude in both modes."""
    omega = _omega
    a0 = jnp.array([0.1, 0.2, 0.3])

    def f(a):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            P = rj.darboux(lambda t: omega(t, a), TS, P0=jnp.eye(3), method="quat", **FIXED)
        return P[-1].reshape(-1)

    _agree(f, a0)


@pytest.mark.parametrize(
    "body, kinematics",
    [
        (rj.RigidBody(jnp.array([[2.0, 0.1, 0.0], [0.1, 3.0, 0.0], [0.0, 0.0, 4.0]])), "quat"),
        pytest.param(  # ~10 s
            rj.RigidBody(jnp.array([1.0, 2.0, 3.0])), "rotvec", marks=pytest.mark.slow
        ),
    ],
    ids=["full_tensor", "rotvec"],
)
def test_simulate_under_jit_on_captured_constants(body, kinematics):
    """`simulate` inside `jax.jit` with `q0` captured from outside (the rotation maps it calls
    compile nothing of their own there): the eager values."""
    eager = rj.simulate(body, W0, Q0, TS, kinematics=kinematics, **FIXED)

    @jax.jit
    def jitted(s):
        traj = rj.simulate(body, s * W0, Q0, TS, kinematics=kinematics, **FIXED)
        return traj.quat, traj.omega

    quat, omega = jitted(1.0)
    np.testing.assert_allclose(quat, eager.quat, rtol=0, atol=1e-14)
    np.testing.assert_allclose(omega, eager.omega, rtol=0, atol=1e-14)
