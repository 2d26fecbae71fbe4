"""6-DOF rigid body: free flight, constant force, off-centre loads against an independent SciPy
solve_ivp model (rotation-matrix kinematics) and the momentum theorems of 004, point velocity."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from rigidjax import RigidBody, simulate
from rigidjax.mechanics import sixdof

MASS = 2.5
I_TENSOR = (
    Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    @ np.diag([1.0, 1.7, 2.2])
    @ Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix().T
)  # full (non-diagonal) tensor
BODY = RigidBody(I_TENSOR, MASS)
R0 = np.array([0.5, -1.0, 2.0])
V0 = np.array([0.3, 0.1, -0.2])
Q0 = Rotation.from_rotvec([0.4, 0.1, -0.7]).as_quat(scalar_first=True)
W0 = np.array([0.8, -0.5, 1.1])
TS = np.linspace(0.0, 4.0, 15)
TIGHT = dict(rtol=1e-12, atol=1e-12)

A1 = np.array([0.3, -0.2, 0.4])  # body point where a space-fixed-direction force acts
A2 = np.array([-0.5, 0.1, 0.0])  # body point of a body-fixed thruster
F_BODY = np.array([0.0, 0.4, 0.2])


def f_space(t):
    return jnp.stack([0.5 * jnp.cos(t), -0.3, 0.2 * t])


class Loads(eqx.Module):
    """Test loads with traced switches, so every variant shares one compilation: a uniform field
    `gravity` (force m g at the COM), the off-centre forces scaled by `on`, and `lever` (1: the
    correct moment a × f; 0: a deliberately wrong model that forgets it)."""

    gravity: jax.Array = eqx.field(converter=jnp.asarray, default=(0.0, 0.0, 0.0))
    on: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)
    lever: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)

    def __call__(self, t, state):
        w = sixdof.wrench_at_point(self.on * f_space(t), A1, state.q) + sixdof.wrench_at_point(
            self.on * F_BODY, A2, state.q, force_frame="body"
        )
        return sixdof.Wrench(w.force + MASS * self.gravity, self.lever * w.torque)


loads = Loads()


def scipy_6dof(ts):
    """Independent model: Ṗ = P Ω̂ on the 9 matrix entries, m V̇ = Σf, I Ω̇ = Σ a × f_body − Ω × IΩ,
    plus the integrals J_F = ∫ Σf dt and J_K = ∫ Σ (P a) × f dt (space axes)."""
    I_inv = np.linalg.inv(I_TENSOR)

    def hat(w):
        return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])

    def rhs(t, y):
        V, P, W = y[3:6], y[6:15].reshape(3, 3), y[15:18]
        fs1 = np.array([0.5 * np.cos(t), -0.3, 0.2 * t])
        fs2 = P @ F_BODY
        F = fs1 + fs2
        K_body = np.cross(A1, P.T @ fs1) + np.cross(A2, F_BODY)
        K_space = np.cross(P @ A1, fs1) + np.cross(P @ A2, fs2)
        dW = I_inv @ (K_body - np.cross(W, I_TENSOR @ W))
        return np.concatenate([V, F / MASS, (P @ hat(W)).ravel(), dW, F, K_space])

    P0 = Rotation.from_quat(Q0, scalar_first=True).as_matrix()
    y0 = np.concatenate([R0, V0, P0.ravel(), W0, np.zeros(6)])
    sol = solve_ivp(rhs, (ts[0], ts[-1]), y0, "DOP853", t_eval=ts, rtol=1e-13, atol=1e-13)
    y = sol.y.T
    return dict(
        R=y[:, :3], V=y[:, 3:6], P=y[:, 6:15].reshape(-1, 3, 3), W=y[:, 15:18],
        JF=y[:, 18:21], JK=y[:, 21:24],
    )  # fmt: skip


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_free_flight_uniform_translation_and_rotation_matches_simulate():
    tr = sixdof.simulate_6dof(BODY, R0, V0, Q0, W0, TS, **TIGHT)
    np.testing.assert_allclose(tr.R, R0 + TS[:, None] * V0, atol=1e-12)
    np.testing.assert_allclose(tr.V, np.broadcast_to(V0, tr.V.shape), atol=1e-13)
    ref = simulate(BODY, W0, Q0, TS, **TIGHT)
    np.testing.assert_allclose(tr.omega, ref.omega, atol=1e-10)
    np.testing.assert_allclose(tr.matrix, ref.matrix, atol=1e-10)
    np.testing.assert_allclose(jnp.linalg.norm(tr.quat, axis=-1), 1, atol=1e-14)
    # free body: kinetic energy and space angular momentum about the COM conserved
    L = sixdof.angular_momentum(BODY, tr.state)
    np.testing.assert_allclose(L, np.broadcast_to(L[0], L.shape), atol=1e-10)
    T = sixdof.kinetic_energy(BODY, tr.state)
    np.testing.assert_allclose(T, T[0], rtol=1e-10)


def test_constant_force_at_com_gives_parabola():
    g = np.array([0.0, 0.0, -9.81])

    tr = sixdof.simulate_6dof(BODY, R0, V0, Q0, W0, TS, Loads(gravity=g, on=0.0), **TIGHT)
    np.testing.assert_allclose(tr.R, R0 + TS[:, None] * V0 + 0.5 * TS[:, None] ** 2 * g, atol=1e-10)
    np.testing.assert_allclose(tr.V, V0 + TS[:, None] * g, atol=1e-11)
    ref = simulate(BODY, W0, Q0, TS, **TIGHT)  # rotation is unaffected by a force at the COM
    np.testing.assert_allclose(tr.omega, ref.omega, atol=1e-10)
    np.testing.assert_allclose(tr.matrix, ref.matrix, atol=1e-10)


def test_off_centre_loads_against_scipy_and_momentum_theorems():
    tr = sixdof.simulate_6dof(BODY, R0, V0, Q0, W0, TS, loads, **TIGHT)
    ref = scipy_6dof(TS)
    np.testing.assert_allclose(tr.R, ref["R"], atol=1e-9)
    np.testing.assert_allclose(tr.V, ref["V"], atol=1e-9)
    np.testing.assert_allclose(tr.matrix, ref["P"], atol=1e-9)
    np.testing.assert_allclose(tr.omega, ref["W"], atol=1e-9)
    # Ṗ = F: m(V − V0) = ∫ F dt; Ṁ = K about the COM (space axes): M − M0 = ∫ Σ a × f dt
    np.testing.assert_allclose(
        sixdof.linear_momentum(BODY, tr.state) - MASS * V0, ref["JF"], atol=1e-9
    )
    L = sixdof.angular_momentum(BODY, tr.state, frame="space")
    np.testing.assert_allclose(L - L[0], ref["JK"], atol=1e-9)
    # the loads really torque the body (a test that can fail): L changes by O(1)
    assert np.max(np.abs(ref["JK"])) > 0.1
    # a wrong lever arm (forgetting a × F) is detected
    bad = sixdof.simulate_6dof(BODY, R0, V0, Q0, W0, TS, Loads(lever=0.0), **TIGHT)
    assert np.max(np.abs(bad.omega - ref["W"])) > 1e-2


def test_point_velocity_matches_finite_differences():
    h = 1e-3
    centres = np.array([0.7, 1.9, 3.1])
    ts = (centres[:, None] + h * np.arange(-2, 3)[None, :]).ravel()  # 15 times, same as TS
    tr = sixdof.simulate_6dof(BODY, R0, V0, Q0, W0, ts, loads, **TIGHT)
    point = np.array([0.9, -0.4, 0.6])
    x = np.asarray(sixdof.point_position(tr.state, point)).reshape(3, 5, 3)
    fd = (x[:, 0] - 8 * x[:, 1] + 8 * x[:, 3] - x[:, 4]) / (12 * h)  # 4th-order central
    v = np.asarray(sixdof.point_velocity(tr.state, point)).reshape(3, 5, 3)[:, 2]
    np.testing.assert_allclose(v, fd, atol=1e-9)
    # and not the naive V (rotation contributes): the point really moves differently
    assert np.max(np.abs(v - np.asarray(tr.V).reshape(3, 5, 3)[:, 2])) > 0.1


def test_point_helpers_take_several_points():
    """Points `(N, 3)` on one state broadcast as in point_position: V + P(Ω × r) per point."""
    q = Rotation.from_rotvec([0.2, 0.9, -0.3]).as_quat(scalar_first=True)
    V, W = np.array([1.0, -0.5, 0.2]), np.array([0.3, 0.0, 1.1])
    state = sixdof.RigidState(jnp.zeros(3), jnp.asarray(V), jnp.asarray(q), jnp.asarray(W))
    points = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, -1.0], [0.5, 0.5, 0.5]])
    P = Rotation.from_quat(q, scalar_first=True).as_matrix()
    np.testing.assert_allclose(sixdof.point_position(state, points), points @ P.T, atol=1e-15)
    want = V + np.cross(W, points) @ P.T
    np.testing.assert_allclose(sixdof.point_velocity(state, points), want, atol=1e-15)


def test_momenta_and_energy_of_a_batch_of_bodies_along_time():
    """Bodies `(2,)` with states `(2, T, ...)` (as `jax.vmap(simulate_6dof)` gives): each body's
    own values, as `rigidjax.energy` takes the same layout; `frame` is checked."""
    bodies = RigidBody(np.stack([I_TENSOR, 2 * I_TENSOR]), np.array([MASS, 1.0]))
    rng = np.random.default_rng(4)
    q = Rotation.random(10, random_state=5).as_quat(scalar_first=True).reshape(2, 5, 4)
    state = sixdof.RigidState(*(jnp.asarray(rng.normal(size=(2, 5, 3))) for _ in range(2)),
                              jnp.asarray(q), jnp.asarray(rng.normal(size=(2, 5, 3))))  # fmt: skip
    for k in range(2):
        one = RigidBody(np.asarray(bodies.inertia[k]), float(bodies.mass[k]))
        st = jax.tree.map(lambda a, k=k: a[k], state)
        for f in (sixdof.kinetic_energy, sixdof.linear_momentum, sixdof.angular_momentum):
            np.testing.assert_allclose(f(bodies, state)[k], f(one, st), rtol=1e-14)
        P = Rotation.from_quat(q[k], scalar_first=True).as_matrix()
        M = P @ (np.asarray(one.inertia) @ np.asarray(st.omega)[..., None])
        np.testing.assert_allclose(sixdof.angular_momentum(one, st), M[..., 0], rtol=1e-13)
        V, W = np.asarray(st.V), np.asarray(st.omega)
        T = 0.5 * one.mass * np.sum(V**2, -1) + 0.5 * np.einsum("ti,ij,tj->t", W, one.inertia, W)
        np.testing.assert_allclose(sixdof.kinetic_energy(one, st), T, rtol=1e-13)
    with pytest.raises(ValueError, match="frame must be 'space' or 'body'"):
        sixdof.angular_momentum(bodies, state, frame="spcae")
    # 5 samples for 2 bodies: named (an einsum's label error before)
    with pytest.raises(ValueError, match=r"the body's batch \(2,\) does not match omega's"):
        sixdof.kinetic_energy(bodies, jax.tree.map(lambda a: a[0], state))


def test_wrench_helpers():
    q = Rotation.from_rotvec([0.2, 0.9, -0.3]).as_quat(scalar_first=True)
    P = Rotation.from_quat(q, scalar_first=True).as_matrix()
    f = np.array([[1.0, 2.0, -0.5], [0.3, 0.0, 0.7]])
    a = np.array([[0.1, -0.2, 0.3], [0.0, 0.5, -0.1]])
    w = sixdof.wrench_at_point(f, a, q).total()
    np.testing.assert_allclose(w.force, f.sum(0))
    # K = Σ a × f about the COM, computed in space and taken to body axes
    K_space = sum(np.cross(P @ ai, fi) for ai, fi in zip(a, f, strict=True))
    np.testing.assert_allclose(w.torque, P.T @ K_space, atol=1e-14)
    wb = sixdof.wrench_at_point(f[0], a[0], q, force_frame="body")
    np.testing.assert_allclose(wb.force, P @ f[0], atol=1e-14)
    np.testing.assert_allclose(wb.torque, np.cross(a[0], f[0]), atol=1e-14)
    # a couple: same torque whatever the points
    c = sixdof.wrench_at_point(np.stack([f[0], -f[0]]), a, q).total()
    np.testing.assert_allclose(c.force, 0, atol=1e-15)
    K = P.T @ np.cross(P @ (a[0] - a[1]), f[0])
    np.testing.assert_allclose(c.torque, K, atol=1e-14)
    np.testing.assert_allclose(sixdof.pure_torque(P @ K, q, frame="space").torque, K, atol=1e-14)


def test_bad_input():
    with pytest.raises(ValueError, match="one body"):
        sixdof.simulate_6dof(RigidBody(np.ones((2, 3)) + 1), R0, V0, Q0, W0, TS)
    with pytest.raises(ValueError, match="unit quaternion"):
        sixdof.simulate_6dof(BODY, R0, V0, 2 * Q0, W0, TS)
    with pytest.raises(ValueError, match=r"R0 must have shape \(3,\)"):
        sixdof.simulate_6dof(BODY, np.zeros((2, 3)), V0, Q0, W0, TS)
    with pytest.raises(ValueError, match="omega0 must be finite"):
        sixdof.simulate_6dof(BODY, R0, V0, Q0, [np.nan, 0, 0], TS)
    with pytest.raises(TypeError, match="must return a rigidjax.sixdof.Wrench"):
        sixdof.simulate_6dof(BODY, R0, V0, Q0, W0, TS, lambda t, s: jnp.zeros(3))
    with pytest.raises(ValueError, match="force_frame"):
        sixdof.wrench_at_point(F_BODY, A1, Q0, force_frame="world")


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_jit_and_gradient():
    """Free flight: ∂R(t)/∂V0 = t E, through reverse-mode differentiation of the solve (jit, with
    constant R0 closed over)."""

    @jax.jit
    def final_position(v0):
        tr = sixdof.simulate_6dof(BODY, R0, v0, Q0, W0, TS, **TIGHT)
        return tr.R[-1]

    w = np.array([1.0, -2.0, 0.5])
    g = jax.grad(lambda v: final_position(v) @ w)(jnp.asarray(V0))
    np.testing.assert_allclose(g, TS[-1] * w, rtol=1e-10)
