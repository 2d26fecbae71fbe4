"""Darboux problem (Zhilin 3.12–3.14): every formulation against closed-form motions."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import darboux, so3
from rigidjax.kinematics import EulerAngles, RotationVector
from rigidjax.solvers.rkmk import RKMK, LieTerm

METHODS = ["rotvec", "quat", "matrix", "euler", "cayley_klein", "geometric"]
TS = jnp.linspace(0.0, 6.0, 7)


class TwoSpins(eqx.Module):
    """P(t) = Rz(a t) Rx(b t): ω = (b cos at, b sin at, a) in space, Ω = (b, a sin bt, a cos bt)
    in the body."""

    a: jax.Array
    b: jax.Array
    frame: str = eqx.field(static=True, default="space")

    def __call__(self, t):
        a, b = self.a, self.b
        if self.frame == "space":
            return jnp.stack([b * jnp.cos(a * t), b * jnp.sin(a * t), a * jnp.ones_like(t)])
        return jnp.stack([b * jnp.ones_like(t), a * jnp.sin(b * t), a * jnp.cos(b * t)])

    def exact(self, ts):
        ts = np.asarray(ts)
        return Rotation.from_euler("ZX", np.stack([self.a * ts, self.b * ts], -1)).as_matrix()


class Coning(eqx.Module):
    """Classical coning P(t) = Rz(Ωt) Rx(β) Rz(−Ωt):
    ω = Ω(−sin β sin Ωt, sin β cos Ωt, 1 − cos β)."""

    rate: float
    beta: float

    def __call__(self, t):
        s = jnp.sin(self.beta)
        w = self.rate * t
        return self.rate * jnp.stack(
            [-s * jnp.sin(w), s * jnp.cos(w), (1 - jnp.cos(self.beta)) + 0 * t]
        )

    def exact(self, ts):
        ts = np.asarray(ts)
        ang = np.stack([self.rate * ts, np.full_like(ts, self.beta), -self.rate * ts], -1)
        return Rotation.from_euler("ZXZ", ang).as_matrix()


SPACE = TwoSpins(jnp.array(0.7), jnp.array(1.3))
BODY = TwoSpins(jnp.array(0.7), jnp.array(1.3), frame="body")
TIGHT = dict(rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("frame", ["space", "body"])
def test_every_method_two_spins(method, frame):
    omega = SPACE if frame == "space" else BODY
    # "ZYX" keeps the Euler chart away from gimbal lock on this motion
    P = darboux(omega, TS, frame=frame, method=method, seq="ZYX", **TIGHT)
    np.testing.assert_allclose(P, SPACE.exact(TS), atol=1e-8)


@pytest.mark.parametrize("method", ["rotvec", "quat", "geometric"])
def test_coning_and_superposition(method, rng):
    """Zhilin (3.12.6): with Q solving Q̇ = ω × Q, P(t) = Q(t) Qᵀ(0) P0 for any P0."""
    cone = Coning(2.0, 0.3)
    P0 = Rotation.random(random_state=3).as_matrix()
    Q = cone.exact(TS)
    P = darboux(cone, TS, P0=P0, method=method, **TIGHT)
    np.testing.assert_allclose(P, Q @ Q[0].T @ P0, atol=1e-9)


def test_fixed_axis_rotation():
    """Zhilin 3.13: ω = w(t) n gives P = exp(θ(t) n × E) P0, θ = ∫ w; the rotation vector keeps
    the direction n iff φ0 ∥ n."""
    n = jnp.array([1.0, 2.0, -2.0]) / 3

    def w(t):
        return (1.0 + 0.5 * jnp.sin(t)) * n

    theta = 1.0 * TS + 0.5 * (1 - jnp.cos(TS))
    for phi0, on_axis in [(0.4 * n, True), (jnp.array([0.3, -0.2, 0.5]), False)]:
        P0 = so3.exp(phi0)
        P, th = darboux(w, TS, P0=P0, method="rotvec", return_state=True, **TIGHT)
        np.testing.assert_allclose(P, so3.exp(theta[:, None] * n) @ P0, atol=1e-9)
        off_axis = np.linalg.norm(th - (th @ n)[:, None] * n, axis=-1)
        if on_axis:
            np.testing.assert_allclose(off_axis, 0, atol=1e-9)
        else:
            assert off_axis[1:].min() > 1e-2


def test_many_turns_shadow():
    """50 full turns: the rotation vector is switched to its shadow and never nears |θ| = 2π."""
    w0 = 2 * np.pi * 5 * np.array([0.6, 0.0, 0.8])
    ts = jnp.linspace(0.0, 10.0, 7)
    P, th = darboux(lambda t: jnp.asarray(w0), ts, method="rotvec", return_state=True, **TIGHT)
    np.testing.assert_allclose(P, Rotation.from_rotvec(np.outer(ts, w0)).as_matrix(), atol=1e-8)
    assert np.all(np.linalg.norm(th, axis=-1) <= np.pi + 1e-12)


def test_theta_dot_identity_and_left_right():
    """θ·θ̇ = θ·ω (3.14.7) on the solution, and left/right problems give the same P."""
    P_space, th = darboux(SPACE, TS, method="rotvec", return_state=True, **TIGHT)
    kin = RotationVector()
    w = jax.vmap(SPACE)(TS)
    thdot = jax.vmap(kin.vector_field)(th, w)
    np.testing.assert_allclose(jnp.sum(th * thdot, -1), jnp.sum(th * w, -1), atol=1e-12)
    P_body = darboux(BODY, TS, frame="body", method="rotvec", **TIGHT)
    np.testing.assert_allclose(P_space, P_body, atol=1e-9)


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_orthogonality_after_1e5_steps():
    """Rotation-vector, normalised-quaternion and geometric paths stay on SO(3) (≤ 1e-12) after
    10⁵ constant steps; the Poisson matrix equation drifts off it (Zhilin's remark)."""
    cone = Coning(3.0, 0.5)
    ts = jnp.array([0.0, 100.0])
    kw = dict(stepsize_controller=diffrax.ConstantStepSize(), dt0=1e-3, max_steps=100_001)
    errs = {}
    for method in ["rotvec", "quat", "geometric", "matrix"]:
        solver = diffrax.Euler() if method == "matrix" else None
        P = darboux(cone, ts, method=method, solver=solver, **kw)
        errs[method] = float(so3.orthogonality_error(P[-1]))
    for method in ["rotvec", "quat", "geometric"]:
        assert errs[method] <= 1e-12, errs
    assert errs["matrix"] > 1e-3, errs


def test_rkmk_order():
    """RKMK with the Dopri5 tableau has classical order 5 (≥ 4 required) on a non-commuting
    motion: the error ratio for halving h is ≈ 2⁵."""
    cone = Coning(2.0, 0.7)
    ts = jnp.array([0.0, 3.0])
    errs = []
    for n in [16, 32, 64]:
        P = darboux(
            cone,
            ts,
            P0=cone.exact(ts)[0],
            method="geometric",
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=3.0 / n,
        )
        errs.append(np.abs(np.asarray(P[-1]) - cone.exact(ts)[-1]).max())
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 4.5), rates


def test_rkmk_body_frame_with_state():
    """RKMK on SO(3) × ℝ: x tracks ∫|Ω| dt alongside the attitude."""
    term = LieTerm(lambda t, y, args: (BODY(t), jnp.linalg.norm(BODY(t))))
    sol = diffrax.diffeqsolve(
        term,
        RKMK(frame="body"),
        0.0,
        6.0,
        None,
        (jnp.eye(3), jnp.array(0.0)),
        saveat=diffrax.SaveAt(ts=TS),
        stepsize_controller=diffrax.PIDController(1e-11, 1e-11),
    )
    R, x = sol.ys
    np.testing.assert_allclose(R, SPACE.exact(TS), atol=1e-9)
    np.testing.assert_allclose(x, np.hypot(0.7, 1.3) * TS, atol=1e-9)
    np.testing.assert_allclose(so3.orthogonality_error(R), 0, atol=1e-13)


def test_sampled_gyro_data():
    t_s = jnp.linspace(0.0, 6.0, 601)
    w_s = jax.vmap(BODY)(t_s)
    P = darboux((t_s, w_s), TS, frame="body", method="quat")
    # backward-difference Hermite interpolation of the samples is second order in their spacing
    np.testing.assert_allclose(P, SPACE.exact(TS), atol=5e-6)


@pytest.mark.slow  # ~50 s: reverse mode through two adaptive solvers
def test_gradients_match_finite_differences():
    """d/da of a scalar of P(t_end) through the solver, for the rotvec and geometric paths."""
    w = np.array([0.2, -0.5, 0.9])

    for method in ["rotvec", "geometric"]:

        def loss(a, method=method):
            P = darboux(TwoSpins(a, jnp.array(1.3)), TS, method=method, **TIGHT)
            return jnp.sum(P[-1] @ w)

        # one compilation per method: the finite differences use the value of the same program
        value_and_grad = jax.jit(jax.value_and_grad(loss))
        g = value_and_grad(jnp.array(0.7))[1]
        h = 1e-5
        fd = (value_and_grad(jnp.array(0.7 + h))[0] - value_and_grad(jnp.array(0.7 - h))[0]) / (
            2 * h
        )
        np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-8)


def test_vmap_over_initial_attitude():
    P0 = jnp.asarray(Rotation.random(3, random_state=0).as_matrix())
    P = jax.vmap(lambda p: darboux(SPACE, TS, P0=p, method="quat", **TIGHT))(P0)
    ref = SPACE.exact(TS)
    np.testing.assert_allclose(P, ref[None] @ np.swapaxes(ref[0], -1, -2) @ P0[:, None], atol=1e-9)


def test_float32():
    P = darboux(SPACE, TS.astype(jnp.float32), method="geometric")
    assert P.dtype == jnp.float32
    np.testing.assert_allclose(P, SPACE.exact(TS), atol=1e-4)


def test_bad_input():
    with pytest.raises(ValueError, match="strictly increasing"):
        darboux(SPACE, jnp.array([0.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match=r"P0 is not a rotation matrix: ‖PᵀP − E‖ = 0\.1"):
        darboux(SPACE, TS, P0=1.05 * jnp.eye(3))
    with pytest.raises(ValueError, match="method must be one of"):
        darboux(omega_fn=SPACE, ts=TS, method="bogus")  # (API.md's argument names)
    # an instance carries its frame and sequence: a different one given was ignored (the
    # instance's problem integrated: 0.73 off the body-frame solution)
    with pytest.raises(ValueError, match="frame='body' disagrees with the method instance's"):
        darboux(SPACE, TS, frame="body", method=RotationVector())
    with pytest.raises(ValueError, match="seq='ZYX' disagrees with the method instance's"):
        darboux(SPACE, TS, method=EulerAngles(seq="XYZ"), seq="ZYX")
    with pytest.raises(ValueError, match="throw=False would return a failed solve's values"):
        darboux(SPACE, TS, max_steps=3, throw=False)
    for shape in [(2,), (3, 3), ()]:
        with pytest.raises(ValueError, match=rf"omega_fn\(t\) must return shape \(3,\).*{shape}"):
            darboux(lambda t, shape=shape: jnp.ones(shape) * t, TS)
    with pytest.raises(Exception, match="non-finite"):
        darboux(lambda t: jnp.array([jnp.nan, 0.0, 0.0]) * t, TS)
    with pytest.raises(Exception, match="maximum number of solver steps"):
        darboux(SPACE, TS, max_steps=3)


@pytest.mark.slow  # ~20 s; test_euler_atlas passes exact gimbal locks in the quick suite
def test_euler_through_gimbal_lock_and_single_chart_advice():
    # ω = e_x from P0 = Rx(−0.5) Ry(δ): the path passes δ from the identity, where ZXZ is locked
    # and ψ̇ ~ 1/δ. The chart-switching atlas integrates near misses and the exact pass alike;
    # a single chart (switch=0) still raises, with advice.
    # One ω function and traced P0: the three starts share one compilation.
    def e_x(t):
        return jnp.array([1.0, 0.0, 0.0])

    about_x = jax.vmap(lambda t: so3.exp(jnp.array([t, 0.0, 0.0])))(TS)
    for delta in (1e-4, 1e-9, 0.0):
        P0 = so3.exp(jnp.array([-0.5, 0.0, 0.0])) @ so3.exp(jnp.array([0.0, delta, 0.0]))
        P = darboux(e_x, TS, P0=P0, method="euler")
        np.testing.assert_allclose(P, about_x @ P0, atol=1e-8)
    with pytest.raises(Exception, match="gimbal lock.*switch > 0.*quaternion/rotation-vector"):
        darboux(e_x, TS, method=EulerAngles(switch=0.0))
