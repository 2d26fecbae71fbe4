"""The estimator in the loop (`rigidjax.estimation.estimated` with `simulate(gyrostat, ...)`):
its generator against an integer implementation of MRG32k3a, the filter's errors consistent
with its covariance in closed loop, draws reproducible body by body, and clear errors."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.estimation import estimated, knowledge_error, loop_log
from rigidjax.estimation.loop import _seed, _uniform, normals
from rigidjax.rotations import quat

M1, M2 = 4294967087, 4294944443


def mrg32k3a_integers(s1, s2, n):
    """L'Ecuyer's MRG32k3a (Oper. Res. 47(1), 1999) in exact integer arithmetic, the output
    scaled by `norm = 1/(m1 + 1)` as in the reference implementation."""
    s1, s2, out = list(s1), list(s2), []
    for _ in range(n):
        p1 = (1403580 * s1[1] - 810728 * s1[0]) % M1
        p2 = (527612 * s2[2] - 1370589 * s2[0]) % M2
        s1, s2 = [s1[1], s1[2], p1], [s2[1], s2[2], p2]
        out.append(float(p1 - p2 if p1 > p2 else p1 - p2 + M1) * (1.0 / (M1 + 1)))  # × norm
    return out


def test_generator_is_mrg32k3a():
    """The float64 generator equals the integer one draw for draw (from the published seed
    12345 its first draw is 0.1270111220), for seeds drawn from keys too."""
    states = [jnp.full(6, 12345.0), _seed(jax.random.key(0), jnp.float64)]
    step = jax.jit(_uniform)
    for s in states:
        want = mrg32k3a_integers([int(x) for x in s[:3]], [int(x) for x in s[3:]], 200)
        got = []
        for _ in range(200):
            u, s = step(s)
            got.append(float(u))
        assert got == want
    assert mrg32k3a_integers([12345] * 3, [12345] * 3, 1)[0] == pytest.approx(0.127011122046577)
    z, _ = jax.jit(jax.vmap(lambda s: normals(s, 20)))(
        jax.vmap(lambda k: _seed(k, jnp.float64))(jax.random.split(jax.random.key(1), 5000))
    )
    z = np.asarray(z).ravel()
    assert abs(z.mean()) < 4 / np.sqrt(z.size) and abs(z.var() - 1) < 4 * np.sqrt(2 / z.size)
    assert abs(np.mean(z**4) - 3) < 0.05


A = np.array([[1, 1, 1], [-1, 1, 1], [-1, -1, 1], [1, -1, 1]]).T / np.sqrt(3)
TARGET = quat.from_rotvec(jnp.array([0.0, 0.0, np.pi / 2]))


def _setup():
    sc = rj.Gyrostat(
        jnp.array([10.0, 12.0, 8.0]), wheel_axes=jnp.asarray(A), wheel_inertia=jnp.full(4, 0.05),
        wheel_torque_max=0.1,
    )  # fmt: skip
    law = rj.control.quaternion_pd(0.6, 3.0, TARGET, wheel_axes=A)
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-8] * 3))
    ctrl = estimated(law, arw=1e-5, rrw=1e-7, sigma=jnp.array([2e-5, 2e-5, 1e-4]), P0=P0)
    return sc, law, ctrl


def _run(keys, **options):
    sc, _, ctrl = _setup()
    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.25)
    return rj.simulate(
        sc, jnp.zeros((keys.shape[0], 3)), None, jnp.linspace(0.0, 30.0, 61),
        controller=ctrl.with_key(keys), control_period=0.5, **(fixed | options),
    )  # fmt: skip


@pytest.mark.slow  # ~20 s: the loop's CPU kernel is built and compiled
def test_closed_loop_errors_consistent_and_reproducible():
    """Over 16 bodies and the last 40 samples, the true knowledge errors normalised by the
    filter's σ have mean square ≈ 1 (within 0.7-1.4); the slew follows the one of the law on the
    true state within 1.5e-2 rad (1 % of the slew); the draws
    of each body depend on its key only (a permuted batch of keys permutes the logs)."""
    keys = jax.random.split(jax.random.key(3), 16)
    tr = _run(keys)
    log = loop_log(tr)
    z = np.asarray(log.attitude_error / log.sigma_attitude)[:, -40:]
    assert 0.7 < np.mean(z**2) < 1.4
    zb = np.asarray(log.bias_error / log.sigma_bias)[:, -40:]
    assert 0.5 < np.mean(zb**2) < 2.0
    assert np.all(np.asarray(knowledge_error(tr))[:, -1] < 5 * 1e-4)
    sc, law, _ = _setup()
    truth = rj.simulate(
        sc, jnp.zeros(3), None, tr.ts, controller=law, control_period=0.5, solver=rj.RK4(),
        stepsize_controller=diffrax.ConstantStepSize(), dt0=0.25,
    )  # fmt: skip
    err = rj.observables.pointing_error(tr, TARGET)
    ideal = rj.observables.pointing_error(truth, TARGET)  # the law on the true state
    assert np.max(np.abs(np.asarray(err - ideal))) < 1.5e-2  # 1 % of the 90° slew
    again = _run(keys[::-1])
    np.testing.assert_array_equal(again.controller_log, tr.controller_log[::-1])
    np.testing.assert_array_equal(again.quat, tr.quat[::-1])
    # the keys given to `simulate` itself: the same draws
    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.25)
    _, _, ctrl = _setup()
    keyed = rj.simulate(
        sc, jnp.zeros((16, 3)), None, tr.ts, controller=ctrl, controller_key=keys,
        control_period=0.5, **fixed,
    )  # fmt: skip
    np.testing.assert_array_equal(keyed.quat, tr.quat)


@pytest.mark.slow  # ~16 s: the loop's kernel, for a batch and for one body
def test_a_body_alone_draws_as_in_its_batch():
    """A single body's one key is its own (it was split, as one key for a batch): run alone
    with `keys[1]`, body 1 of a batch keyed `keys` has the same sensor draws and motion."""
    sc, _, ctrl = _setup()
    ts = jnp.linspace(0.0, 2.0, 5)
    fixed = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.25)
    keys = jax.random.split(jax.random.key(9), 2)
    batch = rj.simulate(
        sc, jnp.zeros((2, 3)), None, ts, controller=ctrl.with_key(keys), control_period=0.5,
        **fixed,
    )  # fmt: skip
    alone = rj.simulate(
        sc, jnp.zeros(3), None, ts, controller=ctrl.with_key(keys[1]), control_period=0.5, **fixed
    )
    np.testing.assert_array_equal(alone.controller_log, batch.controller_log[1])
    np.testing.assert_array_equal(alone.quat, batch.quat[1])


@pytest.mark.slow  # ~40 s: the Diffrax path with jumps compiles slowly
def test_kernel_and_diffrax_paths_agree():
    """The same loop on the Diffrax path (forced by `adjoint=DirectAdjoint()`) gives the same
    draws and trajectory."""
    keys = jax.random.split(jax.random.key(4), 2)
    a = _run(keys)
    b = _run(keys, adjoint=diffrax.DirectAdjoint())
    np.testing.assert_allclose(b.quat, a.quat, atol=1e-10)
    np.testing.assert_allclose(b.controller_log, a.controller_log, rtol=1e-8, atol=1e-12)


def test_errors():
    sc, law, ctrl = _setup()
    ts = jnp.linspace(0.0, 1.0, 3)
    with pytest.raises(ValueError, match="controller_key"):
        rj.simulate(sc, jnp.zeros(3), None, ts, controller=ctrl, control_period=0.5)
    with pytest.raises(ValueError, match="sigma must be positive"):
        estimated(law, arw=1e-5, rrw=1e-7, sigma=0.0)
    with pytest.raises(ValueError, match="one key or one key per run"):
        rj.simulate(
            sc, jnp.zeros((3, 3)), None, ts, control_period=0.5,
            controller=ctrl.with_key(jax.random.split(jax.random.key(0), 2)),
        )  # fmt: skip
    with pytest.raises(TypeError, match="step"):
        ctrl(0.0, jnp.zeros(3), jnp.array([1.0, 0, 0, 0]))
