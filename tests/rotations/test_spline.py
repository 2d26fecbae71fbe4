"""RotationSpline and Slerp against SciPy's: attitudes, angular rates and accelerations to 1e-10
(random keys, uneven times, nearly 180° and tiny turns between keys, times outside the keys),
derivatives with respect to key attitudes, key times and t against central finite differences,
repeated key times and out-of-range times as clear errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.spatial.transform import RotationSpline as SciPySpline
from scipy.spatial.transform import Slerp as SciPySlerp

import rigidjax
from rigidjax import RotationSpline, Slerp, quat
from tests.rotations.test_bad_input import raises_in_jit

K = 7  # keys
T = 40  # evaluation times


def evaluate(ts, q, t):
    s = RotationSpline(ts, q)
    return s(t), s(t, 1), s(t, 2)


EVAL = jax.jit(evaluate)
SLERP = jax.jit(lambda ts, q, t: Slerp(ts, q)(t))


def keys(seed, k=K):
    rng = np.random.default_rng(seed)
    ts = np.cumsum(rng.uniform(0.1, 2.0, k)) - 1.0
    r = Rotation.random(k, rng=rng)
    return ts, r


def close_up_to_sign(q, ref, atol):
    q = np.asarray(q)
    err = np.minimum(np.abs(q - ref).max(-1), np.abs(q + ref).max(-1))
    assert err.max() <= atol, err.max()


def check_against_scipy(ts, r, t, atol=1e-10):
    q, rate, acc = EVAL(ts, r.as_quat(scalar_first=True), t)
    ref = SciPySpline(ts, r)
    close_up_to_sign(q, ref(t).as_quat(scalar_first=True), atol)
    np.testing.assert_allclose(rate, ref(t, 1), atol=atol, rtol=1e-10)
    np.testing.assert_allclose(acc, ref(t, 2), atol=atol, rtol=1e-10)


def test_spline_matches_scipy():
    for seed in range(3):
        ts, r = keys(seed)
        t = np.linspace(ts[0] - 0.3, ts[-1] + 0.3, T)  # beyond the ends: extrapolated cubics
        t[:K] = ts  # at the keys
        check_against_scipy(ts, r, t)
    # between consecutive keys: nearly 180°, a tiny turn, none (identical keys), 90°
    ts, _ = keys(5)
    steps = [[0, 0, 3.1], [1e-9, 0, 0], [0, 0, 0], [0, 1.5707, 0], [-3.0, 0.5, 0.1], [0.2, 0, 0]]
    rots = [Rotation.from_rotvec([0.3, -0.2, 0.1])]
    for step in steps:
        rots.append(rots[-1] * Rotation.from_rotvec(step))
    check_against_scipy(ts, Rotation.concatenate(rots), np.linspace(ts[0], ts[-1], T))


def test_spline_interpolates_and_is_c2():
    ts, r = keys(1)
    q = r.as_quat(scalar_first=True)
    t = np.concatenate([ts, ts[1:-1] - 1e-9, ts[1:-1] + 1e-9, np.full(T - 3 * K + 4, ts[0])])
    lo, hi = slice(K, 2 * K - 2), slice(2 * K - 2, 3 * K - 4)
    qs, rate, acc = EVAL(ts, q, t)
    np.testing.assert_allclose(qs[:K], q, atol=1e-14)  # each key with its sign
    np.testing.assert_allclose(rate[lo], rate[hi], atol=1e-7)  # rate continuous at inner keys
    # the acceleration jumps as much as SciPy's (10 sweeps stop short for these large turns) ...
    ref = SciPySpline(ts, r)
    np.testing.assert_allclose(acc[lo] - acc[hi], ref(t[lo], 2) - ref(t[hi], 2), atol=1e-9)
    assert np.abs(acc[lo] - acc[hi]).max() > 1e-4


def test_every_key_keeps_its_sign():
    """Each key's sign at its time, the last too (its segment ends at ±q[-1]: from the last
    key's time on the spline takes q[-1]'s sign, continuously), whatever the keys' signs."""
    ts, r = keys(2)
    q = r.as_quat(scalar_first=True) * np.array([1, -1, -1, 1, -1, 1, -1])[:, None]
    t = np.concatenate([ts, ts[-1] + np.array([1e-9, 0.1]), np.full(T - K - 2, ts[0])])
    np.testing.assert_allclose(SLERP(ts, q, np.minimum(t, ts[-1]))[:K], q, atol=1e-14)
    out = EVAL(ts, q, t)[0]  # (the shapes of the other tests: compiled once)
    np.testing.assert_allclose(out[:K], q, atol=1e-14)
    assert np.abs(out[K] - q[-1]).max() < 1e-8 and np.sum(out[K + 1] * q[-1]) > 0.9


@pytest.mark.slow
def test_converged_spline_is_c2():
    """Iterated to the fixed point the angular acceleration is continuous at the inner keys."""
    ts, r = keys(1)
    t = np.concatenate([ts[1:-1] - 1e-9, ts[1:-1] + 1e-9])
    full = RotationSpline(ts, r.as_quat(scalar_first=True), max_iter=50, tol=0.0)
    acc = full(t, 2)
    np.testing.assert_allclose(acc[: K - 2], acc[K - 2 :], atol=1e-6)


def test_slerp_matches_scipy():
    ts, r = keys(2)
    t = np.linspace(ts[0], ts[-1], T)
    t[:K] = ts
    q = SLERP(ts, r.as_quat(scalar_first=True), t)
    close_up_to_sign(q, SciPySlerp(ts, r)(t).as_quat(scalar_first=True), 1e-14)


def fd(f, x, h=1e-6):
    x = np.asarray(x, float)
    cols = []
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = h
        cols.append(
            (np.asarray(f(x + e.reshape(x.shape))) - np.asarray(f(x - e.reshape(x.shape))))
            / (2 * h)
        )
    return np.stack(cols, -1)


@pytest.mark.slow
def test_gradients_match_finite_differences():
    """d(attitude, rate, acceleration)/d(key attitudes (chart), key times, t)."""
    ts, r = keys(3)
    q = r.as_quat(scalar_first=True)
    t = np.linspace(ts[0] + 0.05, ts[-1] - 0.05, 5)

    def f(delta, ts, t):
        out = EVAL(ts, quat.retract(q, delta), t)
        return jnp.concatenate([o.ravel() for o in out])

    jac = jax.jit(jax.jacfwd(f, argnums=(0, 1, 2)))
    d0 = np.zeros((K, 3))
    J_q, J_ts, J_t = jac(d0, ts, t)
    np.testing.assert_allclose(J_q.reshape(-1, 3 * K), fd(lambda d: f(d, ts, t), d0), atol=1e-6)
    np.testing.assert_allclose(J_ts, fd(lambda s: f(d0, s, t), ts), atol=1e-6)
    np.testing.assert_allclose(J_t, fd(lambda s: f(d0, ts, s), t), atol=1e-6)
    assert np.all(np.isfinite(J_q))


def test_errors():
    ts, r = keys(4)
    q = r.as_quat(scalar_first=True)
    rep = ts.copy()
    rep[3] = rep[2]
    for cls in (RotationSpline, Slerp):
        with pytest.raises(ValueError, match=r"strictly increasing order: ts\[3\] = .* follows"):
            cls(rep, q)
        with pytest.raises(ValueError, match="Expected number of rotations to be equal"):
            cls(ts[:-1], q)
        with pytest.raises(ValueError, match="at least 2 rotations"):
            cls(ts[:1], q[:1])
        with pytest.raises(ValueError, match="more than 1 leading dimension"):
            cls(ts, q[None])
        with pytest.raises(ValueError, match="q must be a finite quaternion"):
            cls(ts, np.where(q == q[1, 1], np.nan, q))
    with raises_in_jit("Values in `ts` must be finite and in a strictly increasing order"):
        EVAL(rep, q, np.zeros(T))
    with pytest.raises(ValueError, match="`order` must be 0, 1 or 2"):  # at trace time
        jax.jit(lambda ts, q: RotationSpline(ts, q)(0.0, order=3))(ts, q)
    with pytest.raises(ValueError, match=r"Interpolation times must be within the range"):
        Slerp(ts, q)(np.array([ts[0], ts[-1] + 1]))
    with raises_in_jit("Interpolation times must be within the range"):
        SLERP(ts, q, np.full(T, ts[0] - 1))


def test_exported():
    assert rigidjax.RotationSpline is RotationSpline and rigidjax.rotations.Slerp is Slerp


@pytest.mark.slow
@pytest.mark.parametrize("k", [2, 3, 4])
def test_few_keys_and_vmap(k):
    ts, r = keys(10 + k, k)
    t = np.linspace(ts[0] - 0.2, ts[-1] + 0.2, 33)
    q = r.as_quat(scalar_first=True)
    out = jax.jit(evaluate)(ts, q, t)
    ref = SciPySpline(ts, r)
    close_up_to_sign(out[0], ref(t).as_quat(scalar_first=True), 1e-10)
    np.testing.assert_allclose(out[1], ref(t, 1), atol=1e-10)
    np.testing.assert_allclose(out[2], ref(t, 2), atol=1e-10)
    # a scalar time, eager
    s = Slerp(ts, q)
    close_up_to_sign(s(t[5]), SciPySlerp(ts, r)(t[5]).as_quat(scalar_first=True), 1e-14)
    # a batch of splines with jax.vmap, float32
    qs = np.stack([q, -q, q[::-1]])
    batch = jax.vmap(evaluate, in_axes=(None, 0, None))(ts, qs, t)
    np.testing.assert_allclose(batch[1][1], out[1], atol=1e-12)
    s32 = RotationSpline(np.float32(ts), np.float32(q))
    assert s32(np.float32(t), 2).dtype == jnp.float32
    np.testing.assert_allclose(s32(np.float32(t), 1), out[1], atol=1e-3, rtol=1e-3)
