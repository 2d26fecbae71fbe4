"""`rigidjax.estimation.mekf` against independent references, in float64: the fixed point of
the discrete Riccati recursion of Farrenkopf's single-axis model (SciPy's
`solve_discrete_are`), NEES within its χ² bounds over a Monte Carlo, the innovations'
likelihood peaking at the true noise, a static case against Davenport's batch solution
(`quat.align_vectors`), a NumPy implementation (NaN rows skipped), and gradients against
central differences."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.stats

from rigidjax import sensors
from rigidjax.estimation import mekf
from rigidjax.rotations import quat

from ._reference import mekf_numpy

ARW, RRW, SIGMA, DT = 1e-4, 1e-5, 5e-5, 0.1


def farrenkopf_riccati(arw, rrw, sigma, dt):
    """The steady-state covariance of the single-axis filter after an update: the prior P⁻ solves
    P⁻ = Φ (P⁻ − P⁻Hᵀ(HP⁻Hᵀ + R)⁻¹HP⁻) Φᵀ + Q, Φ = [[1, −Δ], [0, 1]], H = [1, 0]."""
    Phi = np.array([[1.0, -dt], [0.0, 1.0]])
    Q = np.array(
        [
            [arw**2 * dt + rrw**2 * dt**3 / 3, -(rrw**2) * dt**2 / 2],
            [-(rrw**2) * dt**2 / 2, rrw**2 * dt],
        ]
    )
    H, R = np.array([[1.0, 0.0]]), np.array([[sigma**2]])
    prior = scipy.linalg.solve_discrete_are(Phi.T, H.T, Q, R)
    return prior - prior @ H.T @ np.linalg.inv(H @ prior @ H.T + R) @ H @ prior


@jax.jit
def _filter(ts, gyro, qm, q0, arw, rrw, sigma, P0):
    return mekf(ts, gyro, qm, arw=arw, rrw=rrw, sigma=sigma, q0=q0, P0=P0)


@functools.partial(jax.jit, static_argnums=(1, 2))
def rotating_truth(key, runs, T, w, P0, arw=ARW, rrw=RRW, sigma=SIGMA, dt=DT):
    """Runs turning at the constant rate `w` (the trapezoid is then the exact mean rate), their
    gyro and star tracker data, and initial errors drawn from `P0`."""
    ts = jnp.arange(T) * dt
    k_err, k_gyro, k_st, k_q = jax.random.split(key, 4)
    err = jax.random.multivariate_normal(k_err, jnp.zeros(6), P0, (runs,))
    q_start = quat.random(k_q, (runs,))
    q = quat.mul(q_start[:, None], quat.from_rotvec(ts[:, None] * w))  # (runs, T, 4)
    rate, bias = sensors.gyro(
        k_gyro, ts, jnp.broadcast_to(w, (runs, T, 3)), arw=arw, rrw=rrw, bias0=err[:, 3:]
    )
    qm = sensors.star_tracker(k_st, q, sigma)
    q0 = quat.mul(q_start, quat.from_rotvec(-err[:, :3]))  # q = q̂ ∘ δq(δθ)
    return ts, q, bias, rate, qm, q0


def test_steady_state_covariance_equals_farrenkopf_riccati():
    """Isotropic noise, at rest with exact data (ω̂ = 0): each axis is Farrenkopf's single-axis
    filter, and the covariance converges to the Riccati fixed point (to 1e-10 relative). With
    noisy data at rest the rate estimate ≠ 0 turns Φ slightly: 1e-6 relative."""
    T = 3000
    ts = jnp.arange(T) * DT
    ident = jnp.broadcast_to(jnp.array([1.0, 0, 0, 0]), (T, 4))
    P0 = jnp.diag(jnp.array([1e-4] * 3 + [1e-8] * 3))
    exact = _filter(ts, jnp.zeros((T - 1, 3)), ident, ident[0], ARW, RRW, SIGMA, P0)
    want = farrenkopf_riccati(ARW, RRW, SIGMA, DT)
    block = np.kron(want, np.eye(3))  # (δθ, δb) order: [[Ptt I, Ptb I], [Ptb I, Pbb I]]
    P = np.asarray(exact.cov[-1])
    np.testing.assert_allclose(P, block, rtol=1e-10, atol=1e-10 * np.abs(block).max())
    _, _, _, rate, qm, _ = rotating_truth(jax.random.key(0), 1, T, jnp.zeros(3), P0)
    noisy = _filter(ts, rate[0], qm[0], qm[0, 0], ARW, RRW, SIGMA, P0)
    np.testing.assert_allclose(noisy.cov[-1], block, rtol=1e-4, atol=1e-4 * np.abs(block).max())


@pytest.mark.slow  # ~19 s: 200 runs of 401 steps, their truth and the NumPy filter
def test_nees_within_chi2_bounds_and_agrees_with_numpy():
    """200 runs turning at 0.05 rad/s, initial errors drawn from P0: the mean NEES over runs at
    five times lies in the two-sided 99.9 % interval of χ²(6N)/N, the mean NIS in that of
    χ²(3N)/N; the filter equals the NumPy implementation to 1e-12."""
    N, T = 200, 401
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-10] * 3))
    w = jnp.array([0.03, -0.04, 0.0])
    ts, q, bias, rate, qm, q0 = rotating_truth(jax.random.key(1), N, T, w, P0)
    res = _filter(ts, rate, qm, q0, ARW, RRW, SIGMA, P0)
    x = jnp.concatenate([quat.local(res.quat, q), bias - res.bias], axis=-1)  # (N, T, 6)
    nees = np.asarray(jnp.einsum("nti,nti->nt", x, jnp.linalg.solve(res.cov, x[..., None])[..., 0]))
    lo, hi = scipy.stats.chi2.ppf([0.0005, 0.9995], 6 * N) / N
    for k in (0, 25, 100, 200, 400):
        assert lo < nees[:, k].mean() < hi, (k, nees[:, k].mean(), lo, hi)
    lo3, hi3 = scipy.stats.chi2.ppf([0.0005, 0.9995], 3 * N) / N
    for k in (1, 200, 400):
        assert lo3 < float(jnp.mean(res.nis[:, k])) < hi3
    ref = mekf_numpy(ts, rate[:20], qm[:20], arw=ARW, rrw=RRW, sigma=SIGMA, q0=q0[:20], P0=P0)
    np.testing.assert_allclose(quat.local(ref[0], res.quat[:20]), 0, atol=1e-13)
    np.testing.assert_allclose(res.bias[:20], ref[1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(res.cov[:20], ref[2], rtol=1e-10, atol=1e-22)
    np.testing.assert_allclose(res.log_likelihood[:20], ref[3], rtol=1e-12)


@pytest.mark.slow  # ~12 s: a 2001-step filter on a grid of 10 noise levels
def test_likelihood_peaks_at_true_noise():
    """The innovations' log-likelihood over a grid of the star tracker's σ (and of the gyro's
    ARW) is largest at the true value."""
    T = 2001
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-10] * 3))
    arw = 3 * SIGMA / np.sqrt(DT)  # σ_v √Δ comparable to σ: both identifiable
    ts, _, _, rate, qm, q0 = rotating_truth(
        jax.random.key(2), 1, T, jnp.array([0.0, 0.02, 0.01]), P0, arw=arw
    )
    args = (ts, rate[0], qm[0], q0[0])
    factors = jnp.array([0.8, 0.9, 1.0, 1.1, 1.25])

    def ll(a, s):
        return _filter(*args, a, RRW, s, P0).log_likelihood

    by_sigma = jax.vmap(lambda f: ll(arw, f * SIGMA))(factors)
    by_arw = jax.vmap(lambda f: ll(f * arw, SIGMA))(factors)
    assert int(jnp.argmax(by_sigma)) == 2 and int(jnp.argmax(by_arw)) == 2


@pytest.mark.slow  # ~9 s
def test_static_case_matches_davenport():
    """At rest with no process noise the filter is the recursive form of the least-squares
    attitude from all the star tracker's measurements: Davenport's batch solution (Wahba's
    problem on the measured body axes, `quat.align_vectors`) agrees to 1e-9 rad, well inside
    the estimation error (σ/√N ≈ 7e-5 rad); the covariance is (P0⁻¹ + N/σ²)⁻¹."""
    N, sigma = 200, 1e-3
    q_true = quat.from_rotvec(jnp.array([0.4, -0.2, 1.1]))
    ts = jnp.arange(N) * 1.0
    qm = sensors.star_tracker(jax.random.key(3), jnp.broadcast_to(q_true, (N, 4)), sigma)
    P0 = jnp.diag(jnp.array([1.0] * 3 + [1e-30] * 3))
    res = mekf(ts, jnp.zeros((N - 1, 3)), qm, arw=0.0, rrw=0.0, sigma=sigma, q0=qm[0], P0=P0)
    axes = jnp.broadcast_to(jnp.eye(3), (N, 3, 3)).reshape(-1, 3)  # body e_j, each measurement
    space = quat.rotate(jnp.repeat(qm, 3, axis=0), axes)  # P(q_k) e_j
    q_batch, _ = quat.align_vectors(space, axes)
    diff = quat.local(q_batch, res.quat[-1])
    assert float(jnp.linalg.norm(diff)) < 1e-9
    assert float(jnp.linalg.norm(quat.local(q_true, res.quat[-1]))) < 5 * sigma / np.sqrt(N)
    want = 1 / (1 / 1.0 + N / sigma**2)
    np.testing.assert_allclose(jnp.diagonal(res.cov[-1])[:3], want, rtol=1e-6)


@pytest.mark.slow  # ~12 s: the filter and its NumPy twin compiled with NaN rows
def test_nan_rows_skipped():
    """A row with a NaN is no update: the state is the prediction (the NumPy filter skips it),
    the innovation and NIS are NaN, the log-likelihood sums the other rows."""
    N, T = 50, 201
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-10] * 3))
    ts, _, _, rate, qm, q0 = rotating_truth(jax.random.key(4), N, T, jnp.array([0.1, 0, 0.05]), P0)
    qm = qm.at[:, 10:20].set(jnp.nan).at[1, 30:].set(jnp.nan).at[2, 5, 1].set(jnp.nan)
    res = _filter(ts, rate, qm, q0, ARW, RRW, SIGMA, P0)
    ref = mekf_numpy(ts, rate[:4], qm[:4], arw=ARW, rrw=RRW, sigma=SIGMA, q0=q0[:4], P0=P0)
    np.testing.assert_allclose(quat.local(ref[0], res.quat[:4]), 0, atol=1e-13)
    np.testing.assert_allclose(res.cov[:4], ref[2], rtol=1e-10, atol=1e-12 * np.abs(ref[2]).max())
    np.testing.assert_allclose(res.log_likelihood[:4], ref[3], rtol=1e-12)
    assert jnp.all(jnp.isnan(res.nis[:, 10:20])) and jnp.isnan(res.nis[2, 5])
    assert jnp.all(jnp.isfinite(res.nis[0, 20:])) and jnp.all(jnp.isnan(res.nis[1, 30:]))
    # where no update, the covariance grows (the prediction)
    assert jnp.all(jnp.diff(res.cov[:, 10:20, 0, 0], axis=-1) > 0)


def richardson(f, x, h):
    """The derivative of `f` at `x` by central differences, Richardson-extrapolated (error
    O(h⁴))."""

    def central(h):
        return (f(x + h) - f(x - h)) / (2 * h)

    return (4 * central(h / 2) - central(h)) / 3


@jax.jit
def _loss_and_grad(ts, gyro, qm, q0, p, P0):
    def loss(p, g, m):
        return _filter(ts, g, m, q0, p[0], p[1], p[2], P0).log_likelihood

    return loss(p, gyro, qm), jax.grad(loss, argnums=(0, 1, 2))(p, gyro, qm)


@pytest.mark.slow  # ~20 s: the reverse mode's compilation
def test_gradients_against_central_differences():
    """d ℓ / d(arw, rrw, sigma) and with respect to one gyro reading and one measured
    quaternion component: reverse mode equals Richardson-extrapolated central differences
    (relative 1e-6); with NaN rows the gradient stays finite."""
    T = 40
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-10] * 3))
    ts, _, _, rate, qm, q0 = rotating_truth(jax.random.key(5), 1, T, jnp.array([0.05, 0.1, 0]), P0)
    rate, qm, q0 = rate[0], qm[0], q0[0]
    p = jnp.array([ARW, RRW, SIGMA])
    _, grads = _loss_and_grad(ts, rate, qm, q0, p, P0)

    def loss(p, g, m):
        return float(_filter(ts, g, m, q0, p[0], p[1], p[2], P0).log_likelihood)

    for i in range(3):
        e = jnp.zeros(3).at[i].set(1.0)
        fd = richardson(lambda x, e=e: loss(p + x * e, rate, qm), 0.0, 1e-3 * float(p[i]))
        assert float(grads[0][i]) == pytest.approx(fd, rel=1e-6), i
    d = jnp.zeros_like(rate).at[7, 1].set(1.0)
    fd = richardson(lambda x: loss(p, rate + x * d, qm), 0.0, 1e-6)
    assert float(grads[1][7, 1]) == pytest.approx(fd, rel=1e-6)
    d = jnp.zeros_like(qm).at[9, 2].set(1.0)
    fd = richardson(lambda x: loss(p, rate, qm + x * d), 0.0, 1e-7)
    assert float(grads[2][9, 2]) == pytest.approx(fd, rel=1e-6)
    holes = qm.at[10:20].set(jnp.nan)
    _, g_holes = _loss_and_grad(ts, rate, holes, q0, p, P0)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in g_holes)
    assert bool(jnp.all(g_holes[2][10:20] == 0))


@pytest.mark.slow
def test_vmap_and_batch_agree():
    """`jax.vmap` over runs equals the batched call; per-run noise levels broadcast."""
    T = 20
    P0 = jnp.diag(jnp.array([1e-6] * 3 + [1e-10] * 3))
    ts, _, _, rate, qm, q0 = rotating_truth(jax.random.key(6), 3, T, jnp.array([0.0, 0, 0.1]), P0)
    sig = jnp.array([4e-5, 5e-5, 6e-5])
    batched = mekf(ts, rate, qm, arw=ARW, rrw=RRW, sigma=sig[:, None], q0=q0, P0=P0)
    mapped = jax.vmap(lambda g, m, q, s: mekf(ts, g, m, arw=ARW, rrw=RRW, sigma=s, q0=q, P0=P0))(
        rate, qm, q0, sig
    )
    np.testing.assert_allclose(batched.log_likelihood, mapped.log_likelihood, rtol=1e-13)
    np.testing.assert_allclose(batched.cov, mapped.cov, rtol=1e-12, atol=1e-24)


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (dict(sigma=-1e-4), "sigma must be positive"),
        (dict(arw=-1.0), "arw must be non-negative"),
        (dict(rrw=jnp.ones(5)), r"rrw must be a scalar .* against \(\.\.\., 3\).*got shape \(5,\)"),
        (dict(P0=-jnp.eye(6)), "P0 must be positive definite"),
        (dict(P0=jnp.eye(6).at[0, 1].set(1e-3)), "P0 must be symmetric"),
        (dict(gyro=jnp.zeros((5, 3))), "gyro must have shape"),
        (dict(q_meas=jnp.ones((4, 4))), "q_meas must have shape"),
        (dict(q_meas=jnp.ones((5, 4)).at[2].set(0.0)), r"row of zeros.*row \[2\].*row of NaN"),
        (dict(q_meas=jnp.ones((5, 4)).at[3, 1].set(-jnp.inf)), r"infinite.*row \[3\].*row of NaN"),
    ],
)
def test_errors_name_the_argument(change, needle):
    kw = dict(
        ts=jnp.arange(5.0), gyro=jnp.zeros((4, 3)), q_meas=jnp.ones((5, 4)), arw=1e-4,
        rrw=1e-6, sigma=1e-4, q0=jnp.array([1.0, 0, 0, 0]),
    )  # fmt: skip
    kw.update(change)
    with pytest.raises(ValueError, match=needle):
        mekf(**kw)


@pytest.mark.slow  # ~9 s: the filter compiled in float32
def test_float32_in_float32_out_with_the_defaults():
    """float32 data with the defaults (`bias0`, `P0`) stay float32 under x64 (a default zero
    bias used to promote the gyro and the filter to float64), with noise levels given as NumPy
    float64 scalars (`np.deg2rad(x) / 60` is one: they promoted too), and the filter's attitude
    follows the float64 filter's on the same data."""
    f32 = jnp.float32
    arw, rrw, sigma = np.float64(ARW), np.float64(RRW), np.float64(SIGMA)
    ts = jnp.arange(11, dtype=f32) * f32(DT)
    w = jnp.array([0.01, -0.02, 0.03], f32)
    q = quat.from_rotvec(ts[:, None] * w)
    k_gyro, k_st = jax.random.split(jax.random.PRNGKey(5))
    rate, bias = sensors.gyro(k_gyro, ts, jnp.broadcast_to(w, (11, 3)), arw=arw, rrw=rrw)
    qm = sensors.star_tracker(k_st, q, sigma)
    assert (rate.dtype, bias.dtype, qm.dtype) == (f32, f32, f32)
    errors = dict(scale_factor=jnp.full(3, 1e-4, f32), misalignment=jnp.full((3, 3), 1e-4, f32))
    imperfect = sensors.gyro(k_gyro, ts, jnp.broadcast_to(w, (11, 3)), arw=arw, rrw=rrw, **errors)
    assert {x.dtype for x in imperfect} == {np.dtype(f32)}
    args = dict(arw=arw, rrw=rrw, sigma=sigma)
    single = mekf(ts, rate, qm, q0=qm[0], **args)
    assert {x.dtype for x in (single.quat, single.bias, single.cov, single.log_likelihood)} == {
        np.dtype(f32)
    }
    double = mekf(*(x.astype(jnp.float64) for x in (ts, rate, qm)), q0=qm[0], **args)
    err = quat.to_rotvec(quat.mul(quat.inv(double.quat), single.quat.astype(jnp.float64)))
    assert np.max(np.linalg.norm(err, axis=-1)) < 1e-5  # rad, float32's rounding of ~1e-7
