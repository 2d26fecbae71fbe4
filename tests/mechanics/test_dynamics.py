"""Euler's equations + attitude kinematics against SciPy solve_ivp (DOP853) and closed forms."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import RK4, RigidBody, angular_momentum, energy, simulate
from rigidjax.mechanics.invariants import drift
from tests.helpers import rigid_body_dop853

TS = jnp.linspace(0.0, 5.0, 6)
TIGHT = dict(rtol=1e-12, atol=1e-12)
I_DIAG = np.array([1.0, 2.0, 2.5])
W0 = np.array([0.3, 1.0, -0.4])
Q0 = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_quat(scalar_first=True)


def _full_tensor():
    R = Rotation.from_rotvec([0.3, 0.5, -0.2]).as_matrix()
    return R @ np.diag(I_DIAG) @ R.T


def scipy_reference(I, w0, q0, ts, torque_body=None):
    """Ω and the attitude matrices from the independent SciPy reference."""
    w, q = rigid_body_dop853(I, w0, q0, ts, torque_body)
    return w, Rotation.from_quat(q, scalar_first=True).as_matrix()


REF_DIAG = scipy_reference(np.diag(I_DIAG), W0, Q0, TS)


@pytest.mark.parametrize(
    "kinematics", ["quat", "rotvec", "matrix", "euler", "cayley_klein", "geometric"]
)
def test_free_body_every_kinematics(kinematics):
    traj = simulate(RigidBody(I_DIAG), W0, Q0, TS, kinematics=kinematics, **TIGHT)
    w_ref, P_ref = REF_DIAG
    np.testing.assert_allclose(traj.omega, w_ref, atol=1e-9)
    np.testing.assert_allclose(traj.matrix, P_ref, atol=1e-9)
    assert traj.omega.shape == (6, 3) and traj.quat.shape == (6, 4)


def test_free_body_full_tensor():
    I = _full_tensor()
    traj = simulate(RigidBody(I), W0, Q0, TS, **TIGHT)
    w_ref, P_ref = scipy_reference(I, W0, Q0, TS)
    np.testing.assert_allclose(traj.omega, w_ref, atol=1e-9)
    np.testing.assert_allclose(traj.matrix, P_ref, atol=1e-9)


def test_constant_torque_about_principal_axis():
    """Ω = (0, 0, Ω3): Ω3 = Ω3(0) + K t / I3; attitude: turn about z by Ω3(0) t + K t²/(2 I3)."""
    K = 0.6
    traj = simulate(
        RigidBody(I_DIAG),
        jnp.array([0.0, 0.0, 0.5]),
        None,
        TS,
        torque=lambda t, w, q: jnp.array([0.0, 0.0, K]),
        **TIGHT,
    )
    np.testing.assert_allclose(traj.omega[:, 2], 0.5 + K * TS / I_DIAG[2], atol=1e-10)
    angle = 0.5 * TS + K * TS**2 / (2 * I_DIAG[2])
    ref = Rotation.from_rotvec(np.outer(angle, [0, 0, 1])).as_matrix()
    np.testing.assert_allclose(traj.matrix, ref, atol=1e-9)


def test_space_torque_changes_space_momentum_linearly():
    """Ṁ = K in space (004): a constant space torque gives M_space(t) = M(0) + K t exactly."""
    K = jnp.array([0.1, -0.2, 0.05])
    body = RigidBody(_full_tensor())
    traj = simulate(body, W0, Q0, TS, torque=lambda t, w, q: K, torque_frame="space", **TIGHT)
    M = angular_momentum(body, traj.omega, traj.quat)
    np.testing.assert_allclose(M, M[0] + TS[:, None] * K, atol=1e-9)
    # the same torque given in the body frame through q reproduces the SciPy reference
    w_ref, P_ref = scipy_reference(
        np.asarray(body.inertia),
        W0,
        Q0,
        TS,
        lambda t, w, q: Rotation.from_quat(q, scalar_first=True).inv().apply(np.array(K)),
    )
    np.testing.assert_allclose(traj.omega, w_ref, atol=1e-8)
    np.testing.assert_allclose(traj.matrix, P_ref, atol=1e-8)


def test_space_torque_on_principal_axes_fast_path():
    """The component fast path (principal moments, quaternions) with a torque given in space
    and depending on t, Ω and q, against the SciPy reference."""

    def torque(t, w, q):
        return jnp.array([0.1 * jnp.sin(t), -0.2 * w[0], 0.05 + 0.1 * q[1]])

    def torque_body_np(t, w, q):
        K = np.array([0.1 * np.sin(t), -0.2 * w[0], 0.05 + 0.1 * q[1]])
        return Rotation.from_quat(q, scalar_first=True).inv().apply(K)

    traj = simulate(RigidBody(I_DIAG), W0, Q0, TS, torque=torque, torque_frame="space", **TIGHT)
    w_ref, P_ref = scipy_reference(np.diag(I_DIAG), W0, Q0, TS, torque_body_np)
    np.testing.assert_allclose(traj.omega, w_ref, atol=1e-8)
    np.testing.assert_allclose(traj.matrix, P_ref, atol=1e-8)


FIXED = dict(solver=RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01)


def test_outputs_are_step_end_states_fixed_steps():
    """Steps end at every output time: with fixed steps and output times on the grid, saving 11
    times takes the same 100 steps as saving only the end, and the saved quaternions are the
    renormalised step-end states (unit to rounding), not interpolants."""
    body, ts = RigidBody(I_DIAG), jnp.linspace(0.0, 1.0, 11)
    many = simulate(body, W0, Q0, ts, **FIXED)
    ends = simulate(body, W0, Q0, ts[::10], **FIXED)
    assert int(many.stats["num_steps"]) == int(ends.stats["num_steps"]) == 100
    np.testing.assert_allclose(many.omega[::10], ends.omega, atol=1e-14)
    np.testing.assert_allclose(many.quat[::10], ends.quat, atol=1e-14)
    np.testing.assert_allclose(jnp.linalg.norm(many.quat, axis=-1), 1.0, atol=4e-16)
    w_ref, P_ref = scipy_reference(np.diag(I_DIAG), W0, Q0, np.asarray(ts))
    np.testing.assert_allclose(many.omega, w_ref, atol=1e-8)  # RK4 at h = 0.01
    np.testing.assert_allclose(many.matrix, P_ref, atol=1e-8)


def test_outputs_adaptive_steps_clipped_not_multiplied():
    """Adaptive steps are clipped at the output times and each interval starts from the previous
    one's step: 51 outputs cost at most one extra step per output, same accuracy."""
    body, ts = RigidBody(I_DIAG), jnp.linspace(0.0, 5.0, 51)
    sparse = simulate(body, W0, Q0, TS, **TIGHT)
    dense = simulate(body, W0, Q0, ts, **TIGHT)
    w_ref, P_ref = scipy_reference(np.diag(I_DIAG), W0, Q0, np.asarray(ts))
    np.testing.assert_allclose(dense.omega, w_ref, atol=1e-9)  # every output, vs SciPy
    np.testing.assert_allclose(dense.matrix, P_ref, atol=1e-9)
    np.testing.assert_allclose(dense.omega[::10], sparse.omega, atol=1e-10)
    np.testing.assert_allclose(dense.quat[::10], sparse.quat, atol=1e-10)
    assert int(dense.stats["num_steps"]) <= int(sparse.stats["num_steps"]) + 50
    assert int(dense.stats["num_accepted_steps"]) >= 50


def test_compiled_once_per_structure():
    """Repeated calls with the same structure and shapes reuse one compilation (the torque
    is traced once), whatever the values."""
    traces = []

    def torque(t, w, q):
        traces.append(None)
        return jnp.zeros(3)

    for w0 in (W0, 2 * W0):
        simulate(RigidBody(I_DIAG), w0, Q0, TS, torque=torque, **FIXED)
    n = len(traces)
    simulate(RigidBody(1.5 * I_DIAG), 3 * W0, Q0, 2 * TS, torque=torque, **FIXED)
    assert n > 0 and len(traces) == n


def test_progress_meter_and_controllers(capfd):
    body = RigidBody(I_DIAG)
    simulate(body, W0, Q0, TS, progress_meter=diffrax.TextProgressMeter(), **FIXED)
    assert "100.00%" in capfd.readouterr().out
    with pytest.raises(ValueError, match="dt0"):
        simulate(body, W0, Q0, TS, stepsize_controller=diffrax.ConstantStepSize())
    with pytest.raises(ValueError, match="stepsize_controller must be"):
        simulate(body, W0, Q0, TS, stepsize_controller=diffrax.StepTo(ts=TS), dt0=None)


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_invariants_long_run():
    ts = jnp.linspace(0.0, 100.0, 11)
    body = RigidBody(_full_tensor())
    traj = simulate(body, W0, Q0, ts, **TIGHT)
    d = drift(body, traj.omega, traj.quat)
    assert float(d["energy"]) < 1e-10 and float(d["momentum_norm"]) < 1e-10
    assert float(d["momentum_space"]) < 1e-9
    T = energy(body, traj.omega)
    np.testing.assert_allclose(T[0], 0.5 * W0 @ np.asarray(body.inertia) @ W0, rtol=1e-14)


def test_batch_equals_loop_and_vmap():
    """A batch of bodies and initial states (one fused solve) equals single solves."""
    inertias = jnp.array([[1.0, 2.0, 2.5], [2.0, 2.0, 3.0], [1.5, 1.0, 2.0], [1.0, 1.0, 1.0]])
    w0 = jnp.array([[0.3, 1.0, -0.4], [0.1, 0.2, 0.9], [-1.0, 0.4, 0.2], [0.5, 0.5, 0.5]])
    traj = simulate(RigidBody(inertias), w0, Q0, TS, **TIGHT)
    assert traj.omega.shape == (4, 6, 3) and traj.quat.shape == (4, 6, 4)
    for k in range(4):
        single = simulate(RigidBody(inertias[k]), w0[k], Q0, TS, **TIGHT)
        np.testing.assert_allclose(traj.omega[k], single.omega, atol=1e-9)
        np.testing.assert_allclose(traj.quat[k], single.quat, atol=1e-9)
    vm = jax.vmap(lambda I, w: simulate(RigidBody(I), w, Q0, TS, **TIGHT).omega)(inertias, w0)
    np.testing.assert_allclose(vm, traj.omega, atol=1e-9)


def test_float32():
    traj = simulate(
        RigidBody(I_DIAG.astype(np.float32)),
        W0.astype(np.float32),
        Q0.astype(np.float32),
        TS.astype(jnp.float32),
    )
    assert traj.omega.dtype == jnp.float32
    np.testing.assert_allclose(traj.omega, REF_DIAG[0], atol=1e-4)


def test_bad_input():
    with pytest.raises(ValueError, match="triangle"):
        RigidBody([1.0, 1.0, 3.0])
    with pytest.raises(ValueError, match="positive definite"):
        RigidBody([1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="mass must be positive"):
        RigidBody(I_DIAG, mass=-1.0)
    for inertia, mass in [(np.stack([I_DIAG] * 2), np.ones(5)), (I_DIAG, np.ones(2))]:
        with pytest.raises(ValueError, match=r"mass must be a scalar or broadcast to .* batch"):
            RigidBody(inertia, mass=mass)
    body = RigidBody(I_DIAG)
    with pytest.raises(ValueError, match="strictly increasing"):
        simulate(body, W0, Q0, jnp.array([0.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="unit quaternion"):
        simulate(body, W0, 2 * Q0, TS)
    with pytest.raises(Exception, match="zero|unit quaternion"):
        simulate(body, W0, np.zeros(4), TS)
    with pytest.raises(ValueError, match="omega0 must be finite"):
        simulate(body, np.array([np.nan, 0, 0]), Q0, TS)
    with pytest.raises(Exception, match="maximum number of solver steps"):
        simulate(body, W0, Q0, TS, max_steps=4)
    with pytest.raises(ValueError, match="kinematics must be one of"):
        simulate(body, W0, Q0, TS, kinematics="nope")
