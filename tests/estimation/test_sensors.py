"""The sensor models against their own definitions: the gyro's Allan deviation at rest
(σ_A²(τ) = arw²/τ + rrw² τ/3, IEEE Std 952-1997 annex C), the joint statistics of the bias
increment and the mean bias over an interval (rrw² Δ [[1, 1/2], [1/2, 1/3]]), and the star
tracker's body-axis noise."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import sensors
from rigidjax.rotations import quat


def allan_variance(rate: np.ndarray, dt: float, n: int) -> float:
    """The non-overlapping Allan variance at τ = n dt of rates `(runs, T, 3)` (cluster means,
    half the mean square of successive differences, pooled over runs and axes)."""
    m = rate.shape[1] // n
    clusters = rate[:, : m * n].reshape(rate.shape[0], m, n, 3).mean(axis=2)
    return 0.5 * float(np.mean(np.diff(clusters, axis=1) ** 2))


def test_gyro_allan_deviation_at_rest():
    """ARW at τ = 1 s and the rate random walk's √τ slope at long τ, from 64 runs at rest."""
    arw, rrw, dt, T = 1e-4, 1e-5, 0.5, 10_001
    ts = jnp.arange(T) * dt
    rate, _ = sensors.gyro(jax.random.key(0), ts, jnp.zeros((64, T, 3)), arw=arw, rrw=rrw)
    rate = np.asarray(rate)
    for tau, rtol in ((1.0, 0.03), (5.0, 0.05), (250.0, 0.15), (500.0, 0.2)):
        want = arw**2 / tau + rrw**2 * tau / 3
        got = allan_variance(rate, dt, round(tau / dt))
        assert got == pytest.approx(want, rel=rtol), tau
    # τ = 1 s: the ARW (the RRW term is 0.3 % of it); τ = 500 s: the RRW (99.4 %)
    assert np.sqrt(allan_variance(rate, dt, 2)) == pytest.approx(arw, rel=0.02)


@pytest.mark.slow  # ~4 s (the quick suite's budget)
def test_gyro_interval_statistics():
    """Reading minus true rate minus bias[k], and the bias increment: covariance
    [[arw²/Δ + rrw² Δ/3, rrw² Δ/2], [rrw² Δ/2, rrw² Δ]] (the mean bias and the increment
    correlated by √3/2); the trapezoid of a linear rate is its exact mean."""
    arw, rrw, dt = 2e-4, 3e-4, 0.2
    T = 20_001
    ts = jnp.arange(T) * dt
    omega = jnp.stack([0.01 + 0.001 * ts, -0.02 * jnp.ones(T), 0.003 * ts], -1)
    rate, bias = sensors.gyro(jax.random.key(1), ts, omega, arw=arw, rrw=rrw)
    mean_rate = 0.5 * (omega[1:] + omega[:-1])
    x = np.asarray(rate - mean_rate - bias[:-1]).ravel()
    d = np.asarray(bias[1:] - bias[:-1]).ravel()
    C = np.cov(np.stack([x, d]))
    want = np.array(
        [[arw**2 / dt + rrw**2 * dt / 3, rrw**2 * dt / 2], [rrw**2 * dt / 2, rrw**2 * dt]]
    )
    np.testing.assert_allclose(np.diag(C), np.diag(want), rtol=0.03)
    corr = C[0, 1] / np.sqrt(C[0, 0] * C[1, 1])
    want_corr = want[0, 1] / np.sqrt(want[0, 0] * want[1, 1])
    assert corr == pytest.approx(want_corr, abs=0.02)
    quiet, b = sensors.gyro(jax.random.key(1), ts[:50], omega[:50], arw=0.0, rrw=0.0)
    np.testing.assert_allclose(quiet, mean_rate[:49], rtol=0, atol=1e-15)
    assert jnp.all(b == 0)


@pytest.mark.slow  # ~4-6 s: three shapes to compile
def test_gyro_scale_factor_misalignment_and_keys():
    """M = I + diag(s) + misalignment on the true mean rate; a key per run gives each run the
    draws of its own key."""
    ts = jnp.linspace(0.0, 1.0, 11)
    om = jnp.ones((11, 3)) * jnp.array([0.1, 0.2, 0.3])
    s = jnp.array([1e-3, -2e-3, 5e-4])
    M = jnp.array([[0.0, 1e-3, 0], [0, 0, -2e-3], [3e-3, 0, 0]])
    r, _ = sensors.gyro(jax.random.key(0), ts, om, arw=0, rrw=0, scale_factor=s, misalignment=M)
    np.testing.assert_allclose(r, jnp.broadcast_to((jnp.eye(3) + jnp.diag(s) + M) @ om[0], r.shape))
    keys = jax.random.split(jax.random.key(5), 3)
    batch = jnp.broadcast_to(om, (3, 11, 3))
    r3, b3 = sensors.gyro(keys, ts, batch, arw=1e-3, rrw=1e-4)
    r1, b1 = sensors.gyro(keys[1], ts, om, arw=1e-3, rrw=1e-4)
    np.testing.assert_array_equal(r3[1], r1)
    np.testing.assert_array_equal(b3[1], b1)


def test_star_tracker_statistics():
    """δθ = log(q⁻¹ ∘ q_meas) in body axes: zero mean, covariance diag(sigma²)."""
    sigma = jnp.array([1e-4, 2e-4, 8e-4])
    q = quat.from_rotvec(jnp.array([0.3, -1.2, 0.7]))
    n = 100_000
    qm = sensors.star_tracker(jax.random.key(2), jnp.broadcast_to(q, (n, 4)), sigma)
    d = np.asarray(quat.local(q, qm))
    se = np.asarray(sigma) / np.sqrt(n)
    assert np.all(np.abs(d.mean(0)) < 4.5 * se)
    C = np.cov(d.T)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), sigma, rtol=0.015)
    corr = C / np.sqrt(np.outer(np.diag(C), np.diag(C)))
    assert np.max(np.abs(corr - np.eye(3))) < 0.02
    np.testing.assert_allclose(np.linalg.norm(qm, axis=-1), 1.0, atol=1e-14)


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        (dict(arw=-1e-3, rrw=0.0), "arw must be non-negative"),
        (dict(arw=0.0, rrw=jnp.nan), "rrw must be non-negative"),
        (dict(arw=0.0, rrw=0.0, bias0=jnp.ones(2)), "bias0 must have shape"),
        # (a raw broadcasting TypeError that named no argument)
        (
            dict(arw=jnp.ones(2), rrw=0.0),
            r"arw must be a scalar or an array broadcasting to.*\(2,\)",
        ),
        (dict(arw=0.0, rrw=jnp.ones((5, 1, 1))), r"rrw must be .*\(4, 3\).*got shape \(5, 1, 1\)"),
    ],
)
def test_gyro_errors(kwargs, needle):
    ts, om = jnp.linspace(0, 1, 5), jnp.zeros((5, 3))
    with pytest.raises(ValueError, match=needle):
        sensors.gyro(jax.random.key(0), ts, om, **kwargs)


def test_sensor_argument_errors():
    with pytest.raises(ValueError, match="strictly increasing"):
        sensors.gyro(jax.random.key(0), jnp.array([0.0, 1.0, 1.0]), jnp.zeros((3, 3)), arw=0, rrw=0)
    with pytest.raises(ValueError, match="omega must have shape"):
        sensors.gyro(jax.random.key(0), jnp.linspace(0, 1, 4), jnp.zeros((3, 3)), arw=0, rrw=0)
    with pytest.raises(TypeError, match="PRNG key"):
        sensors.star_tracker(jnp.zeros(3), jnp.array([1.0, 0, 0, 0]), 1e-4)
    with pytest.raises(ValueError, match="one key per run"):
        sensors.star_tracker(jax.random.split(jax.random.key(0), 3), jnp.ones((2, 4)), 1e-4)
    with pytest.raises(ValueError, match="sigma must be non-negative"):
        sensors.star_tracker(jax.random.key(0), jnp.array([1.0, 0, 0, 0]), -1.0)
    with pytest.raises(ValueError, match=r"sigma must be a scalar or an array broadcasting"):
        sensors.star_tracker(jax.random.key(0), jnp.array([1.0, 0, 0, 0]), jnp.ones(2))
