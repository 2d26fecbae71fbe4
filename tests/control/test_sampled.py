"""Sampled-data (zero-order-hold) control: the loop against SciPy integrated sample by sample
with the held command, the bang-bang rest-to-rest slew time `t_f = 2 √(θ J / u)`, its fast path
against its Diffrax path, and gradients w.r.t. the gains against central differences."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax.mechanics._zoh import sample_grid
from tests.helpers import DOP853_TIGHT, cross

I = np.array([1.0, 1.5, 2.0])
H = np.array([0.05, -0.02, 0.1])
W0 = np.array([0.2, -0.1, 0.3])
Q_T = np.array([np.cos(0.6), np.sin(0.6) * 0.6, np.sin(0.6) * 0.8, 0.0])
AXES = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.6], [0.0, 0.0, 1.0, 0.52915026]])
A_UNIT = AXES / np.linalg.norm(AXES, axis=0)
J_W = np.array([0.01, 0.02, 0.015, 0.01])
TS = np.linspace(0.0, 3.0, 8)  # output times between the samples: the grid holds both
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.02)


def qmul(a, b):
    return np.concatenate(
        [[a[0] * b[0] - a[1:] @ b[1:]], a[0] * b[1:] + b[0] * a[1:] + cross(a[1:], b[1:])]
    )


def pd_np(kp, kd, q, w):
    """Wie's quaternion PD law in NumPy: `u = −kp sgn(q_e0) q_e,1:3 − kd Ω`."""
    qe = qmul(Q_T * np.array([1, -1, -1, -1]), q)
    return -kp * np.sign(qe[0]) * qe[1:] - kd * w


def held_reference(rhs, y0, command, period, ts, commands=None):
    """SciPy DOP853 integrated sample by sample: `command(t_k, y_k)` held over each interval
    (appended to `commands`, if given), the states at `ts` from each interval's dense output."""
    out, y, t_k = np.empty((len(ts), len(y0))), np.asarray(y0, float), ts[0]
    out[0] = y
    while t_k < ts[-1] - 1e-12:
        t_next = min(t_k + period, ts[-1])
        u = command(t_k, y)
        if commands is not None:
            commands.append(u)
        sol = solve_ivp(
            lambda t, x, u=u: rhs(t, x, u), (t_k, t_next), y, dense_output=True, **DOP853_TIGHT
        )
        inside = (ts > t_k + 1e-12) & (ts <= t_next + 1e-12)
        if inside.any():
            out[inside] = sol.sol(ts[inside]).T
        y, t_k = sol.y[:, -1], t_next
    return out


def body_rhs(t, y, u):
    w, q = y[:3], y[3:]
    dw = (u - cross(w, I * w + H)) / I
    return np.concatenate([dw, 0.5 * np.concatenate([[-q[1:] @ w], q[0] * w + cross(q[1:], w)])])


def wheel_rhs(t, y, u):
    w, q, ws = y[:3], y[3:7], y[7:]
    Ifull = np.diag(I)
    dw = np.linalg.solve(
        Ifull - (A_UNIT * J_W) @ A_UNIT.T, -A_UNIT @ u - cross(w, I * w + A_UNIT @ (J_W * ws))
    )
    dq = 0.5 * np.concatenate([[-q[1:] @ w], q[0] * w + cross(q[1:], w)])
    return np.concatenate([dw, dq, u / J_W - A_UNIT.T @ dw])


def test_sample_grid():
    grid, sample, out, src = sample_grid(np.array([0.0, 0.25, 1.0]), 0.3)
    np.testing.assert_allclose(grid, [0.0, 0.25, 0.3, 0.6, 0.9, 1.0])
    assert sample.tolist() == [True, False, True, True, True, False] and out.tolist() == [0, 1, 5]
    assert src.tolist() == [0, 1, -2, -3, -4, 2]  # ts[0], ts[1], samples 1-3, ts[2]
    grid, sample, out, src = sample_grid(np.linspace(0.0, 1.0, 11), 0.1)  # 3 × 0.1 ≠ 0.3: merged
    assert len(grid) == 11 and sample[:-1].all() and not sample[-1]


def test_pd_loop_vs_scipy_and_fast_path():
    """The quaternion PD law on a gyrostat (body torque) and on four wheels with a saturated
    motor-torque bound, held over T_c = 0.1: SciPy integrated sample by sample within RK4's
    error (h = 0.02); the kernel equals the Diffrax path to 1e-13."""
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    g = rj.Gyrostat(I, h=H)
    law = rj.control.quaternion_pd(2.0, 3.0, Q_T)
    kw = dict(controller=law, control_period=0.1)
    tr = rj.simulate(g, W0, q0, TS, solver=rj.RK4(), **kw, **FIXED)
    slow = rj.simulate(g, W0, q0, TS, solver=rj.ExplicitRK(rj.RK4()), **kw, **FIXED)
    np.testing.assert_allclose(tr.omega, slow.omega, rtol=0, atol=1e-13)
    ref = held_reference(
        body_rhs, np.r_[W0, q0], lambda t, y: pd_np(2.0, 3.0, y[3:], y[:3]), 0.1, TS
    )
    np.testing.assert_allclose(tr.omega, ref[:, :3], atol=1e-9)
    np.testing.assert_allclose(tr.quat, ref[:, 3:], atol=1e-9)
    assert tr.command.shape == (30, 3)
    np.testing.assert_allclose(tr.control_ts, 0.1 * np.arange(30), atol=1e-12)

    umax = 0.05
    gw = rj.Gyrostat(np.diag(I), wheel_axes=AXES, wheel_inertia=J_W, wheel_torque_max=umax)
    law = rj.control.quaternion_pd(2.0, 3.0, Q_T, wheel_axes=AXES)
    ws0 = np.array([10.0, -5.0, 0.0, 3.0])
    kw = dict(controller=law, control_period=0.1, wheel_speed0=ws0)
    tr = rj.simulate(gw, W0, q0, TS, solver=rj.RK4(), **kw, **FIXED)
    slow = rj.simulate(gw, W0, q0, TS, solver=rj.ExplicitRK(rj.RK4()), **kw, **FIXED)
    np.testing.assert_allclose(tr.wheel_speed, slow.wheel_speed, rtol=1e-14, atol=1e-12)

    def wheel_command(t, y):
        return np.clip(-np.linalg.pinv(A_UNIT) @ pd_np(2.0, 3.0, y[3:7], y[:3]), -umax, umax)

    commands = []
    ref = held_reference(wheel_rhs, np.r_[W0, q0, ws0], wheel_command, 0.1, TS, commands)
    np.testing.assert_allclose(tr.omega, ref[:, :3], atol=1e-9)
    np.testing.assert_allclose(tr.wheel_speed, ref[:, 7:], atol=1e-7)
    assert np.any(np.abs(tr.command) == umax)  # the bound was reached
    # the commands the kernel records at the samples: the Diffrax path's, and SciPy's loop's
    np.testing.assert_allclose(tr.command, slow.command, rtol=0, atol=1e-13)
    np.testing.assert_allclose(tr.command, np.array(commands), rtol=0, atol=1e-8)


@pytest.mark.parametrize("wheel", [False, True])
def test_bang_bang_slew_time(wheel):
    """Rest-to-rest eigenaxis slew about the principal axis z by θ = π/2 with torque ±u held
    from samples T_c = 0.25 (the switch at t_f/2 on a sample): at `t_f = 2 √(θ J / u) = 4` the
    body is at rest at θ, to RK4's error with steps (h ≤ 0.1) aligned to the samples. With a
    wheel on z the body torque is the motor's reaction and J = I_z − J_w; the controller asks
    for 10 u and the bound clips it to u."""
    theta, u, tf = np.pi / 2, np.pi / 4, 4.0
    if wheel:
        g = rj.Gyrostat([1.5, 1.8, 2.2], wheel_axes=[[0.0], [0.0], [1.0]], wheel_inertia=[0.2],
                        wheel_torque_max=u)  # fmt: skip
        sign = -10.0
    else:
        g, sign = rj.Gyrostat([1.5, 1.8, 2.0]), 1.0

    def bang_bang(t, w, q, params):
        level = jnp.where(t < tf / 2 - 0.125, u, jnp.where(t < tf - 0.125, -u, 0.0))
        return sign * level * (jnp.ones(1) if wheel else jnp.array([0.0, 0.0, 1.0]))

    ts = np.array([0.0, 1.0, 2.0, 3.0, 3.9, 4.0, 5.0])
    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.1)
    tr = rj.simulate(g, np.zeros(3), None, ts, controller=bang_bang, control_period=0.25, **fixed)
    angle = 2 * np.arctan2(tr.quat[:, 3], tr.quat[:, 0])
    np.testing.assert_allclose(tr.omega[5:], 0.0, atol=1e-12)
    np.testing.assert_allclose(angle[5:], theta, atol=1e-10)
    assert angle[4] < theta - 1e-3 and tr.omega[4, 2] > 1e-3  # not yet there at 3.9
    np.testing.assert_allclose(angle[2], theta / 2, atol=1e-10)  # half way at t_f / 2


@pytest.mark.slow  # over 20 s here (the gradient's compiles)
def test_gain_gradient():
    """`jax.grad` of a closed-loop cost w.r.t. the PD gains passed as `controller_params` (kernel
    path) equals central differences."""
    g = rj.Gyrostat(I, h=H)
    law = rj.control.quaternion_pd(1.0, 1.0, Q_T)
    ts = np.array([0.0, 1.0, 2.0])

    def cost(gains):
        tr = rj.simulate(g, W0, None, ts, controller=law, control_period=0.1,
                         controller_params={"kp": gains[0], "kd": gains[1]}, solver=rj.RK4(),
                         **FIXED)  # fmt: skip
        qe = rj.quat.mul(rj.quat.conj(jnp.asarray(Q_T)), tr.quat[-1])
        return jnp.sum(qe[1:] ** 2) + jnp.sum(tr.omega[-1] ** 2)

    x = jnp.array([2.0, 3.0])
    grad = jax.grad(cost)(x)
    eps = 1e-5
    fd = [(cost(x + eps * e) - cost(x - eps * e)) / (2 * eps) for e in jnp.eye(2)]
    np.testing.assert_allclose(grad, fd, rtol=1e-6)


@pytest.mark.slow  # over 20 s here (the gradient's compiles)
def test_command_effort_gradient():
    """`jax.grad` of the control effort `Σ_k |u_k|²` (the recorded commands) and of the final
    state w.r.t. the gains on the wheels: the kernel's adjoint (the commands' cotangents enter
    at their samples) equals the Diffrax path's and central differences."""
    gw = rj.Gyrostat(np.diag(I), wheel_axes=AXES, wheel_inertia=J_W, wheel_torque_max=0.05)
    law = rj.control.quaternion_pd(1.0, 1.0, Q_T, wheel_axes=AXES)
    ts = np.array([0.0, 0.5, 1.0])

    def cost(gains, solver):
        tr = rj.simulate(gw, W0, None, ts, controller=law, control_period=0.1, solver=solver,
                         controller_params={"kp": gains[0], "kd": gains[1]}, **FIXED)  # fmt: skip
        return jnp.sum(tr.command**2) + jnp.sum(tr.omega[-1] ** 2)

    x = jnp.array([0.05, 0.08])  # small gains: the bound is not reached (differentiable)
    grad = jax.grad(cost)(x, rj.RK4())
    np.testing.assert_allclose(grad, jax.grad(cost)(x, rj.ExplicitRK(rj.RK4())), rtol=1e-11)
    eps = 1e-6
    fd = [
        (cost(x + eps * e, rj.RK4()) - cost(x - eps * e, rj.RK4())) / (2 * eps) for e in jnp.eye(2)
    ]
    np.testing.assert_allclose(grad, fd, rtol=1e-6)


@pytest.mark.parametrize("solver", [rj.RK4(), rj.ExplicitRK(rj.RK4())], ids=["kernel", "diffrax"])
def test_closed_loop_failures_are_named(solver):
    """On both paths: more steps in an output interval than `max_steps` is the max_steps
    error, and a controller that returns NaN is reported, not returned as numbers."""
    g = rj.Gyrostat(I, h=H)
    law = rj.control.quaternion_pd(2.0, 3.0, Q_T)
    kw = dict(controller=law, control_period=0.1, solver=solver, **FIXED)
    with pytest.raises(rj.IntegrationError, match="max_steps"):
        rj.simulate(g, W0, None, TS, max_steps=3, **kw)

    def broken(t, w, q, params):
        return jnp.where(t > 1.0, jnp.nan, 0.0) * jnp.ones(3)

    with pytest.raises(
        rj.IntegrationError, match=r"controller returned a non-finite command .* t = 1\.1"
    ):
        rj.simulate(g, W0, None, TS, controller=broken, control_period=0.1, solver=solver, **FIXED)


@pytest.mark.slow  # the reverse kernel with output times, and the Diffrax path's jacfwd
@pytest.mark.parametrize("solver", [rj.RK4(), rj.ExplicitRK(rj.RK4())], ids=["kernel", "diffrax"])
def test_derivatives_wrt_the_output_times_of_a_closed_loop(solver):
    """The sample grid is built from the values of `ts`, and carries their derivatives: moving
    the last output time moves where the state is read, moving `ts[0]` moves every sample with
    it. jacrev and jacfwd equal central differences (they were zero)."""
    law = rj.control.quaternion_pd(2.0, 3.0, Q_T)
    kw = dict(controller=law, control_period=0.1, solver=solver, **FIXED)

    def end(times):
        return rj.simulate(rj.Gyrostat(I, h=H), W0, None, times, **kw).omega[-1]

    ts = jnp.array([0.02, 0.55, 0.97])
    e = jnp.eye(3)
    fd = jnp.stack([(end(ts + 1e-6 * e[i]) - end(ts - 1e-6 * e[i])) / 2e-6 for i in (0, 2)], -1)
    for jac in (jax.jacrev(end), jax.jacfwd(end)):
        np.testing.assert_allclose(jac(ts)[:, [0, 2]], fd, rtol=0, atol=1e-8)
    assert float(jnp.abs(fd).min()) > 1e-3  # (a zero derivative would fail)


@pytest.mark.slow  # ~20 s: the compiles of jax.jacrev
@pytest.mark.parametrize("fixed", [False, True], ids=["adaptive", "kernel"])
def test_derivatives_wrt_an_output_time_that_is_a_sample(fixed):
    """An output time on a sample (1.5 = 5 × 0.3) is one grid point: its derivative moved the
    sample with the output time (d ω(2)/d ts[3] was 4.6e-7, not 0, and d ω(2)/dT off by 3e-7).
    The sample follows ts[0] + k period; the output's own derivative is the field just after
    the sample, the right-sided difference."""
    g = rj.Gyrostat(np.array([2.0, 3.0, 4.0]))
    w0 = jnp.array([0.5, 0.1, 0.0])
    opts = dict(FIXED, solver=rj.RK4()) if fixed else {}

    def omega(times):
        law = lambda t, w, q, p: -w + jnp.array([0.1 * t, 0.0, 0.0])  # noqa: E731
        return rj.simulate(g, w0, None, times, controller=law, control_period=0.3, **opts).omega

    ts = jnp.array([0.0, 0.5, 1.0, 1.5, 2.0])
    h, e = 1e-6, jnp.eye(5)
    jac = jax.jacrev(lambda t: omega(t)[-1, 0])(ts)
    fd = [(omega(ts + h * e[i])[-1, 0] - omega(ts - h * e[i])[-1, 0]) / (2 * h) for i in range(5)]
    np.testing.assert_allclose(jac, fd, rtol=0, atol=1e-8)
    own = jax.jacrev(lambda t: omega(t)[3])(ts)[:, 3]
    right = (omega(ts + 1e-7 * e[3])[3] - omega(ts)[3]) / 1e-7
    np.testing.assert_allclose(own, right, rtol=0, atol=1e-6)


def test_float32_and_an_array_period():
    """float32 inputs give a float32 closed loop in a float64 process (the sample grid's
    offsets were NumPy float64 and promoted the state); a concrete array period is a period
    (it was refused as traced)."""
    f32 = np.float32
    gy = rj.Gyrostat(I.astype(f32), h=H.astype(f32))
    law = rj.control.quaternion_pd(0.5, 1.0, Q_T.astype(f32))
    tr = rj.simulate(gy, W0.astype(f32), None, TS.astype(f32), controller=law, control_period=0.25)
    assert {tr.omega.dtype, tr.quat.dtype, tr.h.dtype, tr.ts.dtype} == {np.dtype(f32)}
    ref = rj.simulate(rj.Gyrostat(I, h=H), W0, None, TS, controller=law, control_period=0.25)
    np.testing.assert_allclose(tr.omega, ref.omega, atol=1e-5)
    arr = rj.simulate(rj.Gyrostat(I, h=H), W0, None, TS, controller=law,
                      control_period=jnp.asarray(0.25))  # fmt: skip
    np.testing.assert_array_equal(arr.omega, ref.omega)


def test_negative_gains_are_refused():
    """A negative gain drives the body away (B-dot would add energy): a clear error."""
    with pytest.raises(ValueError, match="gain must be non-negative, got -1.0"):
        rj.control.bdot(-1.0)
    with pytest.raises(ValueError, match="kd must be non-negative, got min -0.5"):
        rj.control.quaternion_pd(2.0, jnp.array([1.0, -0.5, 1.0]), Q_T)
    assert float(rj.control.bdot(0.0).gain) == 0.0  # zero: no control, allowed
    # a zero spin axis (NaN commands before) or a non-unit one: as the Gyrostat refuses them
    for column in ([0.0, 0.0, 0.0], [0.0, 0.0, 2.0]):
        with pytest.raises(ValueError, match=r"wheel_axes \(columns\) must be a unit vector"):
            rj.control.quaternion_pd(1.0, 1.0, Q_T, wheel_axes=np.c_[np.eye(3)[:, :2], column])


def test_laws_take_batches():
    """The laws map leading batch dimensions, as every public function (quaternion_pd indexed
    the quaternion's first axis: a batch was a TypeError); each row as the law of one body."""
    rng = np.random.default_rng(4)
    w, q = rng.normal(size=(5, 3)), rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    laws = (
        rj.control.quaternion_pd(2.0, jnp.array([1.0, 2.0, 3.0]), Q_T),
        rj.control.quaternion_pd(2.0, 3.0, Q_T, wheel_axes=AXES),
        rj.control.bdot(2.0),
    )
    for law in laws:
        rows = np.stack([law(0.0, w[i], q[i]) for i in range(5)])
        np.testing.assert_allclose(law(0.0, w, q), rows, rtol=1e-14, atol=1e-15)
    # the PD law against its formula, the error quaternion from SciPy: q_e = q_target⁻¹ ∘ q
    qe = Rotation.from_quat(Q_T, scalar_first=True).inv() * Rotation.from_quat(q, scalar_first=True)
    qe = qe.as_quat(scalar_first=True, canonical=False)
    kp, kd = 2.0, np.array([1.0, 2.0, 3.0])
    u = -kp * np.sign(qe[:, :1]) * qe[:, 1:] - kd * w
    np.testing.assert_allclose(laws[0](0.0, w, q), u, rtol=1e-12, atol=1e-14)


def test_bdot():
    """The B-dot torque `k (Ω × B) × B` (B the space field in body axes) matches its formula, and
    held at T_c = 0.05 it removes kinetic energy from a tumbling body (down to the rotation
    about the field, which it cannot remove)."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w = rng.normal(size=3)
    law = rj.control.bdot(2.0, lambda t: jnp.array([0.3, -0.2, 0.9]))
    B = rj.quat.rotate(rj.quat.conj(jnp.asarray(q)), jnp.array([0.3, -0.2, 0.9]))
    np.testing.assert_allclose(law(0.0, w, q), 2.0 * np.cross(np.cross(w, B), B), rtol=1e-13)
    g = rj.Gyrostat(I)
    tr = rj.simulate(g, W0 * 5, None, np.linspace(0, 10, 6), controller=rj.control.bdot(1.0),
                     control_period=0.05, solver=rj.RK4(), **FIXED)  # fmt: skip
    E = 0.5 * np.sum(I * tr.omega**2, -1)
    assert np.all(np.diff(E) < 0) and E[-1] < 0.8 * E[0]
