"""Stationary rotations and their linear stability (Zegrya–Parshin 004 (12.44)–(12.50); 002)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import RigidBody, simulate
from rigidjax.mechanics import stability as st

I123 = np.array([1.0, 2.0, 3.0])


def _tensor(moments, rotvec=(0.3, -0.7, 0.4)):
    R = Rotation.from_rotvec(rotvec).as_matrix()
    return R @ np.diag(moments) @ R.T


def _random_moments(rng, n):
    """Random valid principal moments (triangle inequality) in random order."""
    a = rng.uniform(0.5, 2.0, size=(n, 2))
    c = rng.uniform(np.abs(a[:, 0] - a[:, 1]) + 0.05, a.sum(1) - 0.05)
    return rng.permuted(np.column_stack([a, c]), axis=1)


def _sorted(lam):
    """Complex values in a rounding-proof order (±iν with ±1e-17 real parts)."""
    lam = np.asarray(lam)
    return lam[np.lexsort((np.round(lam.imag, 6), np.round(lam.real, 6)))]


def test_eigenvalues_jacfwd_vs_closed_form_polynomial(rng):
    moments = _random_moments(rng, 6)
    for m in moments:
        for inertia in (m, _tensor(m)):
            for k in range(3):
                w0 = rng.uniform(-3, 3)
                A = np.asarray(st.linearization(inertia, k, w0))
                poly = np.asarray(st.characteristic_polynomial(inertia, k, w0))
                # closed form (★) by hand, axis k of the ascending moments for a tensor
                mk = m if inertia.ndim == 1 else np.sort(m)
                Ik, Ii, Ij = mk[k], mk[(k + 1) % 3], mk[(k + 2) % 3]
                kappa = (Ik - Ii) * (Ik - Ij) / (Ii * Ij)
                np.testing.assert_allclose(poly, [1, 0, kappa * w0**2, 0], atol=1e-14)
                # the jacfwd matrix has exactly this characteristic polynomial
                np.testing.assert_allclose(
                    st.characteristic_coefficients(A), poly, atol=1e-12 * (1 + w0**2)
                )
                lam_np = _sorted(np.linalg.eigvals(A))
                lam_roots = _sorted(np.roots(poly))
                lam = _sorted(st.eigenvalues(inertia, k, w0))
                np.testing.assert_allclose(lam_np, lam_roots, atol=1e-7)
                np.testing.assert_allclose(lam, lam_roots, atol=1e-7)
                assert float(st.growth_rate(inertia, k, w0)) == pytest.approx(
                    max(lam_roots.real.max(), 0.0), abs=1e-7
                )


def test_middle_axis_rate_is_12_49():
    for inertia in (I123, I123[::-1], _tensor(I123)):
        p = np.sqrt((3 - 2) * (2 - 1) / (1 * 3))
        mid = 1 if inertia.ndim == 2 else int(np.argsort(inertia)[1])
        assert float(st.middle_axis_growth_rate(inertia, -2.0)) == pytest.approx(2 * p, rel=1e-14)
        assert float(st.growth_rate(inertia, mid, -2.0)) == pytest.approx(2 * p, rel=1e-12)
        assert float(st.oscillation_frequency(inertia, mid, -2.0)) == 0.0


def test_stationary_rotation_is_stationary():
    for inertia in (I123, _tensor(I123)):
        for k in range(3):
            w = st.stationary_rotation(inertia, k, 1.7)
            assert float(jnp.linalg.norm(w)) == pytest.approx(1.7)
            I = np.diag(inertia) if inertia.ndim == 1 else inertia
            np.testing.assert_allclose(np.cross(w, I @ w), 0, atol=1e-13)
    # tensors: ascending principal axes (axis 2 = largest moment)
    w = st.stationary_rotation(_tensor([3.0, 1.0, 2.0], (0, 0, 0)), 2)
    np.testing.assert_allclose(np.abs(w), [1, 0, 0], atol=1e-14)


# ---------------------------------------------------------------- against the nonlinear flow

W0 = 1.3
EPS = 1e-8
TS = jnp.linspace(0.0, 20.0, 401)


@pytest.fixture(scope="module")
def perturbed():
    """Free body I = (1, 2, 3) spun about each principal axis with a 1e-8 relative
    perturbation off the axis; one batched simulate call (one compilation)."""
    dirs = np.array([[0.0, 0.6, -0.8], [0.6, 0.0, 0.8], [0.8, -0.6, 0.0]])
    w0 = W0 * (np.eye(3) + EPS * dirs)
    traj = simulate(RigidBody(I123), w0, ts=TS, rtol=1e-12, atol=1e-12)
    return np.asarray(traj.omega)  # (3, T, 3)


def test_growth_rate_from_simulated_perturbation(perturbed):
    off = np.linalg.norm(perturbed[1][:, [0, 2]], axis=-1)  # |δΩ| off the middle axis
    t = np.asarray(TS)
    # linear regime: the decaying mode e^{-pt} has died out (t ≥ 8: e^{-2pt} < 1e-6) and the
    # amplitude is still ≤ ~1e-4 Ω0 (nonlinear corrections ~1e-8)
    sel = (t >= 8) & (off <= 1e-4 * W0)
    assert sel.sum() > 100
    slope = np.polyfit(t[sel], np.log(off[sel]), 1)[0]
    p = float(st.growth_rate(I123, 1, W0))
    assert p == pytest.approx(W0 * np.sqrt(1 / 3), rel=1e-12)
    assert slope == pytest.approx(p, rel=1e-3)
    # and it really leaves: the perturbation grew by orders of magnitude
    assert off.max() > 1e4 * EPS * W0


def test_stable_axes_stay_bounded(perturbed):
    for k in (0, 2):
        others = [i for i in range(3) if i != k]
        off = np.linalg.norm(perturbed[k][:, others], axis=-1)
        assert off.max() < 5 * EPS * W0
        assert abs(perturbed[k][:, k] - W0).max() < 1e-12
        assert st.classify(I123, k, W0) == "stable"
        # the perturbation oscillates at the predicted frequency: count sign changes
        nu = float(st.oscillation_frequency(I123, k, W0))
        x = perturbed[k][:, others[0]]
        crossings = np.count_nonzero(np.diff(np.sign(x)) != 0)
        assert crossings == pytest.approx(2 * nu * float(TS[-1]) / (2 * np.pi), abs=1.5)


# ---------------------------------------------------------------- classification


def test_classify_three_axes_any_order():
    assert [st.classify(I123, k) for k in range(3)] == ["stable", "unstable", "stable"]
    m = np.array([3.0, 1.0, 2.0])  # given order: the middle moment is on axis 2
    assert [st.classify(m, k) for k in range(3)] == ["stable", "stable", "unstable"]
    # a tensor: axes in ascending order of the moments
    assert list(st.classify(_tensor(m), np.arange(3))) == ["stable", "unstable", "stable"]
    codes = st.stability_code(I123, jnp.arange(3))
    np.testing.assert_array_equal(codes, [1, -1, 1])


def test_classify_degenerate_is_neutral():
    # symmetric top: the symmetry axis is stable, the equatorial axes are neutral
    assert list(st.classify([1.0, 1.0, 1.5], np.arange(3))) == ["neutral", "neutral", "stable"]
    assert list(st.classify([1.0, 1.0, 1.0], np.arange(3))) == ["neutral"] * 3
    assert st.classify(I123, 1, 0.0) == "neutral"  # at rest
    for k in range(3):  # only zero eigenvalues there
        lam = st.eigenvalues([1.0, 1.0, 1.0], k, 2.0)
        np.testing.assert_allclose(lam, 0, atol=1e-15)
    # a nearly symmetric body is neutral only within rtol
    assert st.classify([1.0, 1.0 + 1e-12, 2.0], 0) == "neutral"
    assert st.classify([1.0, 1.0 + 1e-6, 2.0], 0) == "stable"


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_vmap_jit_grad_over_inertias(rng):
    moments = jnp.asarray(_random_moments(rng, 16))
    w0 = jnp.linspace(-2.0, 2.0, 16)
    batched = jax.jit(jax.vmap(st.growth_rate, in_axes=(0, None, 0)), static_argnums=1)
    for k in range(3):
        got = batched(moments, k, w0)
        loop = [float(st.growth_rate(m, k, w)) for m, w in zip(moments, w0, strict=True)]
        np.testing.assert_allclose(got, loop, rtol=1e-12)
        np.testing.assert_allclose(st.growth_rate(moments, k, w0), loop, rtol=1e-12)
    # the middle moment's axis always carries the closed-form rate (12.49)
    mid = jnp.argsort(moments, axis=-1)[:, 1]
    np.testing.assert_allclose(
        jax.vmap(st.growth_rate)(moments, mid, w0),
        st.middle_axis_growth_rate(moments, w0),
        rtol=1e-12,
    )
    codes = jax.vmap(st.stability_code)(moments, mid, w0)
    np.testing.assert_array_equal(codes, -1)
    # vmap over tensors too
    T = jnp.asarray(np.stack([_tensor(m) for m in np.asarray(moments[:4])]))
    np.testing.assert_allclose(
        jax.vmap(lambda I: st.growth_rate(I, 1, 1.0))(T),
        st.middle_axis_growth_rate(moments[:4]),
        rtol=1e-10,
    )
    # gradient of p w.r.t. the moments vs finite differences
    I0 = np.array([1.0, 2.0, 2.5])
    g = jax.grad(st.growth_rate)(jnp.asarray(I0), 1, 1.0)
    h = 1e-6
    fd = [
        (st.growth_rate(I0 + h * e, 1, 1.0) - st.growth_rate(I0 - h * e, 1, 1.0)) / (2 * h)
        for e in np.eye(3)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-7)


def test_bad_inputs():
    with pytest.raises(ValueError, match="axis must be 0, 1 or 2"):
        st.classify(I123, 3)
    with pytest.raises(TypeError, match="axis must be an integer"):
        st.growth_rate(I123, 1.0)
    with pytest.raises(ValueError, match="triangle inequality"):
        st.growth_rate([1.0, 1.0, 3.0], 1)
    with pytest.raises(ValueError, match="shape"):
        st.growth_rate([1.0, 2.0], 1)
    with pytest.raises(TypeError, match="stability_code"):
        jax.jit(st.classify)(I123, 1)
    # under jit the inertia checks run at run time
    with pytest.raises(Exception, match="triangle inequality"):
        jax.jit(st.growth_rate, static_argnums=1)(jnp.array([1.0, 1.0, 3.0]), 1, 1.0)
