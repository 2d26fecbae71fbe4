"""Robust losses: gyro data with outliers."""

import numpy as np

from rigidjax import identify_inertia
from tests.fit.data import I_TRUE, W0S
from tests.helpers import rigid_body_dop853

TS = np.linspace(0.0, 8.0, 81)  # the shape of tests/fit/test_identify.py: one compile for l2
I_REF = I_TRUE / np.trace(I_TRUE)


def test_huber_loss_resists_outliers():
    w, _ = rigid_body_dop853(I_TRUE, W0S[0], [1.0, 0.0, 0.0, 0.0], TS)
    rng = np.random.default_rng(4)
    sigma = 1e-3
    data = w + sigma * rng.normal(size=w.shape)
    bad = rng.choice(w.size, size=w.size // 20, replace=False)  # 5% outliers of 0.1 rad/s
    data.reshape(-1)[bad] += 0.1 * rng.choice([-1.0, 1.0], size=bad.size)
    l2 = identify_inertia(TS, omega_obs=data, sigma_omega=sigma)
    huber = identify_inertia(TS, omega_obs=data, sigma_omega=sigma, loss="huber")
    assert bool(huber.converged) and huber.loss == "huber"
    assert huber.covariance_method == "sandwich"
    err_l2 = np.abs(np.asarray(l2.inertia) - I_REF).max()
    err_huber = np.abs(np.asarray(huber.inertia) - I_REF).max()
    assert err_huber < err_l2 / 5, (err_huber, err_l2)
    assert err_huber < 1e-3
    # the sandwich std is honest: the error is within a few std
    assert np.all(np.abs(np.asarray(huber.inertia) - I_REF) <= 4.5 * np.asarray(huber.inertia_std))
