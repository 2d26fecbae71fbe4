"""Failures during integration are clear errors naming the interval, the cause and the remedy
(never a NaN trajectory); throw=False keeps the result; reduced precision and forward mode."""

import re

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj

TS = jnp.linspace(0.0, 2.0, 5)
BODY = rj.RigidBody(jnp.array([1.0, 2.0, 2.5]))
W0 = jnp.array([0.3, 1.0, -0.2])
# RK4 at h = 0.45 on |Ω| ~ 3000 rad/s: the explicit method blows up in the first interval
FAST = 1000 * W0
FIXED = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.45)


def test_blow_up_names_the_interval_and_the_remedy():
    with pytest.raises(rj.IntegrationError, match=r"between t = 0 and t = 0.5 .*lower dt0"):
        rj.simulate(BODY, FAST, None, TS, **FIXED)
    tr = rj.simulate(BODY, FAST, None, TS, throw=False, **FIXED)
    assert tr.result == diffrax.RESULTS.nonfinite and not tr.successful
    assert int(tr.stats["num_valid"]) == 1
    np.testing.assert_array_equal(tr.omega[0], FAST)  # the state before the failure is kept
    # the same (static) message under jit, where the time is not known at trace time
    with pytest.raises(Exception, match="state became non-finite.*lower dt0"):
        jax.jit(lambda w: rj.simulate(BODY, w, None, TS, **FIXED).quat)(FAST)


def test_max_steps_names_the_interval_and_the_remedy():
    with pytest.raises(rj.IntegrationError, match=r"between t = 0 and t = 0.5.*raise max_steps"):
        rj.simulate(BODY, W0, None, TS, max_steps=2)
    tr = rj.simulate(BODY, W0, None, TS, max_steps=2, throw=False)
    assert tr.result == diffrax.RESULTS.max_steps_reached
    assert int(tr.stats["num_valid"]) == 1


def test_successful_solve_reports_every_time_valid():
    tr = rj.simulate(BODY, W0, None, TS, **FIXED)
    assert tr.successful and int(tr.stats["num_valid"]) == TS.shape[0]


def test_float32_tolerance_below_reach_warns():
    w32, ts32 = W0.astype(jnp.float32), TS.astype(jnp.float32)
    with pytest.warns(UserWarning, match=r"rtol = 1e-09 is below what float32 can reach") as w:
        rj.simulate(BODY, w32, None, ts32, rtol=1e-9, max_steps=64, throw=False)
    assert "or float64" in str(w[0].message)


def test_float64_tolerance_below_reach_warns_without_suggesting_float64():
    with pytest.warns(UserWarning, match=r"rtol = 1e-17 is below what float64 can reach") as w:
        rj.simulate(BODY, W0, None, TS, rtol=1e-17, max_steps=64, throw=False)
    assert "float64 (" not in str(w[0].message), w[0].message


def _final_quat(w, **kw):
    return rj.simulate(BODY, w, None, TS, **kw).quat[-1]


def test_forward_mode_through_a_reverse_only_adjoint_names_the_remedy():
    """Forward mode works with the default adjoint everywhere (tests/models/test_every_mode.py,
    the flow solvers in tests/solvers/test_splitting.py); with a reverse-mode adjoint given
    explicitly, the error names `adjoint=diffrax.ForwardMode()`."""
    reverse = diffrax.RecursiveCheckpointAdjoint()
    with pytest.raises(TypeError, match=r"adjoint=diffrax\.ForwardMode\(\)"):
        jax.jacfwd(lambda w: _final_quat(w, solver=rj.ExactFreeBody(), dt0=0.5, adjoint=reverse))(
            W0
        )


@pytest.mark.slow  # ~40 s: compiles forward and reverse mode through the solve
def test_forward_mode_with_forward_adjoint_matches_reverse_mode():
    fwd = jax.jacfwd(lambda w: _final_quat(w, adjoint=diffrax.ForwardMode()))(W0)
    rev = jax.jacrev(_final_quat)(W0)
    np.testing.assert_allclose(fwd, rev, atol=1e-8)
    # and both against central finite differences (independent of either AD mode)
    h = 1e-6
    fd = np.stack(
        [(_final_quat(W0 + h * e) - _final_quat(W0 - h * e)) / (2 * h) for e in np.eye(3)], -1
    )
    np.testing.assert_allclose(fwd, fd, atol=1e-6)


def _nan_from_the_fast_body(t, w, q):
    """A torque that turns NaN after t = 1 for the body spinning faster than 1 rad/s about e1."""
    return jnp.where((w[0] > 1.0) & (t > 1.0), jnp.nan, 0.0) * w


@pytest.mark.slow  # (half a minute of compiling)
def test_a_batch_failure_names_the_body():
    """A failed body of a batch is named, by its index in the batch's shape (each body its own
    steps), or in the flattened batch (a batch stepped as one); a batch of gyrostats raises
    the same error as one gyrostat (not a runtime error from inside the mapped solve), and
    with throw=False its stats are each body's (as the body alone)."""
    w = jnp.tile(W0, (2, 3, 1)).at[1, 2, 0].set(3.0)  # body (1, 2), flat index 5
    torque = _nan_from_the_fast_body
    cases = {
        "body (1, 2) of the batch of shape (2, 3)": dict(kinematics="rotvec"),
        "body 5 of 6": dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.05),
    }
    for name, kw in cases.items():
        with pytest.raises(rj.IntegrationError, match=rf"for {re.escape(name)} between t = 1 "):
            rj.simulate(BODY, w, None, TS, torque=torque, **kw)
    g = rj.Gyrostat(BODY.inertia, h=jnp.array([0.1, 0.0, 0.0]))
    w2 = w[1, 1:]  # the fast body second
    with pytest.raises(rj.IntegrationError, match=r"for body 1 of 2 between t = 1 .*non-finite"):
        rj.simulate(g, w2, None, TS, torque=torque)
    quiet = rj.simulate(g, w2, None, TS, torque=torque, throw=False)
    assert quiet.result != diffrax.RESULTS.successful and int(quiet.stats["num_valid"]) == 3
    alone = rj.simulate(g, w2[0], None, TS, torque=torque)
    np.testing.assert_array_equal(quiet.omega[0], alone.omega)
    np.testing.assert_array_equal(quiet.stats["num_steps"][0], alone.stats["num_steps"])
