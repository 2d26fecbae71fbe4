"""Inertia identification from data generated with SciPy (not with rigidjax)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rigidjax import identify_inertia
from rigidjax.fit.identify import inertia_from_params, params_from_inertia
from rigidjax.fit.parameters import feasibility, project
from rigidjax.mechanics.inertia import check_inertia
from tests.helpers import fd_jacobian, rigid_body_dop853
from tests.rotations.test_bad_input import raises_in_jit

TS = np.linspace(0.0, 8.0, 81)
R = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
I_TRUE = R @ np.diag([1.0, 2.0, 2.6]) @ R.T  # full, non-diagonal tensor
W0 = np.array([0.4, 1.1, -0.7])
Q0 = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_quat(scalar_first=True)
K = np.array([0.1, -0.2, 0.15])  # constant body-frame torque for the absolute-scale case


def scipy_data(torque=(0.0, 0.0, 0.0)):
    """Gyro and attitude data from SciPy DOP853 (independent of rigidjax)."""
    return rigid_body_dop853(I_TRUE, W0, Q0, TS, lambda t, w, q: np.asarray(torque))


OMEGA, QUAT = scipy_data()


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_data_that_do_not_fix_the_inertia():
    """A steady spin (constant Ω) does not determine the inertia: a clear error, not a
    `converged` estimate with std 0."""
    for w in ([0.0, 0.0, 1.0], [0.3, 0.2, 1.0]):
        with pytest.raises(ValueError, match="inertia is not identifiable from these data"):
            identify_inertia(TS, omega_obs=np.tile(w, (TS.size, 1)))


def test_non_finite_data():
    bad = OMEGA.copy()
    bad[40, 2] = np.nan
    with pytest.raises(ValueError, match=r"omega_obs must be finite: omega_obs\[40, 2\] = nan"):
        identify_inertia(TS, omega_obs=bad)
    with pytest.raises(ValueError, match="quat_obs must hold non-zero quaternions"):
        identify_inertia(TS, quat_obs=np.zeros((TS.size, 4)))


def test_gyro_data_full_tensor(recwarn):
    rng = np.random.default_rng(0)
    # (the default trace given as a NumPy float: it was kept as a static field, with
    # equinox's warning about a JAX array set as static)
    omega_obs = OMEGA + 1e-3 * rng.normal(size=OMEGA.shape)
    est = identify_inertia(TS, omega_obs=omega_obs, trace=np.float64(1.0))
    assert not [w for w in recwarn if "static" in str(w.message)]
    assert bool(est.converged) and bool(est.identifiable)
    assert "trace" in est.scale
    ref = I_TRUE / np.trace(I_TRUE)
    err = np.abs(np.asarray(est.inertia) - ref).max()
    assert err <= 0.005 * np.trace(ref), err
    # the Gauss–Newton uncertainty is of the size of the actual error
    assert err < 6 * float(np.max(est.inertia_std)) and float(np.max(est.inertia_std)) < 5e-3
    np.testing.assert_allclose(est.omega0, W0, atol=5e-3)
    np.testing.assert_allclose(est.principal_moments, np.array([1.0, 2.0, 2.6]) / 5.6, atol=2e-3)


def test_float32_data_give_a_float32_fit():
    """float32 data under x64: a float32 estimate, as the float64 fit to float32 precision
    (the step's damping took a float64 identity and the fit's loop failed to trace)."""
    rng = np.random.default_rng(0)
    data = OMEGA + 1e-3 * rng.normal(size=OMEGA.shape)
    ref = identify_inertia(TS, omega_obs=data)
    est = identify_inertia(TS.astype(np.float32), omega_obs=data.astype(np.float32))
    assert bool(est.converged)
    for name in ("inertia", "inertia_std", "omega0"):
        assert getattr(est, name).dtype == jnp.float32, name
    np.testing.assert_allclose(est.inertia, ref.inertia, atol=2e-5)
    np.testing.assert_allclose(est.inertia_std, ref.inertia_std, rtol=1e-2)


@pytest.mark.slow  # ~35 s: compiling the attitude-only fit
def test_attitude_data_only():
    rng = np.random.default_rng(1)
    noisy = Rotation.from_quat(QUAT, scalar_first=True) * Rotation.from_rotvec(
        1e-3 * rng.normal(size=(len(TS), 3))
    )
    est = identify_inertia(TS, quat_obs=noisy.as_quat(scalar_first=True))
    assert bool(est.converged)
    ref = I_TRUE / np.trace(I_TRUE)
    assert np.abs(np.asarray(est.inertia) - ref).max() <= 0.005
    # the fitted initial attitude matches the truth (up to the sign of q)
    assert abs(abs(float(jnp.dot(est.q0, Q0))) - 1) < 1e-5


@pytest.mark.slow  # ~10 s: compiling the attitude-only fit
def test_noisy_attitude_data_reach_the_right_minimum():
    """0.01 rad star-tracker noise at 10 Hz on a tumbling body near its intermediate axis: the
    linear start (from twice-differenced attitudes) led the fit to a degenerate rod
    (I_min = 0): "not identifiable", or a converged wrong tensor. Where the fit from the linear
    start fails, it runs from a sphere: both noise draws (of 20, the two that failed) fit."""
    Rm = Rotation.from_rotvec([0.2, -0.3, 0.4]).as_matrix()
    I = Rm @ np.diag([1.0, 2.0, 2.6]) @ Rm.T
    I = I / np.trace(I)
    ts = np.linspace(0.0, 6.0, 61)
    _, q = rigid_body_dop853(I, [0.3, 1.0, -0.4], [1.0, 0, 0, 0], ts)
    rng = np.random.default_rng(5)
    draws = [0.01 * rng.normal(size=(ts.size, 3)) for _ in range(14)]
    for k in (10, 13):
        noisy = Rotation.from_quat(q, scalar_first=True) * Rotation.from_rotvec(draws[k])
        est = identify_inertia(ts, quat_obs=noisy.as_quat(scalar_first=True), sigma_angle=0.01)
        assert bool(est.converged) and bool(est.identifiable)
        assert np.abs(np.asarray(est.inertia) - I).max() < 0.02
        assert float(est.cost) < 120  # ½ χ² of 183 residuals


@pytest.mark.slow  # ~50 s: compiling the fit with a torque model and both data kinds
def test_known_torque_gives_absolute_inertia():
    omega, quat_ = scipy_data(K)
    est = identify_inertia(
        TS, omega_obs=omega, quat_obs=quat_, torque=lambda t, w, q: jnp.asarray(K)
    )
    assert bool(est.converged) and est.scale.startswith("absolute")
    np.testing.assert_allclose(est.inertia, I_TRUE, atol=1e-6)
    np.testing.assert_allclose(est.principal_moments, [1.0, 2.0, 2.6], atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=6, max_size=6))
def test_projection_gives_a_physical_body(params):
    """`project` clips the negative eigenvalues of Σ (NumPy reference): symmetric, PSD, triangle
    inequality; physical parameters unchanged; exact round trip through the tensor."""
    p = np.asarray(params)
    S = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    s, V = np.linalg.eigh(S)
    S_ref = (V * np.maximum(s, 0.0)) @ V.T
    sigma = np.linalg.eigvalsh(S_ref)
    assume(sigma[1] > 1e-6 * max(sigma[2], 1e-300))  # exclude the rod (rank-one Σ) and Σ = 0
    proj = np.asarray(project(jnp.asarray(p)))
    if s[0] >= 0:  # physical: unchanged
        np.testing.assert_array_equal(proj, p)
    np.testing.assert_allclose(proj, S_ref[[0, 1, 2, 1, 2, 2], [0, 1, 2, 0, 0, 1]], atol=1e-12)
    for trace in (None, 1.0):
        I = inertia_from_params(jnp.asarray(proj), trace)
        check_inertia(I, rtol=1e-9)
        back = params_from_inertia(I, trace)
        np.testing.assert_allclose(project(back), back, rtol=1e-12, atol=1e-15)  # to rounding
        np.testing.assert_allclose(inertia_from_params(back, trace), I, rtol=1e-12, atol=1e-12)


def test_feasibility_gradient():
    """`∂σ_min/∂θ` against central differences of NumPy's smallest eigenvalue of Σ."""
    p = np.array([0.3, 1.1, 0.7, 0.2, -0.1, 0.25])

    def smallest(x):
        S = np.array([[x[0], x[3], x[4]], [x[3], x[1], x[5]], [x[4], x[5], x[2]]])
        return np.linalg.eigvalsh(S)[:1]

    c, n = feasibility(jnp.asarray(p))
    np.testing.assert_allclose(c, smallest(p)[0], rtol=1e-12)
    np.testing.assert_allclose(n, fd_jacobian(smallest, p)[0], atol=1e-8)


def test_planar_body_is_reachable():
    """A plate (I3 = I1 + I2, normal along body x) has exact parameters (σ_min = 0: on the
    boundary of the physical set, not outside it)."""
    I = np.diag([3.0, 1.0, 2.0])
    p = params_from_inertia(I)
    np.testing.assert_array_equal(inertia_from_params(p, None), I)
    assert float(feasibility(p)[0]) == 0.0


def planar_data(moments):
    """Clean gyro and attitude data (SciPy DOP853) of the rotated body with these moments, and
    its tensor normalised to trace 1."""
    I = R @ np.diag(moments) @ R.T
    omega, quat_ = rigid_body_dop853(I, W0, Q0, TS, lambda t, w, q: np.zeros(3))
    return omega, quat_, I / np.trace(I)


@pytest.mark.parametrize("moments", [[1.0, 2.0, 3.0], [1.0, 2.0, 2.999]])
def test_planar_body_identified(moments):
    """A plate (and a nearly planar body) is identified like any other body: its truth from
    clean gyro data, identifiable, std of the size of the actual scatter (noisy data), and a
    physical estimate (the constraint Σ ⪰ 0 is active for a plate)."""
    omega, _, ref = planar_data(moments)
    est = identify_inertia(TS, omega_obs=omega)
    assert bool(est.converged) and bool(est.identifiable)
    np.testing.assert_allclose(est.inertia, ref, atol=1e-6)
    np.testing.assert_allclose(est.principal_moments, np.asarray(moments) / sum(moments), atol=1e-6)
    assert float(np.max(est.inertia_std)) < 1e-8  # clean data
    rng = np.random.default_rng(3)
    sigma = 1e-3
    est = identify_inertia(
        TS, omega_obs=omega + sigma * rng.normal(size=omega.shape), sigma_omega=sigma
    )
    assert bool(est.converged) and bool(est.identifiable)
    check_inertia(est.inertia, rtol=1e-12)
    err = np.abs(np.asarray(est.inertia) - ref)
    std = np.asarray(est.inertia_std)
    assert np.all(err < 4 * std) and 1e-5 < float(np.max(std)) < 1e-3, (err, std)


@pytest.mark.slow  # compiles the attitude-only fit
def test_planar_body_from_attitude_data():
    _, quat_, ref = planar_data([1.0, 2.0, 3.0])
    est = identify_inertia(TS, quat_obs=quat_)
    assert bool(est.converged) and bool(est.identifiable)
    np.testing.assert_allclose(est.inertia, ref, atol=1e-6)
    assert abs(abs(float(jnp.dot(est.q0, Q0))) - 1) < 1e-9


def test_bad_input():
    with pytest.raises(ValueError, match="too few samples"):
        identify_inertia(TS[:2], omega_obs=OMEGA[:2])
    with pytest.raises(ValueError, match="strictly increasing"):
        identify_inertia(TS[::-1], omega_obs=OMEGA)
    with pytest.raises(ValueError, match="omega_obs"):
        identify_inertia(TS)
    with pytest.raises(ValueError, match=r"omega_obs must have shape \(81, 3\)"):
        identify_inertia(TS, omega_obs=OMEGA[:10])
    # -1 gave a negative-definite tensor, 0 "not identifiable"
    for trace in (-1.0, 0.0, np.inf, np.nan):
        with pytest.raises(ValueError, match=r"trace must be positive \(and finite\), got"):
            identify_inertia(TS, omega_obs=OMEGA, trace=trace)
    for name in ("max_steps", "sim_max_steps"):
        for n in (0, -3):
            with pytest.raises(ValueError, match=f"{name} must be a positive integer, got"):
                identify_inertia(TS, omega_obs=OMEGA, **{name: n})


def test_step_limits():
    """Too few RK4 steps for the data is a clear error (it was blamed on the data: "not
    identifiable"); one Levenberg–Marquardt step is a valid, unconverged fit."""
    with pytest.raises(
        ValueError, match=r"reached sim_max_steps = 1 .* \(it needs \d+: .*raise sim"
    ):
        identify_inertia(TS, omega_obs=OMEGA, sim_max_steps=1)
    # under jit the check goes with every output (it was on num_steps only: dropped with it)
    with raises_in_jit("the model.s simulation reached sim_max_steps = 1 "):
        jax.jit(lambda w: identify_inertia(TS, omega_obs=w, sim_max_steps=1).inertia)(OMEGA)
    # NumPy integers are integers
    est = identify_inertia(TS, omega_obs=OMEGA, max_steps=np.int64(1))
    assert not bool(est.converged) and int(est.num_steps) == 1


@pytest.mark.slow
def test_vmap_over_datasets():
    """Two datasets (different noise) fitted in one vmapped call equal the separate fits."""
    ts = TS[:41]
    rng = np.random.default_rng(2)
    data = OMEGA[None, :41] + 1e-3 * rng.normal(size=(2, 41, 3))
    batched = jax.vmap(lambda w: identify_inertia(ts, omega_obs=w).inertia)(jnp.asarray(data))
    single = identify_inertia(ts, omega_obs=data[1]).inertia
    np.testing.assert_allclose(batched[1], single, atol=1e-8)
    ref = I_TRUE / np.trace(I_TRUE)
    assert np.abs(np.asarray(batched) - ref).max() < 0.005
