"""The elliptic integral of the third kind at large negative characteristics, and the closed-form
attitude where the precession angle needs it: a symmetric top turning slowly about its axis
(ν² ~ 1/Ω3²), and a body with I1 ≪ I3 in float32 (ψ̇ = M/I1 − … cancels). References: the
elementary Π at m = 0, SciPy's quadrature, DOP853, the symmetric top's own closed form."""

import jax.numpy as jnp
import numpy as np
from scipy.integrate import quad, solve_ivp

from rigidjax import analytic
from tests.helpers import rigid_body_dop853, rigid_body_rhs


def qdist(a, b):
    """Largest distance between unit quaternions up to sign."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))))


def test_ellippi_keeps_its_digits_at_large_negative_characteristic():
    # m = 0: Π(n; φ|0) = atan(√(1 − n) tan φ)/√(1 − n); the sum F + (n/3) s³ R_J lost every
    # digit by n ~ −1e16 (1.2 instead of 9e-9)
    n = -np.logspace(-1, 16, 18)
    phi = np.array([-1.4, 1e-3, 0.3, 1.2, np.pi / 2])
    N, PHI = np.meshgrid(n, phi)
    mu = np.sqrt(1 - N)
    exact = np.arctan2(mu * np.sin(PHI), np.cos(PHI)) / mu
    got = np.asarray(analytic.ellippi(N, PHI, np.zeros_like(N)))
    np.testing.assert_allclose(got, exact, rtol=2e-14, atol=0)
    # 0 < m < 1 against the integral itself
    for nn in (-0.5, -2.0, -1e3, -1e7):
        for m in (0.3, 0.99):
            for ph in (0.4, 1.3, 3.0):

                def f(t, nn=nn, m=m):
                    s2 = np.sin(t) ** 2
                    return 1 / ((1 - nn * s2) * np.sqrt(1 - m * s2))

                pts = [k * np.pi for k in range(int(ph / np.pi) + 1)]
                ref = quad(f, 0, ph, points=pts, epsabs=0, epsrel=2e-14, limit=500)[0]
                got = float(analytic.ellippi(nn, ph, m))
                np.testing.assert_allclose(got, ref, rtol=1e-12, err_msg=f"{nn} {m} {ph}")


def test_attitude_of_a_symmetric_top_turning_slowly_about_its_axis():
    """I = (2, 2, 1) and (1, 2, 2), Ω0 = (0.3, 0.8, δ) with δ on the unique axis: the general
    closed form took ν² ~ 1/δ² and was 2 rad off at δ = 1e-8 (5.5e-4 at δ = 1e-5)."""
    ts = np.linspace(0.0, 5.0, 11)
    deltas = (1e-5, 1e-8, 1e-14)
    I = np.array([[2.0, 2.0, 1.0]] * 3 + [[1.0, 2.0, 2.0]] * 3)
    w = np.array([[0.3, 0.8, d] for d in deltas] + [[d, 0.3, 0.8] for d in deltas])
    q0 = np.array([0.9, 0.1, -0.3, 0.2])
    q0 = np.broadcast_to(q0 / np.linalg.norm(q0), (len(w), 4))
    q = np.asarray(analytic.free_rigid_body_attitude(I, w, q0, ts))
    top = np.asarray(
        analytic.symmetric_top_attitude(jnp.asarray(2.0), jnp.asarray(1.0), w[:3], q0[:3], ts)
    )
    assert qdist(q[:3], top) < 1e-12
    for k in (1, 4):  # δ = 1e-8, each axis order
        assert qdist(q[k], rigid_body_dop853(I[k], w[k], q0[k], ts)[1]) < 1e-11
    # q(0) = q0 exactly enough, however small δ
    assert qdist(q[:, 0], q0) < 1e-15


def test_float32_attitude_of_a_body_with_very_unequal_moments():
    """I = (1, 1e3, 1e3 + 1): ψ = M t/I1 − … cancelled to 17 000 rad of which 17 remain, so
    float32 was 1.4e-3 rad off after 20 s; float64 is the reference (and DOP853 its own)."""
    I = np.array([1.0, 1e3, 1e3 + 1])
    w = np.array([0.3, -0.5, 0.7])
    ts = np.linspace(0.0, 20.0, 9)
    q64 = np.asarray(analytic.free_rigid_body_attitude(I, w, None, ts))
    assert qdist(q64, rigid_body_dop853(I, w, (1.0, 0, 0, 0), ts)[1]) < 1e-10
    q32 = analytic.free_rigid_body_attitude(
        I.astype(np.float32), w.astype(np.float32), None, ts.astype(np.float32)
    )
    assert q32.dtype == jnp.float32
    assert qdist(q32, q64) < 2e-5


def test_first_flip_close_to_the_separatrix():
    """I = (1, 2, 3), Ω0 = (δ, 1, δ): the flip time is F(φ|m)/|λ| with φ → π/2 and m → 1, where
    dF/dφ = 1/Δ is huge; F from φ itself was 7.9e-3 off at δ = 1e-14 (2.7e-7 at 1e-10). The
    reference: the sign change of Ω2 in the closed-form Ω(t) (the Jacobi functions, another
    path), on a grid of step 1e-7 around it, linearly interpolated; SciPy's DOP853 event."""
    I = np.array([1.0, 2.0, 3.0])
    for d in (1e-8, 1e-10, 1e-12, 1e-14):
        w = np.array([d, 1.0, d])
        t = float(analytic.time_of_first_flip(I, w))
        grid = t + np.linspace(-1e-4, 1e-4, 2001)
        w2 = np.asarray(analytic.free_rigid_body(I, w, grid))[:, 1]
        k = int(np.flatnonzero((w2[:-1] > 0) & (w2[1:] <= 0))[0])
        ref = grid[k] + (grid[k + 1] - grid[k]) * w2[k] / (w2[k] - w2[k + 1])
        assert abs(t - ref) < 1e-10, (d, t - ref)
        if d in (1e-10, 1e-12):  # and SciPy's DOP853 with an event, independent of rigidjax
            hit = solve_ivp(
                rigid_body_rhs(I),
                (0.0, t + 1.0),
                np.concatenate([w, [1.0, 0.0, 0.0, 0.0]]),
                method="DOP853",
                rtol=1e-13,
                atol=1e-15,
                events=lambda _, y: y[1],
            )
            assert abs(t - hit.t_events[0][0]) < 1e-8, (d, t - hit.t_events[0][0])
