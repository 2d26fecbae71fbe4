"""Several experiments at once and the gyro sensor model, on SciPy-generated data."""

import numpy as np
import pytest

from rigidjax import identify_inertia
from tests.fit.data import BIAS, I_REF, MOMENTS_REF, TS, attitude_noise, experiments

W, Q = experiments()
SIGMA = 1e-3


def _noisy(seed, bias=BIAS):
    rng = np.random.default_rng(seed)
    return W + bias + SIGMA * rng.normal(size=W.shape)


def test_several_experiments_with_gyro_bias():
    """Three manoeuvres, one biased gyro: one inertia, three initial states, one bias."""
    est = identify_inertia(TS, omega_obs=_noisy(0), gyro_bias=True, sigma_omega=SIGMA)
    assert bool(est.converged) and bool(est.identifiable)
    assert est.omega0.shape == (3, 3) and est.q0.shape == (3, 4)
    err = np.asarray(est.inertia) - I_REF
    assert np.all(np.abs(err) <= 4.5 * np.asarray(est.inertia_std) + 1e-12), err
    assert np.abs(err).max() < 2e-4
    np.testing.assert_allclose(est.gyro_bias, BIAS, atol=4.5 * float(est.gyro_bias_std.max()))
    assert float(est.gyro_bias_std.max()) < 2e-4
    np.testing.assert_allclose(est.omega0, W[:, 0], atol=1e-3)
    z = (np.asarray(est.principal_moments) - MOMENTS_REF) / np.asarray(est.principal_moments_std)
    assert np.all(np.abs(z) < 4.5), z
    # the weighted residuals are unit white noise at the solution
    assert 0.85 < float(np.std(est.residuals)) < 1.15


def test_bad_input():
    with pytest.raises(ValueError, match=r"quat_obs must have shape \(3, 61, 4\)"):
        identify_inertia(TS, omega_obs=W, quat_obs=Q[:2])
    with pytest.raises(ValueError, match=r"ts of shape \(3, 61\) \(E, T\) needs data of E"):
        identify_inertia(np.tile(TS, (3, 1)), omega_obs=W[0])
    with pytest.raises(ValueError, match=r"ts\[1\] must be strictly increasing"):
        ts = np.tile(TS, (3, 1))
        ts[1, 5] = ts[1, 4]
        identify_inertia(ts, omega_obs=W)
    with pytest.raises(ValueError, match="sequence of 3"):
        identify_inertia(TS, omega_obs=W, torque=[lambda t, w, q: w])
    with pytest.raises(ValueError, match="gyro_bias and gyro_scale need gyro data"):
        identify_inertia(TS, quat_obs=Q, gyro_bias=True)
    with pytest.raises(ValueError, match="covariance must be one of"):
        identify_inertia(TS, omega_obs=W, covariance="bootstrap")
    with pytest.raises(ValueError, match="loss must be one of"):
        identify_inertia(TS, omega_obs=W, loss="l1")
    with pytest.raises(ValueError, match=r"omega0_guess must have shape \(3,\) or \(3, 3\)"):
        identify_inertia(TS, omega_obs=W, omega0_guess=np.zeros((2, 3)))


@pytest.mark.slow  # two compilations (one and three experiments)
def test_joint_fit_beats_every_single_experiment():
    """One experiment alone fixes the inertia poorly along some directions; the joint fit is at
    least as accurate as the best single one (and its std the smallest)."""
    data = _noisy(1, bias=0.0)
    joint = identify_inertia(TS, omega_obs=data, sigma_omega=SIGMA)
    singles = [identify_inertia(TS, omega_obs=data[e], sigma_omega=SIGMA) for e in range(3)]
    err = [np.abs(np.asarray(s.inertia) - I_REF).max() for s in singles]
    assert np.abs(np.asarray(joint.inertia) - I_REF).max() <= min(err)
    assert float(joint.inertia_std.max()) <= min(float(s.inertia_std.max()) for s in singles)
    np.testing.assert_allclose(singles[0].omega0, joint.omega0[0], atol=2e-3)


@pytest.mark.slow  # compiles the attitude-only fit of three experiments
def test_attitude_only_several_experiments_own_times():
    """Star-tracker data only, each experiment with its own times (E, T)."""
    ts = np.stack([TS, 0.9 * TS, 1.1 * TS])
    _, q = experiments(ts)
    rng = np.random.default_rng(2)
    est = identify_inertia(ts, quat_obs=attitude_noise(q, 1e-3, rng), sigma_angle=1e-3)
    assert bool(est.converged)
    err = np.asarray(est.inertia) - I_REF
    assert np.all(np.abs(err) <= 4.5 * np.asarray(est.inertia_std) + 1e-12), err
    from tests.fit.data import Q0S

    assert np.all(np.abs(np.abs(np.sum(np.asarray(est.q0) * Q0S, axis=-1)) - 1) < 1e-5)


@pytest.mark.slow  # compiles the fit with gyro and attitude data and both sensor errors
def test_gyro_scale_factor_and_bias_with_attitude_data():
    scale = np.array([0.01, -0.02, 0.005])
    rng = np.random.default_rng(3)
    w = (1 + scale) * W + BIAS + SIGMA * rng.normal(size=W.shape)
    q = attitude_noise(Q, 1e-3, rng)
    est = identify_inertia(
        TS,
        omega_obs=w,
        quat_obs=q,
        gyro_bias=True,
        gyro_scale=True,
        sigma_omega=SIGMA,
        sigma_angle=1e-3,
    )
    assert bool(est.converged)
    for value, std, truth in (
        (est.gyro_scale, est.gyro_scale_std, scale),
        (est.gyro_bias, est.gyro_bias_std, BIAS),
        (est.inertia, est.inertia_std, I_REF),
    ):
        value, std = np.asarray(value), np.asarray(std)
        assert np.all(np.abs(value - truth) <= 4.5 * std + 1e-12), (value, truth, std)
