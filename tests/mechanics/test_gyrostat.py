"""The gyrostat `I Ω̇ + Ω × (IΩ + h) = τ − ḣ` (constant h, h_rate(t), reaction wheels) against
SciPy DOP853 on equations written here in NumPy, its fast path against its Diffrax path, the
zero-h gyrostat against `simulate`, its integrals, and gradients against central differences."""

import shutil
import time
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rigidjax as rj
from rigidjax.kernels import _build
from rigidjax.mechanics import gyrostat as gy
from tests.helpers import DOP853_TIGHT, cross

needs_compiler = pytest.mark.skipif(
    shutil.which(_build._compiler()[0]) is None, reason="no C++ compiler ($CXX or c++)"
)

TS = np.linspace(0.0, 2.0, 5)
FIXED = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=0.01)
TENSOR = np.array([[1.2, 0.1, -0.05], [0.1, 1.5, 0.02], [-0.05, 0.02, 1.9]])
W0 = np.array([0.5, -1.0, 2.0])
Q0 = np.array([0.9, 0.2, -0.3, 0.1]) / np.sqrt(0.95)
H = np.array([0.3, -0.2, 0.5])
AXES = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.6], [0.0, 0.0, 1.0, 0.52915026]])
J_W = np.array([0.01, 0.02, 0.015, 0.01])
WS0 = np.array([30.0, -20.0, 10.0, 5.0])


def tau(t, w, q):
    return jnp.array([0.1 * jnp.sin(t), 0.05, -0.02 * w[0]])


def tau_np(t, w, q):
    return np.array([0.1 * np.sin(t), 0.05, -0.02 * w[0]])


def h_rate(t):
    return jnp.array([0.2 * jnp.cos(t), -0.1, 0.05 * t])


def gyrostat_rhs(I, h=None, h_rate=None, A=None, J=None, torque=None):
    """NumPy right-hand side of y = (Ω, q, [h or ω_w]): `I Ω̇ = τ − ḣ − Ω × (IΩ + h)`; with
    wheels `(I − A J Aᵀ) Ω̇ = τ − Ω × (IΩ + A J ω_w)`, `ω̇_w = −Aᵀ Ω̇` (no motor torque)."""
    I = np.asarray(I, float)

    def rhs(t, y):
        w, q = y[:3], y[3:7]
        K = np.zeros(3) if torque is None else torque(t, w, q)
        dq = 0.5 * np.concatenate([[-q[1:] @ w], q[0] * w + cross(q[1:], w)])
        if A is not None:
            hw = A @ (J * y[7:])
            dw = np.linalg.solve(I - (A * J) @ A.T, K - cross(w, I @ w + hw))
            return np.concatenate([dw, dq, -A.T @ dw])
        if h_rate is not None:
            hd = np.asarray(h_rate(t), float)
            dw = np.linalg.solve(I, K - hd - cross(w, I @ w + y[7:]))
            return np.concatenate([dw, dq, hd])
        return np.concatenate([np.linalg.solve(I, K - cross(w, I @ w + h)), dq])

    return rhs


CASES = {
    "h": (dict(h=H), dict(torque=tau), dict(h=H, torque=tau_np)),
    "h_rate": (dict(h=H), dict(h_rate=h_rate, torque=tau), dict(h_rate=h_rate)),
    "wheels": (
        dict(wheel_axes=AXES, wheel_inertia=J_W),
        dict(wheel_speed0=WS0, torque=tau),
        dict(A=AXES / np.linalg.norm(AXES, axis=0), J=J_W, torque=tau_np),
    ),
}


@needs_compiler
@pytest.mark.parametrize("case", sorted(CASES))
def test_gyrostat_fast_path_and_scipy(case):
    """Each kind of gyrostat (full inertia tensor, external torque) on the kernel equals its
    Diffrax path on the same RK4 steps to 1e-13, and SciPy DOP853 on the NumPy equations within
    RK4's error at h = 0.01."""
    make, kw, ref = CASES[case]
    g = rj.Gyrostat(TENSOR, **make)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the fast path takes the field: no fallback warning
        fast = rj.simulate(g, W0, Q0, TS, solver=rj.RK4(), **kw, **FIXED)
    slow = rj.simulate(g, W0, Q0, TS, solver=rj.ExplicitRK(rj.RK4()), **kw, **FIXED)
    for name in ("omega", "quat", "h") + (("wheel_speed",) if case == "wheels" else ()):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-14, atol=1e-13)
    if case == "h_rate":
        ref = dict(h_rate=lambda t: np.array([0.2 * np.cos(t), -0.1, 0.05 * t]), torque=tau_np)
    extra = {"h": [], "h_rate": [H], "wheels": [WS0]}[case]
    y0 = np.concatenate([W0, Q0, *extra])
    sol = solve_ivp(gyrostat_rhs(TENSOR, **ref), (0, 2), y0, t_eval=TS, **DOP853_TIGHT)
    np.testing.assert_allclose(fast.omega, sol.y[:3].T, atol=1e-8)
    np.testing.assert_allclose(fast.quat, sol.y[3:7].T, atol=1e-8)
    if case == "wheels":
        np.testing.assert_allclose(fast.wheel_speed, sol.y[7:].T, rtol=1e-9, atol=1e-8)
    if case == "h_rate":
        np.testing.assert_allclose(fast.h, sol.y[7:].T, atol=1e-10)


def test_zero_h_gyrostat_is_simulate():
    """`Gyrostat(I, h=0)` through its own field equals `simulate(RigidBody(I))` with the same
    torque and steps (principal moments and a tensor), to 1e-13; another formulation
    (`kinematics="rotvec"`) of a constant-h gyrostat agrees with the quaternion one."""
    for I in (np.array([1.0, 2.0, 3.0]), TENSOR):
        g = rj.Gyrostat(I, h=np.zeros(3))
        a = rj.simulate(g, W0, Q0, TS, tau, solver=rj.RK4(), **FIXED)
        b = rj.simulate(rj.RigidBody(I), W0, Q0, TS, tau, solver=rj.RK4(), **FIXED)
        np.testing.assert_allclose(a.omega, b.omega, rtol=0, atol=1e-13)
        np.testing.assert_allclose(a.quat, b.quat, rtol=0, atol=1e-13)
        assert not np.any(a.h)
    g = rj.Gyrostat(TENSOR, h=H)
    a = rj.simulate(g, W0, Q0, TS, solver=rj.RK4(), **FIXED)
    b = rj.simulate(g, W0, Q0, TS, None, "rotvec", solver=rj.RK4(), **FIXED)
    np.testing.assert_allclose(a.omega, b.omega, atol=1e-9)
    np.testing.assert_allclose(rj.quat.canonical(a.quat), rj.quat.canonical(b.quat), atol=1e-9)


def test_batch_and_gradient():
    """A batch of initial states equals a loop over them; the gradient of a final observable
    w.r.t. h (kernel path) equals central differences."""
    g = rj.Gyrostat(TENSOR, h=H)
    w0s = np.stack([W0, -W0, 0.5 * W0])
    batch = rj.simulate(g, w0s, Q0, TS, solver=rj.RK4(), **FIXED)
    for i in range(3):
        one = rj.simulate(g, w0s[i], Q0, TS, solver=rj.RK4(), **FIXED)
        np.testing.assert_allclose(batch.omega[i], one.omega, rtol=0, atol=1e-14)
    assert batch.h.shape == (3, 5, 3)

    def final(h):
        tr = rj.simulate(rj.Gyrostat(TENSOR, h=h), W0, Q0, TS, solver=rj.RK4(), **FIXED)
        return jnp.sum(tr.omega[-1] ** 2) + tr.quat[-1, 1]

    grad = jax.grad(final)(jnp.asarray(H))
    eps = 1e-6
    fd = [(final(H + eps * e) - final(H - eps * e)) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-9)


def test_wheel_integrals():
    """Torque-free wheels spinning freely: the total energy (rotors included) and |IΩ + h| are
    conserved within RK4's error, and `h = A J ω_w` is reported."""
    g = rj.Gyrostat(TENSOR, wheel_axes=AXES, wheel_inertia=J_W)
    tr = rj.simulate(g, W0, Q0, TS, wheel_speed0=WS0, solver=rj.RK4(), **FIXED)
    E, M = gy.energy(g, tr), jnp.linalg.norm(gy.angular_momentum(g, tr), axis=-1)
    assert np.max(np.abs(E / E[0] - 1)) < 1e-9
    assert np.max(np.abs(M / M[0] - 1)) < 1e-9
    A = AXES / np.linalg.norm(AXES, axis=0)
    np.testing.assert_allclose(tr.h, (tr.wheel_speed * J_W) @ A.T, rtol=1e-14)


@needs_compiler
def test_zhukovsky_volterra_integrals_long_run():
    """The constant-h gyrostat's integrals, energy `½ Ω·IΩ` and `|IΩ + h|`, over 1e5 fixed
    steps of Dopri8 (h = 0.01, local error ~1e-18: what is left is rounding) stay within
    1e-13 relative (measured 1.8e-14, 1.5e-14); the run is on the kernel (a few seconds)."""
    g = rj.Gyrostat(np.array([1.0, 2.0, 3.0]), h=np.array([0.5, 1.0, -0.3]))
    ts = np.linspace(0.0, 1000.0, 11)
    start = time.perf_counter()
    tr = rj.simulate(
        g, W0, Q0, ts, solver=diffrax.Dopri8(), max_steps=20_000, **dict(FIXED, dt0=0.01)
    )
    assert int(tr.stats["num_steps"]) == 100_000
    E, M = gy.energy(g, tr), jnp.linalg.norm(gy.angular_momentum(g, tr), axis=-1)
    drift_E, drift_M = np.max(np.abs(E / E[0] - 1)), np.max(np.abs(M / M[0] - 1))
    print(
        f"1e5 Dopri8 steps: {time.perf_counter() - start:.2f} s, drift {drift_E:.2e} {drift_M:.2e}"
    )
    assert drift_E < 1e-13 and drift_M < 1e-13


def test_clear_errors():
    with pytest.raises(ValueError, match="wheel_inertia too large"):
        rj.Gyrostat(np.ones(3), wheel_axes=np.eye(3), wheel_inertia=np.full(3, 1.5))
    with pytest.raises(ValueError, match="give both wheel_axes"):
        rj.Gyrostat(np.ones(3), wheel_axes=np.eye(3))
    with pytest.raises(ValueError, match=r"wheel_torque_max must be a scalar or .*\(3,\)"):
        rj.Gyrostat(np.ones(3), wheel_axes=np.eye(3), wheel_inertia=np.full(3, 0.1),
                    wheel_torque_max=[0.1, 0.2])  # fmt: skip
    for solver in (rj.ExactFreeBody(), rj.LiePoissonSplitting()):
        with pytest.raises(ValueError, match="integrates a rigid body, not a gyrostat"):
            rj.simulate(rj.Gyrostat(np.ones(3), h=[0.0, 0.0, 0.1]), W0, None, TS, solver=solver)
    with pytest.raises(ValueError, match="wheel_speed0"):
        rj.simulate(rj.Gyrostat(np.ones(3)), W0, None, TS, wheel_speed0=np.zeros(3))
    with pytest.raises(ValueError, match="apply to a gyrostat"):
        rj.simulate(rj.RigidBody(np.ones(3)), W0, None, TS, h_rate=h_rate)
    with pytest.raises(ValueError, match="h_rate must return shape"):
        rj.simulate(rj.Gyrostat(np.ones(3)), W0, None, TS, h_rate=lambda t: t)
