"""`analytic.time_of_first_flip`: the first sign change of the body Ω component along the
initially dominant axis (∞ when the polhode encircles that axis), against `rigidjax.simulate`
over 200 initial states in every regime, plus ties, degenerate inputs, gradients and batching.

Everything is evaluated in a few batched calls (one `simulate` for all 200 states)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax import analytic

HORIZON = 3.0  # in periods of Ω (each state is scaled to period 1; separatrix: |λ| t ≤ 10)
TS = np.linspace(0.0, HORIZON, 6001)
SEP_LAM = 10.0 / HORIZON
MAX_TURNS = 25.0
N_PAD = 256  # every closed-form call is padded to this batch size: one compilation each


def _padded(fn, I, w):
    """`fn(I, w)` for `(n, 3)` inputs, n ≤ N_PAD, through one padded `(N_PAD, 3)` call."""
    n = len(I)
    Ip = np.concatenate([np.asarray(I, float), np.ones((N_PAD - n, 3))])
    wp = np.concatenate([np.asarray(w, float), np.ones((N_PAD - n, 3))])
    return jax.tree_util.tree_map(lambda a: np.asarray(a)[:n], fn(Ip, wp))


def _flip(I, w):
    return _padded(analytic.time_of_first_flip, I, w)


def _params(I, w):
    return _padded(analytic.free_rigid_body_parameters, I, w)


def _random_states():
    """200 random (inertia, Ω0, kind) in every regime, moments in random order. Candidates that
    spin more than MAX_TURNS turns per period of Ω are skipped (they cost `simulate` the most
    steps: the attitude is integrated too)."""
    rng = np.random.default_rng(31)

    def permuted(I, w):
        perm = np.argsort(rng.uniform(size=I.shape), axis=1)
        return np.take_along_axis(I, perm, 1), np.take_along_axis(w, perm, 1)

    def keep(I, w, n):
        par = _params(I, w)
        turns = np.linalg.norm(w, axis=1) * par.period / (2 * np.pi)
        ok = np.flatnonzero(turns <= MAX_TURNS)[:n]
        assert len(ok) == n
        return permuted(I[ok], w[ok])

    # generic: random moments in [1, 2] (triangle inequality holds), Ω0 in random directions
    generic = keep(rng.uniform(1.0, 2.0, (N_PAD, 3)), rng.normal(size=(N_PAD, 3)), 113)
    # near (not on) the separatrix I1(I2 − I1)Ω1² = I3(I3 − I2)Ω3² (sorted moments): Ω3 off by a
    # relative ±1e-6..1e-2 (both polhode families), Ω2 of every size, random signs
    Is = np.sort(rng.uniform(1.0, 2.0, (N_PAD, 3)), axis=1)
    w1 = rng.normal(size=N_PAD)
    w2 = rng.normal(size=N_PAD) * np.array([0.1, 1.0, 3.0])[np.arange(N_PAD) % 3]
    r = np.sqrt(Is[:, 0] * (Is[:, 1] - Is[:, 0]) / (Is[:, 2] * (Is[:, 2] - Is[:, 1])))
    off = 10 ** rng.uniform(-6, -2, N_PAD) * np.where(np.arange(N_PAD) % 2, 1, -1)
    ws = np.stack([w1, w2, np.abs(w1) * r * (1 + off)], 1) * rng.choice([-1, 1], (N_PAD, 3))
    near = keep(Is, ws, 50)
    # symmetric tops (oblate, prolate): dominant along the symmetry axis or transverse
    It = np.where(np.arange(N_PAD)[:, None] % 2, [[1.5, 1.5, 2.5]], [[2.0, 2.0, 1.2]])
    wt = rng.normal(size=(N_PAD, 3))
    wt[:, 2] *= np.where(np.arange(N_PAD) % 4 < 2, 0.5, 3.0)
    sym = keep(It, wt, 24)
    # exact separatrix (I = (3, 4, 6)): the middle component dominant, approaching zero or not;
    # the sech component dominant
    signs = np.array([(1, 1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, -1), (-1, -1, -1), (1, -1, -1)])
    sep = permuted(
        np.full((7, 3), [3.0, 4.0, 6.0]),
        np.concatenate([signs * np.array([0.2, 1.0, 0.1]), [[2.0, 0.5, 1.0]]]),
    )
    # steady rotations about each axis, an equatorial symmetric-top rotation, a sphere, Ω = 0
    steady = permuted(
        np.array([[1.0, 1.6, 2.1]] * 3 + [[2.0, 2.0, 3.0], [2.0, 2.0, 2.0], [1.0, 1.6, 2.1]]),
        np.concatenate([np.eye(3) * 1.3, [[0.6, -0.8, 0.0], [0.3, -1.0, 2.0], [0.0, 0.0, 0.0]]]),
    )
    groups = dict(
        generic=generic, near_separatrix=near, symmetric=sym, separatrix=sep, steady=steady
    )
    I = np.concatenate([g[0] for g in groups.values()])
    w = np.concatenate([g[1] for g in groups.values()])
    kind = np.concatenate([[k] * len(g[0]) for k, g in groups.items()])
    assert len(I) == 200
    return I, w, kind


# Ties and extremes (moments as given, all polhodes around the largest axis):
TIES_I = np.array(
    [[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0]]
)
TIES_W = np.array(
    [
        [1.0, -1.0, 0.9],  # |Ω1| = |Ω2|: axis 1 (the minor one, cn type)
        [0.1, 1.0, -1.0],  # |Ω2| = |Ω3|: axis 2 (the middle one, sn type)
        [1.0, 0.1, -1.0],  # |Ω1| = |Ω3|: axis 1, the one the polhode encircles: ∞
        [0.0, 1.0, 0.3],  # sn at its extreme: the first zero a quarter period later
        [1.0, 0.0, 0.7],  # cn at its extreme: likewise
    ]
)
TIES_AXIS = np.array([0, 1, 0, 1, 0])


def _scaled(I, w):
    """Ω0 scaled so that every periodic state has period 1 (separatrix: |λ| = SEP_LAM)."""
    par = _params(I, w)
    period, lam = par.period, par.lam
    sep = np.where(lam > 0, SEP_LAM / np.maximum(lam, 1e-300), 1.0)
    return w * np.where(np.isfinite(period), period, sep)[:, None]


def _first_sign_change(ts, x):
    """First time the samples x(ts) leave the sign of x[0], by linear interpolation (∞: never)."""
    out = np.full(x.shape[0], np.inf)
    for k in range(x.shape[0]):
        i = np.flatnonzero(np.sign(x[k]) != np.sign(x[k, 0]))
        if i.size:
            i = i[0]
            a, b = x[k, i - 1], x[k, i]
            out[k] = ts[i - 1] + (ts[i] - ts[i - 1]) * a / (a - b)
    return out


@pytest.fixture(scope="module")
def flips():
    """The 200 random states and the ties, scaled; closed form and `simulate` (one call each)."""
    I, w, kind = _random_states()
    I = np.concatenate([I, TIES_I])
    w = _scaled(I, np.concatenate([w, TIES_W]))
    kind = np.concatenate([kind, ["ties"] * len(TIES_I)])
    got = _flip(I, w)
    traj = rj.simulate(rj.RigidBody(I, check=False), w, None, TS, rtol=1e-10, atol=1e-10)
    om = np.asarray(traj.omega)
    d = np.argmax(np.abs(w), axis=1)
    sim = _first_sign_change(TS, om[np.arange(len(w)), :, d])
    return dict(I=I, w=w, kind=kind, d=d, got=got, sim=sim, par=_params(I, w))


def test_regimes_covered(flips):
    """The 200 states cover both polhode families with the dominant axis the minor, middle and
    major one, the neighbourhood of the separatrix on both sides, the separatrix itself (with and
    without a crossing), symmetric tops with a finite and an infinite answer, and steady spins."""
    f = flips
    regime = np.asarray(f["par"].regime)
    role = np.argsort(np.argsort(f["I"], axis=1), axis=1)[np.arange(len(f["d"])), f["d"]]
    kind = f["kind"]
    asym = (kind != "symmetric") & (kind != "ties")
    for r in (-1, 1):
        for axis in (0, 1, 2):
            assert np.sum(asym & (regime == r) & (role == axis)) >= 5, (r, axis)
    near = kind == "near_separatrix"
    k1 = 1 - np.asarray(f["par"].k2)
    assert np.all((k1[near] > 0) & (k1[near] < 0.1)) and np.min(k1[near]) < 1e-5
    assert np.sum(near & (regime == 1)) >= 20 and np.sum(near & (regime == -1)) >= 20
    sep = kind == "separatrix"
    assert np.all(regime[sep] == 0)
    assert np.any(np.isfinite(f["got"][sep])) and np.any(np.isinf(f["got"][sep]))
    sym = kind == "symmetric"
    assert np.any(np.isfinite(f["got"][sym])) and np.any(np.isinf(f["got"][sym]))
    # stable spins (dominant axis = the axis the polhode encircles) give ∞
    stable = asym & (regime != 0) & (role == np.where(regime == 1, 2, 0))
    assert stable.sum() >= 10 and np.all(np.isinf(f["got"][stable]))
    assert np.all(np.isinf(f["got"][kind == "steady"]))


def test_matches_simulate(flips):
    """Finite exactly where the simulated component changes sign within 3 periods (∞ exactly
    where it does not), and then equal to the interpolated first sign change."""
    f = flips
    got, sim = f["got"], f["sim"]
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(sim))
    fin = np.isfinite(got)
    assert fin.sum() >= 80 and (~fin).sum() >= 80
    np.testing.assert_allclose(got[fin], sim[fin], rtol=1e-6)  # measured: 5e-8
    periodic = fin & (np.asarray(f["par"].regime) != 0)
    assert np.all(got[periodic] <= 0.5 * (1 + 1e-12))  # within half a period (period 1)


def test_ties_and_extremes(flips):
    """Ties go to the axis listed first; at an extreme of a cn or sn component the first zero is
    a quarter period away (exactly)."""
    f = flips
    ties = f["kind"] == "ties"
    np.testing.assert_array_equal(f["d"][ties], TIES_AXIS)  # the rule, as NumPy's argmax
    assert np.all(np.asarray(f["par"].regime)[ties] == 1)
    got = f["got"][ties]
    assert np.all(np.isfinite(got[[0, 1, 3, 4]])) and np.isinf(got[2])
    np.testing.assert_allclose(got[3:], np.asarray(f["par"].period)[ties][3:] / 4, rtol=1e-13)


def test_symmetric_top_closed_form():
    """Symmetric top I1 = I2: Ω1 + iΩ2 = R e^{i(α0 + νt)}, ν = Ω3 (I3 − I1)/I1 (THEORY §6), so
    a dominant transverse component first vanishes when α0 + νt reaches the next zero of cos
    (Ω1) or sin (Ω2); a dominant symmetry-axis component never does."""
    rng = np.random.default_rng(5)
    w = rng.normal(size=(40, 3)) * np.array([1.0, 1.0, 0.8])
    I = np.where(np.arange(40)[:, None] % 2, [[2.0, 2.0, 3.0]], [[3.0, 3.0, 1.5]])
    got = _flip(I, w)
    nu = w[:, 2] * (I[:, 2] - I[:, 0]) / I[:, 0]
    alpha = np.arctan2(w[:, 1], w[:, 0])
    d = np.argmax(np.abs(w), axis=1)
    shift = np.where(d == 0, 0.5 * np.pi, 0.0)  # zeros of cos at π/2 + nπ, of sin at nπ
    # angle still to go, in the direction of rotation, to the next zero: in (0, π]
    left = np.mod(-np.sign(nu) * (alpha - shift), np.pi)
    left = np.where(left == 0, np.pi, left)
    ref = np.where(d == 2, np.inf, left / np.abs(nu))
    assert np.any(d == 2) and np.any(d < 2)
    np.testing.assert_allclose(got, ref, rtol=1e-12)


def test_gradients_finite_differences():
    """jax.grad of the flip time w.r.t. (inertia, Ω0) against central differences (cn-type and
    sn-type dominant components in both regimes, near the separatrix, a symmetric top), finite on
    the separatrix; zero where the time is ∞, also at degenerate points. jit(vmap) agrees with
    the batched call."""
    x = np.array(
        [
            [1.0, 2.0, 2.5, 1.0, 0.2, 0.95],  # cn type (minor axis), around the major axis
            [1.0, 2.0, 2.5, 0.3, 1.0, 0.6],  # sn type (middle axis), around the major axis
            [2.2, 2.0, 1.0, 1.0, 0.3, 0.95],  # cn type (major axis), around the minor axis
            [3.0, 4.0, 6.0, 2.0, 0.5, 1.0 + 1e-4],  # near the separatrix, cn type
            [2.0, 2.0, 3.0, 1.0, 0.3, 0.5],  # symmetric top, transverse dominant
            [3.0, 4.0, 6.0, -0.2, 1.0, 0.1],  # on the separatrix, tanh component
        ]
    )
    y = np.array(  # ∞
        [
            [1.0, 2.0, 2.5, 0.3, -0.5, 0.8],  # around the major axis, which dominates
            [3.0, 4.0, 6.0, 2.0, 0.5, 1.0],  # separatrix, sech component dominant
            [2.0, 3.0, 4.0, 0.0, 1.0, 0.0],  # steady rotations
            [2.0, 3.0, 4.0, 0.0, 0.0, 1.0],
            [2.0, 2.0, 2.0, 1.0, 2.0, 3.0],  # sphere
            [1.0, 2.0, 3.0, 0.0, 0.0, 0.0],  # Ω = 0
        ]
    )
    f = lambda z: analytic.time_of_first_flip(z[..., :3], z[..., 3:])  # noqa: E731
    xy = np.concatenate([x, y])
    val, g = jax.jit(jax.vmap(jax.value_and_grad(f)))(jnp.asarray(xy))
    val, g = np.asarray(val), np.asarray(g)
    np.testing.assert_array_equal(val, _flip(xy[:, :3], xy[:, 3:]))
    assert np.all(np.isfinite(val[:6])) and np.all(np.isinf(val[6:]))
    h = 1e-7  # near the separatrix the curvature is large
    z = np.concatenate([x[:, None] + np.eye(6) * h, x[:, None] - np.eye(6) * h]).reshape(-1, 6)
    t = _flip(z[:, :3], z[:, 3:]).reshape(2, 6, 6)
    fd = (t[0] - t[1]) / (2 * h)
    np.testing.assert_allclose(g[:5], fd[:5], rtol=1e-6, atol=1e-6)
    # on the separatrix: finite, exact along it (Ω2 does not enter I1(I2 − I1)Ω1² = I3(I3 − I2)Ω3²)
    assert np.all(np.isfinite(g[5]))
    np.testing.assert_allclose(g[5, 4], fd[5, 4], rtol=1e-6)
    np.testing.assert_array_equal(g[6:], 0.0)


def test_broadcasting_float32():
    """Batch dims broadcast; float32 in, float32 out (≈ the float64 answer)."""
    I = np.array([[1.0, 2.0, 2.5], [2.5, 1.0, 2.0]])
    w = np.array([[[1.0, 0.2, 0.95]], [[0.3, 1.0, 0.6]], [[0.2, 0.1, 1.0]]])  # (3, 1, 3)
    t32 = analytic.time_of_first_flip(I.astype(np.float32), w.astype(np.float32))
    assert t32.shape == (3, 2) and t32.dtype == jnp.float32
    Ib, wb = (a.reshape(-1, 3) for a in np.broadcast_arrays(I, w))
    ref = _flip(Ib.astype(np.float32), wb.astype(np.float32)).reshape(3, 2)
    assert np.any(np.isfinite(ref)) and np.any(np.isinf(ref))
    np.testing.assert_allclose(t32, ref, rtol=1e-4)
