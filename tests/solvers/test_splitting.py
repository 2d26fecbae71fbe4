"""`LiePoissonSplitting`: Strang splitting of the exact free flow and the torque kick. Checked on
the heavy top against SciPy DOP853 at rtol = atol = 1e-13 (tests.helpers): second-order
convergence, |γ| = 1 and the area integral M·γ to rounding, bounded energy error.

The quick tests share one compilation (one top, the same output-time shape; dt0 and the end
time are traced values)."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax import heavy_top as ht
from rigidjax import satellite as sat
from rigidjax.solvers import ExactFreeBody, LiePoissonSplitting
from rigidjax.solvers.splitting import reads_omega
from tests.helpers import cross, rigid_body_dop853

I_TOP = np.array([1.0, 1.5, 2.0])
COM = np.array([0.1, 0.05, 0.3])
MASS, G = 1.0, 1.0
W0 = np.array([0.5, -0.3, 2.0])
Q0 = np.array([0.9, 0.3, -0.2, 0.1]) / np.linalg.norm([0.9, 0.3, -0.2, 0.1])
N_OUT = 101  # output times: every call below has this shape


def _top():
    return rj.HeavyTop(I_TOP, MASS, COM, G)


def _split(t_end, dt0, order=2):
    ts = jnp.linspace(0.0, t_end, N_OUT)
    return rj.simulate_heavy_top(
        _top(), W0, None, ts, q0=Q0, solver=LiePoissonSplitting(order), dt0=dt0
    )


def _gravity(t, w, q):
    """m g γ × r_c with γ = P(q)ᵀ e_Z, written independently of rigidjax (NumPy)."""
    q0, v = q[0], q[1:]
    e_z = np.array([0.0, 0.0, 1.0])
    t_ = 2 * cross(-v, e_z)
    gamma = e_z + q0 * t_ + cross(-v, t_)
    return cross(gamma, MASS * G * COM)


@pytest.fixture(scope="module")
def reference():
    ts = np.linspace(0.0, 4.0, N_OUT)
    return rigid_body_dop853(I_TOP, W0, Q0, ts, torque_body=_gravity)


@pytest.mark.slow  # ~9 s: three step sizes
def test_second_order_convergence(reference):
    """Halving the step divides the error by 4 (order 2), against DOP853 at 1e-13."""
    w_ref, q_ref = reference
    errors = []
    for dt0 in (0.04, 0.02, 0.01):
        traj = _split(4.0, dt0)
        errors.append(
            max(np.abs(traj.omega - w_ref).max(), np.abs(np.asarray(traj.quat) - q_ref).max())
        )
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < 1e-4
    np.testing.assert_allclose(rates, 2.0, atol=0.15)


def test_casimirs_to_rounding_and_bounded_energy():
    """4000 steps of 0.05 (200 time units, many nutation periods): |γ| = 1 and M·γ to rounding;
    the energy error is of order h² and does not grow (the last quarter's error is no larger
    than twice the first quarter's)."""
    traj = _split(200.0, 0.05)
    d = ht.drift(_top(), traj)
    assert float(d["geometric"]) < 1e-14
    assert float(d["area"]) < 1e-13
    assert float(d["energy"]) < 1e-2
    # energy at the 101 output times: no secular drift
    e = np.asarray(ht.energy(_top(), traj.omega, traj.gamma))
    err = np.abs(e - e[0])
    first, last = err[1:26].max(), err[76:].max()
    assert last < 2 * first, (first, last)


def test_gamma_and_quat_agree_and_start():
    traj = _split(1.0, 0.05)
    np.testing.assert_allclose(traj.gamma, traj.gamma_from_quat, atol=1e-15)
    np.testing.assert_array_equal(traj.quat[0], jnp.asarray(Q0))
    np.testing.assert_allclose(np.linalg.norm(traj.quat, axis=-1), 1.0, atol=4e-16)


def test_clear_errors():
    ts = jnp.linspace(0.0, 1.0, 3)
    with pytest.raises(ValueError, match="order must be 2"):
        LiePoissonSplitting(3)
    with pytest.raises(ValueError, match="dt0"):
        rj.simulate_heavy_top(_top(), W0, None, ts, q0=Q0, solver=LiePoissonSplitting())
    with pytest.raises(ValueError, match="gravity is a torque"):
        rj.simulate_heavy_top(_top(), W0, None, ts, q0=Q0, solver=ExactFreeBody())
    with pytest.raises(ValueError, match="fixed steps"):
        rj.simulate(
            rj.RigidBody(I_TOP),
            W0,
            None,
            ts,
            solver=LiePoissonSplitting(),
            stepsize_controller=diffrax.PIDController(1e-8, 1e-8),
        )
    fixed = dict(
        solver=LiePoissonSplitting(), dt0=0.1, stepsize_controller=diffrax.ConstantStepSize()
    )
    with pytest.raises(ValueError, match="this torque reads omega"):  # its kick would be Euler's
        rj.simulate(rj.RigidBody(I_TOP), W0, None, ts, torque=lambda t, w, q: -0.5 * w, **fixed)


def test_torques_that_read_omega():
    """The data flow of the torque's jaxpr: a use of Ω anywhere counts, its shape alone not."""
    assert reads_omega(lambda t, w, q: -0.5 * w, 0.0, jnp.float64)
    assert reads_omega(lambda t, w, q: q[1:] * jnp.sum(w * w), 0.0, jnp.float64)
    assert not reads_omega(lambda t, w, q: jnp.cross(q[1:], jnp.ones(3)), 0.0, jnp.float64)
    assert not reads_omega(lambda t, w, q: jnp.zeros_like(w) + jnp.sin(t), 0.0, jnp.float64)


@pytest.mark.slow  # ~40 s: the compiles of forward mode through both flow solvers
def test_forward_mode_with_the_default_adjoint():
    """`jax.jacfwd` and `jax.jvp` through the flow solvers with default options (they asked
    for `adjoint=diffrax.ForwardMode()`): equal to central differences, with respect to Ω0 and
    the centre of mass that the torque closes over, and for `ExactFreeBody` on Diffrax's
    steps."""
    ts = jnp.linspace(0.0, 1.0, 3)

    def top_end(x):
        top = rj.HeavyTop(I_TOP, MASS, x[3:], G)
        split = LiePoissonSplitting()
        return rj.simulate_heavy_top(top, x[:3], None, ts, q0=Q0, solver=split, dt0=0.1).omega[-1]

    def free_end(w):
        body = rj.RigidBody(I_TOP)
        return rj.simulate(body, w, Q0, ts, solver=ExactFreeBody(), dt0=0.5).quat[-1]

    x, h = jnp.concatenate([jnp.asarray(W0), jnp.asarray(COM)]), 1e-6
    top = jax.jit(top_end)  # (the differences: one compile)
    fd = jnp.stack([(top(x + h * e) - top(x - h * e)) / (2 * h) for e in jnp.eye(6)], 1)
    np.testing.assert_allclose(jax.jacfwd(top_end)(x), fd, atol=1e-8)
    w, dw = jnp.asarray(W0), jnp.array([0.3, -0.2, 0.5])
    free = jax.jit(free_end)
    fd = (free(w + h * dw) - free(w - h * dw)) / (2 * h)
    np.testing.assert_allclose(jax.jvp(free_end, (w,), (dw,))[1], fd, atol=1e-8)


@pytest.mark.slow
def test_gamma0_only_and_fourth_order(reference):
    """From gamma0 alone (a quaternion is made for it); Yoshida's triple jump converges at
    order 4."""
    w_ref, _ = reference
    top = _top()
    gamma0 = np.asarray(ht.vertical_from_quat(jnp.asarray(Q0)))
    ts = jnp.linspace(0.0, 4.0, N_OUT)
    traj = rj.simulate_heavy_top(top, W0, gamma0, ts, solver=LiePoissonSplitting(), dt0=0.01)
    assert traj.quat is None
    # γ and Ω do not depend on the rotation about the vertical
    np.testing.assert_allclose(traj.omega, _split(4.0, 0.01).omega, atol=1e-11)
    np.testing.assert_allclose(traj.gamma[0], gamma0, atol=1e-15)
    errors = [np.abs(_split(4.0, dt0, order=4).omega - w_ref).max() for dt0 in (0.04, 0.02)]
    assert 3.7 < np.log2(errors[0] / errors[1]) < 4.3, errors


@pytest.mark.slow
def test_satellite_second_order():
    """simulate_satellite with the splitting (Störmer–Verlet orbit, exact free attitude,
    gravity-gradient kick) converges at order 2 to the Runge–Kutta solution."""
    body = rj.RigidBody(jnp.array([2.0, 3.0, 1.0]))
    mu = 1.0
    R0, V0 = sat.circular_orbit(mu, 1.0)
    q0, w0 = sat.lvlh_state(R0, V0, jnp.array([0.05, 0.1, -0.05]))
    ts = jnp.linspace(0.0, 6.0, 4)
    ref = sat.simulate_satellite(body, R0, V0, q0, w0, ts, mu, rtol=1e-12, atol=1e-12)
    errors = []
    for dt0 in (0.01, 0.005):
        tr = sat.simulate_satellite(
            body, R0, V0, q0, w0, ts, mu, solver=LiePoissonSplitting(), dt0=dt0
        )
        np.testing.assert_allclose(np.linalg.norm(tr.quat, axis=-1), 1.0, atol=4e-16)
        errors.append(max(np.abs(tr.omega - ref.omega).max(), np.abs(tr.R - ref.R).max()))
    assert 1.85 < np.log2(errors[0] / errors[1]) < 2.15, errors
