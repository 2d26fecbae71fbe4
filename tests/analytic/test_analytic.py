"""Closed forms of rigidjax.analytic against SciPy (special functions, DOP853 integration),
rigidjax.simulate, Principia's published test case and finite differences.

Compilation dominates the cost: cases are batched into a few calls with shared shapes. The closed
forms take `check=False` throughout: the cases hold Principia's formal moments (3, 5, 9), outside
the triangle inequality, and finite differences leave the flat body (1, 2, 3) both ways."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special as sp
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax import analytic
from tests.helpers import DOP853_TIGHT as RTOL_IVP
from tests.helpers import fd_jacobian, rigid_body_dop853, scalar_first
from tests.helpers import rigid_body_rhs as _rhs

# ---------------------------------------------------------------------------------------------
# references
# ---------------------------------------------------------------------------------------------


def ivp(I, w0, ts, q0=(1.0, 0, 0, 0), t0=0.0):
    """Euler's equations + q̇ = ½ q∘(0,Ω) by DOP853 at rtol = atol = 1e-13; (Ω (T,3), q (T,4))."""
    return rigid_body_dop853(I, w0, q0, ts, t0=t0)


def qdist(a, b):
    """Largest distance between unit quaternions up to sign."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))))


def random_quat(rng, n):
    return scalar_first(Rotation.random(n, random_state=rng))


# ---------------------------------------------------------------------------------------------
# Jacobi elliptic functions
# ---------------------------------------------------------------------------------------------


def test_ellipj_matches_scipy(rng):
    u = rng.uniform(-40, 40, 3000)
    # SciPy's ellipj loses all accuracy for 1 − m ≲ 1e-9 at large u (cn ~ 1e10): compare above it
    m = np.concatenate([rng.uniform(0, 1, 2000), 1 - 10 ** rng.uniform(-8, 0, 1000)])
    m[:3] = [0.0, 1.0, 0.5]
    got = analytic.ellipj(u, m)
    ref = sp.ellipj(u, m)
    for g, r, name in zip(got, ref, ("sn", "cn", "dn", "am"), strict=True):
        np.testing.assert_allclose(g, r, rtol=0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(analytic.sn(u, m), ref[0], atol=1e-12)
    np.testing.assert_allclose(analytic.cn(u, m), ref[1], atol=1e-12)
    np.testing.assert_allclose(analytic.dn(u, m), ref[2], atol=1e-12)
    np.testing.assert_allclose(analytic.am(u, m), ref[3], atol=1e-12)
    assert np.all(np.isnan(np.asarray(analytic.ellipj(1.0, np.array([-0.1, 1.1]))[0])))


def test_ellipj_near_one(rng):
    """1 − m down to 1e-16, where SciPy fails: identities, the derivative of am, the inverse
    am(F(φ)) = φ, and the m → 1 limit sn = tanh u + O(1 − m)."""
    m1 = 10 ** rng.uniform(-16, -6, 500)
    m = 1 - m1
    u = rng.uniform(-60, 60, 500)
    s, c, d, ph = analytic.ellipj(u, m)
    np.testing.assert_allclose(s**2 + c**2, 1, atol=1e-15)
    np.testing.assert_allclose(d**2, 1 - m * s**2, atol=1e-15)
    # F ∘ am is ill-conditioned here (du/dφ = 1/dn ~ 1/√(1 − m)); am ∘ F is not
    phi = rng.uniform(-12, 12, 500)
    np.testing.assert_allclose(analytic.am(analytic.ellipkinc(phi, m), m), phi, atol=1e-13)
    dam = jax.vmap(jax.grad(analytic.am))(jnp.asarray(u), jnp.asarray(m))
    np.testing.assert_allclose(dam, d, rtol=1e-10, atol=1e-12)
    small = np.abs(u) < 3
    np.testing.assert_allclose(s[small], np.tanh(u[small]), atol=1e-5)
    np.testing.assert_allclose(c[small], 1 / np.cosh(u[small]), atol=1e-5)


def test_ellipk_ellipkinc_match_scipy(rng):
    m = np.concatenate([[0.0, 0.5, 1 - 1e-12], rng.uniform(0, 1, 500)])
    np.testing.assert_allclose(analytic.ellipk(m), sp.ellipk(m), rtol=1e-14)
    assert np.isinf(analytic.ellipk(1.0))
    p = 10 ** rng.uniform(-300, 0, 200)
    np.testing.assert_allclose(analytic.ellipkm1(p), sp.ellipkm1(p), rtol=1e-14)
    phi = rng.uniform(-12, 12, 2000)
    mm = np.concatenate([rng.uniform(0, 1, 1000), 1 - 10 ** rng.uniform(-15, 0, 1000)])
    np.testing.assert_allclose(analytic.ellipkinc(phi, mm), sp.ellipkinc(phi, mm), rtol=1e-12)
    np.testing.assert_allclose(analytic.ellipkinc(0.7, 1.0), sp.ellipkinc(0.7, 1.0), rtol=1e-14)
    # am is the inverse of F
    np.testing.assert_allclose(analytic.am(analytic.ellipkinc(phi, mm), mm), phi, atol=1e-13)


def test_sn_derivative_in_m_close_to_one():
    """∂sn/∂m near u = ±K (where sn is the reflected cd) for m → 1, against mpmath
    (`mp.diff` of `ellipfun('sn', u, m)` at 50 digits, m the given doubles): d(cd v) lost
    eps/(1 − m) to cancellation (1.2e-4 and 3e-8 relative)."""
    u = jnp.array([-14.0, 10.0])
    m = jnp.array([1 - 1e-12, 1 - 1e-8])
    ref = np.array([0.22740273326242747, -0.17419292392457459])
    got = jax.vmap(jax.grad(analytic.sn, 1))(u, m)
    np.testing.assert_allclose(got, ref, rtol=1e-9)


def test_elliptic_derivatives(rng):
    """d sn/du = cn dn, d am/du = dn, dF/dφ = 1/√(1 − m sin²φ); d/dm against central differences of
    SciPy (m in [0, 1)); dK/dm against (E − (1 − m)K)/(2m(1 − m)) and π/8 at m = 0."""
    u = jnp.asarray(rng.uniform(-5, 5, 40))
    m = jnp.asarray(np.concatenate([[0.0, 1e-9], rng.uniform(0, 0.999, 38)]))

    funcs = (analytic.sn, analytic.cn, analytic.dn, analytic.am, analytic.ellipkinc)

    @jax.jit
    def derivs(u, m):
        stacked = lambda u, m: jnp.stack([f(u, m) for f in funcs])  # noqa: E731
        return (
            jax.vmap(jax.jacrev(stacked, argnums=(0, 1)))(u, m),
            jax.vmap(jax.grad(analytic.ellipk))(m),
        )

    (du, dm), dk = derivs(u, m)
    du, dm, dk = np.asarray(du), np.asarray(dm), np.asarray(dk)
    _, c, d, _ = sp.ellipj(u, m)
    np.testing.assert_allclose(du[:, 0], c * d, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(du[:, 3], d, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(du[:, 4], 1 / np.sqrt(1 - m * np.sin(u) ** 2), rtol=1e-12)
    h = 1e-6
    mp, mm = np.asarray(m) + h, np.maximum(np.asarray(m) - h, 0)
    for i in range(3):
        fd = (sp.ellipj(u, mp)[i] - sp.ellipj(u, mm)[i]) / (mp - mm)
        np.testing.assert_allclose(dm[:, i], fd, rtol=1e-5, atol=1e-6)
    fd = (sp.ellipkinc(u, mp) - sp.ellipkinc(u, mm)) / (mp - mm)
    np.testing.assert_allclose(dm[:, 4], fd, rtol=1e-5, atol=1e-6)
    assert np.all(np.isfinite(dm))
    mk = np.asarray(m)[2:]
    ref = (sp.ellipe(mk) - (1 - mk) * sp.ellipk(mk)) / (2 * mk * (1 - mk))
    np.testing.assert_allclose(dk[2:], ref, rtol=1e-10)
    np.testing.assert_allclose(dk[0], math.pi / 8, rtol=1e-14)


# ---------------------------------------------------------------------------------------------
# Euler–Poinsot. Every closed form is evaluated ONCE on a batch of all cases and a union grid of
# times (the closed forms accept unsorted times), so each compiles once; tests slice the batch.
# ---------------------------------------------------------------------------------------------

TS = np.linspace(0.0, 40.0, 161)  # step 0.25
EXTRA = np.array([-7.0, -3.0, -1.5, 333.3, 400.0])
T_ALL = np.concatenate([TS, EXTRA])
SEP_T = np.flatnonzero(TS <= 8.0)  # separatrix: λ t ≤ 6 (rounding grows like e^{λt})


def _at(*times):
    return np.array([np.flatnonzero(T_ALL == t)[0] for t in times])


def _cases():
    rng = np.random.default_rng(7)
    cases = {}
    n = 14  # random bodies (moments in random order), Ω0 with random signs: both regimes
    I = rng.uniform(1.0, 3.0, (n, 3))
    w = rng.normal(size=(n, 3)) * rng.choice([-1, 1], (n, 3))
    I[0], w[0] = (
        (3.0, 5.0, 9.0),
        np.array([0.0, 2.0, 0.01]) / np.array([3.0, 5.0, 9.0]),
    )  # Principia
    I[1], w[1] = (9.0, 3.0, 5.0), np.array([0.01, 0.0, -2.0]) / np.array([9.0, 3.0, 5.0])
    I[2], w[2] = (1.0, 2.0, 3.0), (1.0, 0.1, 0.1)  # around the smallest axis
    I[3], w[3] = (3.0, 2.0, 1.0), (-0.1, 0.1, 1.0)  # around the smallest axis, reversed labels
    cases["generic"] = (I, w)
    # exact separatrix I1(I2 − I1)Ω1² = I3(I3 − I2)Ω3² for I = (3, 4, 6), Ω = (±2, ±½, ±1), permuted
    signs = np.array([[1, 1, 1], [-1, 1, 1], [1, -1, -1], [-1, -1, 1]], float)
    ws = signs * np.array([2.0, 0.5, 1.0])
    Is = np.array([[3.0, 4.0, 6.0], [3.0, 4.0, 6.0], [6.0, 3.0, 4.0], [4.0, 6.0, 3.0]])
    ws[2], ws[3] = ws[2][[2, 0, 1]], ws[3][[1, 2, 0]]
    cases["separatrix"] = (Is, ws)
    # constant Ω: sphere, Ω = 0, steady rotation about each axis, equatorial rotation of an oblate
    # and a prolate symmetric top
    Id = np.array([[2, 2, 2], [1, 2, 3], [2, 3, 4], [2, 3, 4], [2, 3, 4], [2, 2, 3], [3, 4, 4.0]])
    wd = np.array(
        [
            [0.3, -1, 2],
            [0, 0, 0],
            [1.5, 0, 0],
            [0, -1.5, 0],
            [0, 0, 1.5],
            [0.6, -0.8, 0],
            [0, 0.6, -0.8],
        ]
    )
    cases["steady"] = (Id, wd)
    # near (not on) the separatrix: 1 − k² ≈ 1e-12
    cases["near_separatrix"] = (np.array([[3.0, 4.0, 6.0]]), np.array([[2.0, 0.5, 1.0 + 1e-12]]))
    # symmetric tops (oblate, prolate)
    It = np.array([[2.0, 2.0, 3.0], [3.0, 3.0, 1.5]])
    cases["top"] = (It, np.array([[0.3, -0.7, 1.1]] * 2))
    return cases


CASES = _cases()


@pytest.fixture(scope="module")
def batch():
    """Ω, q (closed forms) for all cases at T_ALL, in one call each; q0 random."""
    names = list(CASES)
    I = np.concatenate([CASES[k][0] for k in names])
    w = np.concatenate([CASES[k][1] for k in names])
    q0 = random_quat(np.random.default_rng(11), len(I))
    om = np.asarray(analytic.free_rigid_body(I, w, T_ALL, check=False))
    q = np.asarray(analytic.free_rigid_body_attitude(I, w, q0, T_ALL, check=False))
    par = analytic.free_rigid_body_parameters(I, w, check=False)
    out, start = {}, 0
    for k in names:
        sl = slice(start, start + len(CASES[k][0]))
        par_k = jax.tree_util.tree_map(lambda a, sl=sl: np.asarray(a)[sl], par)
        out[k] = dict(I=I[sl], w=w[sl], q0=q0[sl], om=om[sl], q=q[sl], par=par_k)
        start = sl.stop
    out["all"] = dict(I=I, w=w, q0=q0, om=om, q=q)
    return out


SHORT = np.abs(T_ALL) <= 40  # DOP853 references on these times (long spans cost seconds)


@pytest.fixture(scope="module")
def reference(batch):
    """DOP853 (rtol = atol = 1e-13) Ω and q for the generic cases at T_ALL[SHORT]."""
    b = batch["generic"]
    out = [ivp(b["I"][k], b["w"][k], T_ALL[SHORT], b["q0"][k]) for k in range(len(b["I"]))]
    return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])


def test_free_body_matches_dop853(batch, reference):
    b = batch["generic"]
    assert set(b["par"].regime) == {-1, 1}, b["par"].regime
    for k in range(len(b["I"])):
        ref = reference[0][k]
        err = np.max(np.abs(b["om"][k][SHORT] - ref)) / np.max(np.abs(ref))
        assert err < 1e-9, (k, b["I"][k], b["w"][k], err)
    # exact initial value
    np.testing.assert_allclose(batch["all"]["om"][:, 0], batch["all"]["w"], rtol=1e-15, atol=0)


def test_initial_time_t0(batch):
    """Ω(t0) = omega0 for t0 ≠ 0, negative times too (same shapes: no recompilation)."""
    b = batch["all"]
    t0 = 2.5
    om = np.asarray(analytic.free_rigid_body(b["I"], b["w"], T_ALL + t0, t0=t0, check=False))
    np.testing.assert_allclose(om, b["om"], atol=1e-12)
    q = analytic.free_rigid_body_attitude(b["I"], b["w"], b["q0"], T_ALL + t0, t0=t0, check=False)
    assert qdist(q, b["q"]) < 1e-12


def test_free_body_is_a_solution(batch):
    """Ω̇ (forward-mode derivative in t) satisfies Euler's equations I Ω̇ = IΩ × Ω, and 2T, |M|²
    are constant: a check independent of any integrator."""
    b = batch["all"]
    ts = jnp.asarray(TS)

    def omega(t):
        return analytic.free_rigid_body(b["I"], b["w"], t, check=False)

    om, dom = jax.jvp(omega, (ts,), (jnp.ones_like(ts),))
    I = b["I"][:, None]
    scale = np.max(np.abs(om), axis=(1, 2))[:, None, None] ** 2 * I.max()
    resid = (I * dom - np.cross(I * om, om)) / np.maximum(scale, 1e-300)
    assert np.max(np.abs(resid)) < 1e-12
    e2, m2 = np.sum(I * om**2, -1), np.sum((I * om) ** 2, -1)
    np.testing.assert_allclose(e2, e2[:, :1] * np.ones_like(e2), rtol=1e-13, atol=0)
    np.testing.assert_allclose(m2, m2[:, :1] * np.ones_like(m2), rtol=1e-13, atol=0)


def test_separatrix_sech_tanh(batch):
    b = batch["separatrix"]
    np.testing.assert_array_equal(b["par"].regime, 0)
    np.testing.assert_array_equal(b["par"].k2, 1.0)
    assert np.all(np.isinf(b["par"].period))
    ts = T_ALL[SEP_T]
    for k in range(len(b["I"])):
        np.testing.assert_allclose(b["om"][k][SEP_T], ivp(b["I"][k], b["w"][k], ts)[0], atol=1e-10)
    # aperiodic: Ω tends to a steady rotation about the middle axis (±|M|/I_mid)
    far = b["om"][:, _at(400.0)[0]]
    n = np.arange(len(b["I"]))
    mid = np.argsort(b["I"], axis=1)[:, 1]
    M = np.linalg.norm(b["I"] * b["w"], axis=1)
    np.testing.assert_allclose(np.abs(far[n, mid]), M / b["I"][n, mid], rtol=1e-12)
    # near the separatrix (1 − k² ≈ 1e-12) the periodic formula still matches DOP853
    c = batch["near_separatrix"]
    assert c["par"].regime[0] == 1 and 0 < 1 - c["par"].k2[0] < 1e-10
    np.testing.assert_allclose(c["om"][0][SEP_T], ivp(c["I"][0], c["w"][0], ts)[0], atol=1e-10)


def test_steady_and_degenerate(batch):
    """Sphere, Ω = 0, steady rotations about each axis, equatorial rotation of symmetric tops:
    Ω stays constant and P(t) = P0 exp(t Ω × E); no flip ever."""
    b = batch["steady"]
    np.testing.assert_allclose(b["om"], np.broadcast_to(b["w"][:, None], b["om"].shape), atol=1e-15)
    keep = np.abs(T_ALL) <= 40
    expect = rj.quat.mul(b["q0"][:, None], rj.quat.from_rotvec(T_ALL[keep, None] * b["w"][:, None]))
    assert qdist(b["q"][:, keep], expect) < 1e-12
    assert np.all(np.isinf(analytic.time_of_first_flip(b["I"], b["w"], check=False)))
    assert np.all(np.isfinite(b["om"])) and np.all(np.isfinite(b["q"]))


# ---------------------------------------------------------------------------------------------
# Principia's case and the flip period
# ---------------------------------------------------------------------------------------------


def _crossings(ts, x):
    """Zero crossings of samples x(ts) by a cubic through the 4 samples around each sign change."""
    out = []
    for i in np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0):
        j = slice(max(i - 1, 0), i + 3)
        r = np.roots(np.polyfit(ts[j] - ts[i], x[j], 3))
        r = r[np.isreal(r)].real + ts[i]
        out.append(r[np.argmin(np.abs(r - 0.5 * (ts[i] + ts[i + 1])))])
    return np.array(out)


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_principia_case_and_flip_period(batch):
    """Principia (documentation/Celledoni.tex): I = (3, 5, 9), M0 = (0, 2, 0.01):
    k² = 0.99996, λ = 0.21774, K = 6.4293, flip half-period 2K/λ = 59.055 s."""
    b = batch["generic"]
    I, w0 = b["I"][0], b["w"][0]
    p = jax.tree_util.tree_map(lambda a: a[0], b["par"])
    assert p.regime == 1
    assert round(float(p.k2), 5) == 0.99996
    assert round(float(p.lam), 5) == 0.21774
    assert round(float(p.K), 4) == 6.4293
    assert round(float(p.period) / 2, 3) == 59.055
    np.testing.assert_allclose(analytic.flip_period(I, w0, check=False), p.period, rtol=1e-15)

    ts = np.linspace(0.0, 260.0, 5201)  # step 0.05
    traj = rj.simulate(rj.RigidBody(I, check=False), w0, None, ts, rtol=1e-12, atol=1e-12)
    cross = _crossings(ts, np.asarray(traj.omega[:, 1]))
    assert len(cross) >= 4
    measured = cross[2] - cross[0]  # two sign changes of Ω_mid per period of Ω
    assert abs(measured / float(p.period) - 1) < 1e-6
    np.testing.assert_allclose(analytic.time_of_first_flip(I, w0, check=False), cross[0], rtol=1e-6)
    # closed form vs simulate on the shared times (TS ⊂ ts)
    np.testing.assert_allclose(b["om"][0][: len(TS)], traj.omega[::5][: len(TS)], atol=1e-9)


def test_time_of_first_flip_matches_events(batch):
    """First sign change of the component along the initially dominant axis (largest |Ω0_i|):
    finite with flips every half period when it is of cn/sn type, ∞ (no event) when the polhode
    encircles that axis (test_first_flip.py checks 200 states against simulate)."""
    b = batch["generic"]
    got = np.asarray(analytic.time_of_first_flip(b["I"], b["w"], check=False))
    periods = b["par"].period
    assert set(b["par"].regime[:8]) == {-1, 1}
    assert np.any(np.isfinite(got[:8])) and np.any(np.isinf(got[:8]))
    for k in range(8):
        dom = int(np.argmax(np.abs(b["w"][k])))
        ev = lambda t, y, dom=dom: y[dom]  # noqa: E731
        y0 = np.r_[b["w"][k], 1, 0, 0, 0]
        sol = solve_ivp(_rhs(b["I"][k]), (0, 1.01 * periods[k]), y0, events=ev, **RTOL_IVP)
        t_ev = sol.t_events[0]
        t_ev = t_ev[t_ev > 1e-9]
        if np.isinf(got[k]):
            assert len(t_ev) == 0
            continue
        assert len(t_ev) >= 2
        np.testing.assert_allclose(got[k], t_ev[0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(periods[k] / 2, t_ev[1] - t_ev[0], rtol=1e-9)
    # Ω_mid = 0 at t = 0 on a spin around the major axis, which dominates: it never flips
    Ik, wk = np.array([1.0, 2.0, 3.0]), np.array([0.4, 0.0, 1.0])
    assert np.isinf(analytic.time_of_first_flip(Ik, wk, check=False))


# ---------------------------------------------------------------------------------------------
# attitude
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def simulated(batch):
    """rigidjax.simulate for the first 7 generic bodies and the two symmetric tops, at TS."""
    g, t = batch["generic"], batch["top"]
    I = np.concatenate([g["I"][:7], t["I"]])
    w = np.concatenate([g["w"][:7], t["w"]])
    q0 = np.concatenate([g["q0"][:7], t["q0"]])
    return rj.simulate(rj.RigidBody(I, check=False), w, q0, TS, rtol=1e-12, atol=1e-12)


def test_attitude_matches_dop853_and_simulate(batch, reference, simulated):
    b = batch["generic"]
    q = b["q"]
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-14)
    for k in range(len(b["I"])):  # includes negative times
        err = qdist(q[k][SHORT], reference[1][k])
        assert err < 1e-8, (k, err)
    n = len(TS)
    assert qdist(q[:7, :n], simulated.quat[:7]) < 1e-8
    np.testing.assert_allclose(b["om"][:7, :n], simulated.omega[:7], atol=1e-8)
    # M is fixed in space
    Ms = np.asarray(rj.quat.rotate(q, b["I"][:, None] * b["om"]))
    np.testing.assert_allclose(Ms, np.broadcast_to(Ms[:, :1], Ms.shape), atol=1e-12)


def test_attitude_separatrix_and_long_times(batch):
    b = batch["separatrix"]
    idx = np.concatenate([SEP_T, _at(-3.0, -1.5)])
    for k in range(len(b["I"])):
        _, qr = ivp(b["I"][k], b["w"][k], T_ALL[idx], b["q0"][k])
        assert qdist(b["q"][k][idx], qr) < 1e-9
    # whole precession periods + quadrature stay accurate over ~6 flips (Principia body)
    g = batch["generic"]
    idx = _at(0.0, 333.3)
    assert qdist(g["q"][0][idx], ivp(g["I"][0], g["w"][0], T_ALL[idx], g["q0"][0])[1]) < 1e-8


def test_attitude_close_to_the_separatrix():
    """δ off the separatrix (1 − m ≈ δ²) the precession angle stays exact to rounding: Π takes
    the amplitudes with cn accurate to ulps of dn, where dΠ/dφ ~ 1/dn is large (with the
    amplitude only to ulps of π, the quaternion was 1e-8 off at δ = 1e-8 and 1e-2 at 1e-14)."""
    ts = np.linspace(0.0, 4.0, 5)
    I = np.array([1.0, 2.0, 3.0])
    w = np.array([[d, 1.0, d] for d in (1e-8, 1e-11, 1e-14)])
    q0 = random_quat(np.random.default_rng(5), len(w))
    q = np.asarray(analytic.free_rigid_body_attitude(I, w, q0, ts))
    for k in range(len(w)):
        assert qdist(q[k], ivp(I, w[k], ts, q0[k])[1]) < 1e-11, w[k]


# ---------------------------------------------------------------------------------------------
# symmetric top, fixed axis
# ---------------------------------------------------------------------------------------------


def test_symmetric_top(batch, simulated):
    b = batch["top"]
    I1, I3 = b["I"][:, 0], b["I"][:, 2]
    w0, q0 = b["w"], b["q0"]
    om = analytic.symmetric_top(I1, I3, w0, TS)
    q = analytic.symmetric_top_attitude(I1, I3, w0, q0, TS)
    np.testing.assert_allclose(om, simulated.omega[7:], atol=1e-10)
    assert qdist(q, simulated.quat[7:]) < 1e-9
    # the general closed form reduces to it (k² = 0)
    n = len(TS)
    np.testing.assert_allclose(b["om"][:, :n], om, atol=1e-13)
    assert qdist(b["q"][:, :n], q) < 1e-12
    np.testing.assert_array_equal(b["par"].k2, 0.0)
    # regular precession: the symmetry axis keeps the angle θ with M and turns about it at |M|/I1
    pr = analytic.symmetric_top_precession(I1, I3, w0)
    np.testing.assert_allclose(pr.body_rate, w0[:, 2] * (I3 - I1) / I1)
    np.testing.assert_allclose(pr.spin, w0[:, 2])
    M = np.linalg.norm(b["I"] * w0, axis=-1)
    np.testing.assert_allclose(pr.spin, M / I3 * np.cos(pr.nutation), rtol=1e-14)
    axis = np.asarray(rj.quat.to_matrix(q))[..., :, 2]  # body z in space
    mhat = np.asarray(rj.quat.rotate(q0, b["I"] * w0)) / M[:, None]
    cos_t = np.einsum("ktj,kj->kt", axis, mhat)
    np.testing.assert_allclose(
        cos_t, np.cos(pr.nutation)[:, None] * np.ones_like(cos_t), atol=1e-12
    )
    perp = axis - cos_t[..., None] * mhat[:, None]
    sin_a = np.einsum("ktj,kj->kt", np.cross(perp[:, :1], perp), mhat)
    cos_a = np.einsum("ktj,ktj->kt", np.broadcast_to(perp[:, :1], perp.shape), perp)
    ang = np.unwrap(np.arctan2(sin_a, cos_a), axis=1)
    np.testing.assert_allclose(ang, pr.precession_rate[:, None] * TS, atol=1e-10)


def test_fixed_axis_rotation():
    ts = np.linspace(0.0, 3.0, 31)
    q0 = random_quat(np.random.default_rng(9), 1)[0]
    axis = np.array([1.0, -2.0, 0.5])
    n = axis / np.linalg.norm(axis)
    q = analytic.fixed_axis_rotation(axis, 0.7, ts, q0)
    expect = Rotation.from_rotvec(0.7 * ts[:, None] * n) * Rotation.from_quat(q0[[1, 2, 3, 0]])
    assert qdist(q, expect.as_quat()[:, [3, 0, 1, 2]]) < 1e-14
    q2 = analytic.fixed_axis_rotation(axis, lambda t: 0.3 * t**2, ts)
    expect2 = Rotation.from_rotvec(0.3 * ts[:, None] ** 2 * n).as_quat()[:, [3, 0, 1, 2]]
    assert qdist(q2, expect2) < 1e-14
    for bad, needle in [(np.zeros(3), "non-zero"), (np.array([np.nan, 0.0, 1.0]), "finite")]:
        with pytest.raises(ValueError, match=f"axis must be {needle}"):
            analytic.fixed_axis_rotation(bad, 0.7, ts)


# ---------------------------------------------------------------------------------------------
# differentiability, dtypes, transformations
# ---------------------------------------------------------------------------------------------


def _fd(f, x, h=1e-6):
    x = np.asarray(x, float)
    g = np.zeros_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = h
        g[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_gradients_match_finite_differences():
    """jax.grad w.r.t. inertia and omega0 of Ω(t), q(t), the first-flip time and the period,
    against central differences; finite at degenerate points."""
    ts = jnp.linspace(0.0, 25.0, 11)
    rng = np.random.default_rng(0)
    wt = jnp.asarray(rng.normal(size=(11, 3)))
    wq = jnp.asarray(rng.normal(size=(11, 4)))

    def loss(x, flip):  # x = (inertia, omega0)
        I, w = x[:3], x[3:]
        q = analytic.free_rigid_body_attitude(I, w, None, ts, check=False)
        q = q * jnp.sign(q[..., :1])
        out = jnp.sum(analytic.free_rigid_body(I, w, ts, check=False) * wt) + jnp.sum(q * wq)
        t_flip = analytic.time_of_first_flip(I, w, check=False) + 0.1 * analytic.flip_period(
            I, w, check=False
        )
        return out + flip * jnp.where(jnp.isfinite(t_flip), t_flip, 0.0)

    vg = jax.jit(jax.value_and_grad(loss))
    cases = [
        ((1.0, 2.0, 3.0, 0.3, -0.5, 0.8), 1.0),
        ((3.0, 1.0, 2.0, 0.9, 0.2, -0.1), 1.0),  # around the smallest axis
        # symmetric top: exact tie I1 = I2 (which axis is "middle" flips with the perturbation, so
        # the flip time is discontinuous there and left out)
        ((2.0, 2.0, 3.0, 0.3, 0.2, 0.5), 0.0),
    ]
    for x, flip in cases:
        g = np.asarray(vg(jnp.asarray(x), flip)[1])
        fd = _fd(lambda y, flip=flip: float(vg(jnp.asarray(y), flip)[0]), x)
        np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-6)
    # finite (though not the transverse derivative) at degenerate points: separatrix, unstable
    # and stable steady rotations, Ω = 0, equatorial rotation of a symmetric top (and at a
    # sphere, exact: test_derivatives_at_a_sphere)
    for x in [
        (3.0, 4.0, 6.0, 2.0, 0.5, 1.0),
        (2.0, 3.0, 4.0, 0.0, 1.0, 0.0),
        (2.0, 3.0, 4.0, 0.0, 0.0, 1.0),
        (2.0, 2.0, 2.0, 1.0, 2.0, 3.0),
        (1.0, 2.0, 3.0, 0.0, 0.0, 0.0),
        (2.0, 2.0, 3.0, 1.0, 0.3, 0.0),
    ]:
        g = np.asarray(vg(jnp.asarray(x), 1.0)[1])
        assert np.all(np.isfinite(g)), (x, g)


@pytest.mark.slow  # ~20 s: second derivatives of the whole closed form
def test_derivatives_at_a_sphere():
    """At a sphere Ω is constant, but not its derivatives in the moments: moving them by εa
    (A = diag a) gives Ω = Ω0 + ε t b + ε² Ω2, b = AΩ0 × Ω0 / c, Ω2 = t²/(2c) (Ab × Ω0 +
    AΩ0 × b) − t/c Ab (Euler's equations at first and second order); the attitude's derivatives:
    `test_derivatives_at_steady_rotations`."""
    c, t = 2.0, 3.0
    I, w0 = jnp.full(3, c), jnp.array([0.3, 1.0, -0.4])
    a = jnp.array([0.3, -0.7, 0.5])
    b = jnp.cross(a * w0, w0) / c
    om2 = t**2 / (2 * c) * (jnp.cross(a * b, w0) + jnp.cross(a * w0, b)) - t / c * a * b

    def omega(e, w=w0):
        return analytic.free_rigid_body(I + e * a, w, jnp.array([0.0, t]), check=False)[-1]

    @jax.jit  # (one compilation: eagerly, op by op, this takes half a minute)
    def derivatives(e):
        second = jax.jacfwd(jax.jacfwd(omega))(e)
        by_w = jax.jacfwd(lambda w: omega(e, w))(w0)
        return jax.jacfwd(omega)(e), jax.jacrev(omega)(e), second, by_w

    d1, d1_rev, d2, by_w = derivatives(0.0)
    np.testing.assert_allclose(d1, t * b, rtol=0, atol=1e-14)
    np.testing.assert_allclose(d1_rev, d1, rtol=0, atol=1e-14)
    np.testing.assert_allclose(d2, 2 * om2, rtol=0, atol=1e-13)
    np.testing.assert_allclose(by_w, np.eye(3), rtol=0, atol=1e-14)


@pytest.mark.slow  # compile-heavy (jacfwd and jacrev of the whole closed form): 28 s
def test_derivatives_at_steady_rotations():
    """A steady rotation on the separatrix (about the middle axis; in a symmetric top's plane of
    equal moments) is a rest point of Euler's equations, as is any rotation of a sphere: Ω stays
    Ω0 and q = q0 ∘ exp(tΩ0), but the derivatives in Ω0 and the moments do not (they grow like
    cosh λt about the middle axis). They match central differences of DOP853's motion, in the
    moments by forward mode and in Ω0 by reverse mode; far out (λt ~ 7000) they stay finite."""
    cases = [  # (moments, Ω0): the middle axis, an oblate and a prolate top's equator, a sphere
        ([1.0, 2.0, 2.5], [0.0, 1.5, 0.0]),
        ([1.0, 1.0, 2.0], [1.0, 0.7, 0.0]),
        ([2.0, 1.0, 1.0], [0.0, 1.0, 0.5]),
        ([2.0, 2.0, 2.0], [0.3, 1.0, -0.4]),
    ]
    I, w0 = (jnp.array(x) for x in zip(*cases, strict=True))
    q0, ts, h = jnp.array([0.6, 0.0, 0.8, 0.0]), jnp.array([1.3, 1e4]), 1e-6

    def flow(i, w, t):
        return jnp.concatenate(analytic.free_body_flow(i, w, q0, t))

    def at_times(f):
        return jax.vmap(jax.vmap(f, (None, None, 0)), (0, 0, None))  # cases × times

    @jax.jit  # one compilation for the four cases and two times
    def derivatives(I, w0):
        d_i = at_times(jax.jacfwd(flow, argnums=0))(I, w0, ts)
        d_w = at_times(jax.jacrev(flow, argnums=1))(I, w0, ts)
        return d_i, d_w, at_times(flow)(I, w0, ts)

    d_i, d_w, val = derivatives(I, w0)
    t = float(ts[0])
    spin = Rotation.from_quat(np.roll(q0, -1)) * Rotation.from_rotvec(t * np.asarray(w0))
    spin_np = scalar_first(spin)
    np.testing.assert_array_equal(val[..., :3], np.broadcast_to(w0[:, None], (4, 2, 3)))
    np.testing.assert_allclose(val[:, 0, 3:], spin_np, rtol=0, atol=1e-15)
    assert np.all(np.isfinite(d_i)) and np.all(np.isfinite(d_w))
    for k, (i, w) in enumerate(cases):

        def motion(x, near=spin_np[k]):
            om, q = ivp(np.asarray(x[:3]), x[3:], [0.0, t], q0=q0)
            return np.concatenate([om[-1], q[-1] * np.sign(q[-1] @ near)])

        ref = fd_jacobian(motion, np.concatenate([i, w]), h)
        np.testing.assert_allclose(d_i[k, 0], ref[:, :3], rtol=0, atol=1e-8, err_msg=str(k))
        np.testing.assert_allclose(d_w[k, 0], ref[:, 3:], rtol=0, atol=1e-8, err_msg=str(k))
    assert d_w[0, 0, 0, 0] > 1.4  # the middle axis: cosh λt = 1.405, not 1


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_float32_and_vmap(batch):
    a = batch["all"]
    f32 = [np.asarray(x, np.float32) for x in (a["I"], a["w"], a["q0"], T_ALL)]
    o32 = analytic.free_rigid_body(f32[0], f32[1], f32[3], check=False)
    q32 = analytic.free_rigid_body_attitude(*f32, check=False)
    assert o32.dtype == jnp.float32 and q32.dtype == jnp.float32
    assert analytic.ellipj(np.float32(0.3), np.float32(0.9))[0].dtype == jnp.float32
    # reference: float64 from the same (rounded) inputs; the error is ~ eps32 · λt
    ref = [np.asarray(x, np.float64) for x in f32]
    o64 = np.asarray(analytic.free_rigid_body(ref[0], ref[1], ref[3], check=False))
    scale = np.maximum(np.max(np.abs(o64), axis=(1, 2), keepdims=True), 1e-30)
    sep = np.flatnonzero(np.isin(np.arange(len(o64)), _rows("separatrix", "near_separatrix")))
    ok = np.setdiff1d(np.arange(len(o64)), sep)  # rounding moves those off the separatrix
    assert np.max((np.abs(o32 - o64) / scale)[ok][:, SHORT]) < 1e-4
    q64 = np.asarray(analytic.free_rigid_body_attitude(*ref, check=False))
    assert qdist(q32[ok][:, SHORT], q64[ok][:, SHORT]) < 1e-4
    # jit(vmap) agrees with the batched call; batch dims broadcast
    fn = jax.jit(jax.vmap(lambda i, w: analytic.free_rigid_body(i, w, T_ALL, check=False)))
    np.testing.assert_allclose(fn(a["I"], a["w"]), a["om"], atol=1e-13)
    b = batch["generic"]
    assert analytic.free_rigid_body(b["I"][0], b["w"][:3, None], T_ALL[:2], check=False).shape == (
        3,
        1,
        2,
        3,
    )
    assert analytic.free_rigid_body(b["I"][0], b["w"][0], 1.5, check=False).shape == (3,)


def _rows(*names):
    """Row indices of the named case groups in batch["all"]."""
    start, out = 0, []
    for k, (I, _) in CASES.items():
        if k in names:
            out.extend(range(start, start + len(I)))
        start += len(I)
    return np.array(out, int)
