"""Gravity-gradient satellite: torque against a point-mass model, LVLH equilibrium, pitch libration
frequency measured from the simulation, roll/yaw against the linearised equations."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from rigidjax import RigidBody
from rigidjax.mechanics import satellite as sat

MU, RADIUS = 1.0, 1.0
N_ORB = 1.0  # √(μ/r³)
MOMENTS = np.array([2.0, 2.5, 1.0])  # I_y > I_x > I_z: Lagrange region, all librations stable
BODY = RigidBody(MOMENTS, 3.0)
R0, V0 = (np.asarray(x) for x in sat.circular_orbit(MU, RADIUS))
TS = np.linspace(0.0, 10 * 2 * np.pi, 2001)  # ten orbits; every test reuses one compilation
TIGHT = dict(rtol=1e-11, atol=1e-11)


def _run(rotvec=None, body=BODY):
    q0, w0 = sat.lvlh_state(R0, V0, rotvec)
    tr = sat.simulate_satellite(body, R0, V0, q0, w0, TS, MU, **TIGHT)
    return tr, np.asarray(sat.lvlh_angles(tr.R, tr.V, tr.quat))


def test_gravity_gradient_torque_against_point_masses():
    """Six point masses ±d e_k (different masses per axis) far from the Earth: the exact torque
    Σ ρ_i × (−μ m_i r_i/r_i³) about the COM tends to (3μ/R³) n × I n with relative error
    O((d/R)²) (odd terms cancel by symmetry)."""
    d, Rn = 1.0, 1e3
    masses = np.array([1.0, 2.0, 0.5])
    rho = np.concatenate([np.diag([d, d, d]), -np.diag([d, d, d])])
    m = np.concatenate([masses, masses])
    I = sum(mi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for mi, ri in zip(m, rho, strict=True))
    q = Rotation.from_rotvec([0.3, -0.8, 0.5]).as_quat(scalar_first=True)
    P = Rotation.from_quat(q, scalar_first=True).as_matrix()
    R = Rn * np.array([0.6, -0.48, 0.64])
    K_space = sum(
        np.cross(P @ ri, -MU * mi * (R + P @ ri) / np.linalg.norm(R + P @ ri) ** 3)
        for mi, ri in zip(m, rho, strict=True)
    )
    K = sat.gravity_gradient_torque(MU, R, q, I)
    assert np.linalg.norm(K) > 0
    np.testing.assert_allclose(P @ K, K_space, rtol=1e-5, atol=1e-6 * np.linalg.norm(K_space))
    # moments form == diagonal tensor form
    np.testing.assert_allclose(
        sat.gravity_gradient_torque(MU, R, q, MOMENTS),
        sat.gravity_gradient_torque(MU, R, q, np.diag(MOMENTS)),
    )


def test_lvlh_frame():
    L = np.asarray(sat.lvlh_matrix(R0, V0))
    np.testing.assert_allclose(L.T @ L, np.eye(3), atol=1e-15)
    assert np.linalg.det(L) > 0
    np.testing.assert_allclose(L[:, 0], V0 / np.linalg.norm(V0))  # along-track
    np.testing.assert_allclose(L[:, 2], -R0 / np.linalg.norm(R0))  # nadir
    q, w = sat.lvlh_state(R0, V0)
    np.testing.assert_allclose(w, [0.0, -N_ORB, 0.0], atol=1e-15)  # ω_o = (0, −n, 0) in LVLH


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_equilibrium_stays_put():
    tr, ang = _run()
    assert np.max(np.abs(ang)) < 1e-8
    # the orbit stays circular (Kepler: orbit integrated together with the attitude)
    np.testing.assert_allclose(np.linalg.norm(tr.R, axis=-1), RADIUS, rtol=1e-9)


def test_pitch_libration_frequency():
    theta0 = 0.01
    tr, ang = _run([0.0, theta0, 0.0])
    roll, pitch, yaw = ang.T
    assert np.max(np.abs(roll)) < 1e-10 and np.max(np.abs(yaw)) < 1e-10  # planar motion
    assert np.max(np.abs(pitch)) == pytest.approx(theta0, rel=1e-3)  # libration, not tumbling
    # zero crossings (linear interpolation is O(dt³) there: the inflection point of a sinusoid)
    s = np.sign(pitch)
    idx = np.flatnonzero(s[:-1] * s[1:] < 0)
    t0, t1 = TS[idx], TS[idx + 1]
    tz = t0 - pitch[idx] * (t1 - t0) / (pitch[idx + 1] - pitch[idx])
    assert tz.size >= 15
    half_period = np.polyfit(np.arange(tz.size), tz, 1)[0]
    w_sim = np.pi / half_period
    w_formula = float(sat.pitch_frequency(MOMENTS, N_ORB))
    assert abs(w_sim / w_formula - 1) <= 1e-3
    # the formula's axis labels matter: swapping x and z gives an unstable "frequency"
    with pytest.raises(ValueError, match="unstable"):
        sat.pitch_frequency(MOMENTS[::-1], N_ORB)


def test_pitch_unstable_when_ix_below_iz():
    tr, ang = _run([0.0, 1e-3, 0.0], body=RigidBody([1.0, 2.5, 2.0], 3.0))
    assert np.max(np.abs(ang[:, 1])) > 0.1  # runs away from the equilibrium


def test_roll_yaw_against_linearised_equations():
    Ix, Iy, Iz = MOMENTS
    n = N_ORB
    # roll/yaw linear system x = (φ, ψ, φ̇, ψ̇) (module docstring)
    c = n * (Ix - Iy + Iz)
    A = np.array(
        [
            [0, 0, 1, 0],
            [0, 0, 0, 1],
            [-4 * n**2 * (Iy - Iz) / Ix, 0, 0, c / Ix],
            [0, -(n**2) * (Iy - Ix) / Iz, -c / Iz, 0],
        ]
    )
    ev = np.linalg.eigvals(A)
    assert np.max(np.abs(ev.real)) < 1e-12
    np.testing.assert_allclose(
        sorted(np.abs(ev.imag))[::2], sat.roll_yaw_frequencies(MOMENTS, n), rtol=1e-12
    )
    amp = 1e-4
    tr, ang = _run([amp, 0.0, -0.7 * amp])
    x0 = np.array([amp, -0.7 * amp, 0.0, 0.0])  # Ω = Pᵀω_o at start ⇒ α̇(0) = 0 to first order
    lin = np.stack([expm(A * t) @ x0 for t in TS])
    roll, yaw = ang[:, 0], ang[:, 2]
    err = max(np.max(np.abs(roll - lin[:, 0])), np.max(np.abs(yaw - lin[:, 1])))
    assert err < 1e-3 * amp  # nonlinear terms are O(amp²); 10 orbits of phase agree
    assert np.max(np.abs(ang[:, 1])) < 1e-6  # pitch is only excited at second order


def test_bad_input():
    with pytest.raises(ValueError, match="mu must be positive"):
        sat.simulate_satellite(BODY, R0, V0, None, [0.0, -1.0, 0.0], TS, -1.0)
    with pytest.raises(ValueError, match="must be diagonal"):
        sat.pitch_frequency(RigidBody(np.array([[2.0, 0.1, 0], [0.1, 2.5, 0], [0, 0, 1.0]])), 1.0)
    with pytest.raises(TypeError, match="RigidBody"):
        sat.simulate_satellite(MOMENTS, R0, V0, None, [0.0, -1.0, 0.0], TS, 1.0)
    # no LVLH frame for a radial velocity or R = 0; no gravity gradient at R = 0 (NaN before)
    for R, V in [(R0, 2 * np.asarray(R0)), (np.zeros(3), V0)]:
        with pytest.raises(ValueError, match="LVLH frame needs R and V .* not parallel"):
            sat.lvlh_angles(R, V, [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="R must be a non-zero position"):
        sat.gravity_gradient_torque(1.0, np.zeros(3), [1.0, 0.0, 0.0, 0.0], MOMENTS)
