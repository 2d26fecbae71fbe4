"""`rigidjax.observables` against independent references: SciPy DOP853 trajectories (nutation,
flip time; drifts recomputed in NumPy/SciPy), closed forms (`analytic.time_of_first_flip`, the
regular precession of a symmetric top, a body spun up or braked about a principal axis), under
`jit`, `vmap` (over `simulate`) and with leading batch dimensions, and derivatives (`jax.jvp`
through `simulate`, `jax.grad`/`jacrev`) against central finite differences and analytic ones.

Compilations are few (the whole file is one `vmap` of `jvp` through `simulate` plus a handful of
small programs); the reverse-mode derivative through `simulate` is the one `slow` test."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax import observables as ob
from tests.helpers import rigid_body_dop853

TS = np.linspace(0.0, 16.0, 321)  # one set of output times for every simulate call
DT = TS[1] - TS[0]
Q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])

# (inertia, Ω0): the tennis racket (flips at t ≈ 14.1), a steady spin about a principal axis,
# symmetric tops spun mostly about the symmetry axis (oblate; prolate with Ω3 < 0, so that the
# angle θ between the axis and M exceeds π/2) or transversally (a finite flip time), generic bodies
STATES = [
    ((1.0, 2.0, 2.5), (0.05, 1.0, 0.05)),
    ((1.0, 2.0, 2.5), (0.0, 0.0, 1.3)),
    ((1.5, 1.5, 2.5), (0.3, 0.1, 2.0)),
    ((2.0, 2.0, 1.2), (0.2, -0.3, -1.5)),
    ((1.5, 1.5, 2.5), (1.0, 0.2, 0.3)),
    ((1.3, 1.7, 1.9), (0.5, -1.0, 0.8)),
    ((1.9, 1.2, 1.6), (-1.1, 0.4, 0.7)),
    ((1.1, 1.4, 2.0), (0.2, 0.3, -1.2)),
]
INERTIA = np.array([s[0] for s in STATES])
OMEGA0 = np.array([s[1] for s in STATES])
SYMMETRIC_AXIAL = [2, 3]
NUT, FLIP, ENERGY, MOMENTUM = range(4)


@jax.jit
def _all(body, traj):
    """The four observables of a (batched) trajectory, stacked last, in one compiled call."""
    return jnp.stack(
        [
            ob.max_nutation(traj),
            ob.first_flip_time(traj),
            ob.energy_drift(body, traj),
            ob.momentum_drift(body, traj),
        ],
        axis=-1,
    )


# ------------------------------------------------------------- independent references (NumPy)


def _dominant(w0):
    return int(np.argmax(np.abs(w0)))


def _rotate(q, v):
    """P(q) v by SciPy (q scalar-first)."""
    return Rotation.from_quat(np.asarray(q)[..., [1, 2, 3, 0]]).apply(v)


def _ref_nutation(q, w0):
    n = _rotate(q, np.eye(3)[_dominant(w0)])
    angle = np.arctan2(np.linalg.norm(np.cross(n[0], n), axis=-1), n @ n[0])
    return np.max(angle)


def _ref_flip(ts, w):
    """The first sign change of Ω_d, d the dominant axis of Ω(t0), by a plain loop."""
    d = _dominant(w[0])
    c = w[:, d] * np.sign(w[0, d])
    for i in range(len(ts) - 1):
        if c[i + 1] < 0:
            return ts[i] + (ts[i + 1] - ts[i]) * c[i] / (c[i] - c[i + 1])
    return np.inf


def _ref_drifts(I, w, q):
    T = 0.5 * np.sum(I * w * w, axis=-1)
    M = _rotate(q, I * w)
    return np.max(np.abs(T / T[0] - 1)), np.max(np.linalg.norm(M - M[0], axis=-1)) / np.linalg.norm(
        M[0]
    )


# ------------------------------------------------------------- vmap(jvp(simulate)), tight


def _simulated(x):
    body = rj.RigidBody(x[:3])
    traj = rj.simulate(body, x[3:], Q0, TS, rtol=1e-12, atol=1e-12, adjoint=diffrax.ForwardMode())
    return _all(body, traj), traj.omega, traj.quat


@pytest.fixture(scope="module")
def sweep():
    """Every state through ONE compiled `jit(vmap(jvp(observables ∘ simulate)))` along random
    directions V in (I, Ω0), and at X ± hV for central finite differences."""
    f = jax.jit(jax.vmap(lambda x, v: jax.jvp(_simulated, (x,), (v,))))
    X = np.concatenate([INERTIA, OMEGA0], axis=1)
    V = np.random.default_rng(7).normal(size=X.shape)
    (vals, omega, quat), (dvals, _, _) = f(X, V)
    h = 1e-5
    fd = (f(X + h * V, V)[0][0] - f(X - h * V, V)[0][0]) / (2 * h)
    return dict(
        X=X,
        V=V,
        h=h,
        vals=np.asarray(vals),
        dvals=np.asarray(dvals),
        fd=np.asarray(fd),
        omega=np.asarray(omega),
        quat=np.asarray(quat),
    )


@pytest.fixture(scope="module")
def scipy_refs():
    return [rigid_body_dop853(I, w, Q0, TS) for I, w in STATES]


def test_nutation_against_scipy(sweep, scipy_refs):
    nut = sweep["vals"][:, NUT]
    ref = [_ref_nutation(q, w[0]) for w, q in scipy_refs]
    np.testing.assert_allclose(nut, ref, rtol=1e-7, atol=1e-9)
    assert nut[0] > 2.0  # the racket's intermediate axis turns over
    assert nut[1] < 1e-12  # steady rotation about a principal axis


def test_nutation_symmetric_top_closed_form(sweep):
    """Regular precession: the symmetry axis n(t) turns about M at μ = |M|/I1 at the constant
    angle θ, tan θ = I1 |Ω⊥| / (I3 Ω3): cos ∠(n(t), n(0)) = cos²θ + sin²θ cos μt, largest
    (2θ, or 2π − 2θ for θ > π/2) after half a precession period, which TS covers."""
    for k in SYMMETRIC_AXIAL:
        (I1, _, I3), w = INERTIA[k], OMEGA0[k]
        perp = np.hypot(w[0], w[1])
        theta = np.arctan2(I1 * perp, I3 * w[2])
        mu = np.hypot(I1 * perp, I3 * w[2]) / I1
        assert mu * TS[-1] > 2 * np.pi
        cos_g = np.cos(theta) ** 2 + np.sin(theta) ** 2 * np.cos(mu * TS)
        nut = sweep["vals"][k, NUT]
        np.testing.assert_allclose(nut, np.max(np.arccos(cos_g)), rtol=1e-8)
        np.testing.assert_allclose(nut, min(2 * theta, 2 * np.pi - 2 * theta), atol=1e-2)
        if k == 3:  # the prolate top, θ > π/2: the second branch
            assert 2 * theta > np.pi


def test_flip_time_against_scipy_and_closed_form(sweep, scipy_refs):
    flip = sweep["vals"][:, FLIP]
    ref = np.array([_ref_flip(TS, w) for w, _ in scipy_refs])
    closed = np.asarray(rj.analytic.time_of_first_flip(INERTIA, OMEGA0))
    finite = np.isfinite(closed)
    # flips (the racket, the transverse symmetric top, generic bodies) and never-flips (the
    # steady spin, the axial symmetric tops) both occur
    assert finite.sum() >= 3 and (~finite).sum() >= 3
    np.testing.assert_array_equal(np.isfinite(flip), finite)
    np.testing.assert_array_equal(np.isfinite(ref), finite)
    np.testing.assert_allclose(flip[finite], ref[finite], rtol=1e-8)
    # linear interpolation between samples DT apart: O(DT²) in general (here O(DT³))
    np.testing.assert_allclose(flip[finite], closed[finite], rtol=0, atol=DT**2 / 10)
    np.testing.assert_allclose(flip[0], 14.1, atol=0.01)


def test_drifts_against_numpy(sweep):
    ref = np.array(
        [
            _ref_drifts(I, w, q)
            for I, w, q in zip(INERTIA, sweep["omega"], sweep["quat"], strict=True)
        ]
    )
    got = sweep["vals"][:, [ENERGY, MOMENTUM]]
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-14)
    assert np.all(got < 1e-9)  # a tight torque-free solve conserves both


def test_derivatives_through_simulate_against_finite_differences(sweep):
    """`jvp` (forward mode through the adaptive solve) of nutation and flip time against central
    differences of the same compiled program, and the flip time's against central differences
    of the closed form (`analytic.time_of_first_flip`). The drifts at this tolerance are rounding
    noise: their derivatives are checked in the closed-form and the slow tests."""
    dvals, fd = sweep["dvals"], sweep["fd"]
    assert np.all(np.isfinite(dvals))
    # the steady spin (row 1) is a kink: its nutation grows like |perturbation|
    smooth = np.arange(len(STATES)) != 1
    np.testing.assert_allclose(dvals[smooth, NUT], fd[smooth, NUT], rtol=1e-5, atol=1e-7)
    finite = np.isfinite(sweep["vals"][:, FLIP])
    assert np.all(dvals[~finite, FLIP] == 0)
    np.testing.assert_allclose(dvals[finite, FLIP], fd[finite, FLIP], rtol=1e-5)
    X, V, h = sweep["X"], sweep["V"], sweep["h"]

    def closed(X):
        return np.asarray(rj.analytic.time_of_first_flip(X[:, :3], X[:, 3:]))

    fd_closed = (closed(X + h * V)[finite] - closed(X - h * V)[finite]) / (2 * h)
    np.testing.assert_allclose(dvals[finite, FLIP], fd_closed, rtol=1e-3)


def test_batch_dimensions_match_vmap(sweep):
    """A batched trajectory (`omega (N, T, 3)`, a batch of bodies; `ts (T,)` as from a batched
    `simulate`, or `(N, T)` as from a vmapped one) gives the per-member values of vmap. Three
    more members: Ω1 touches 0 and comes back (not a flip), then changes sign between samples 3
    and 4; the same with a negative initial component; NaN states (a failed solve with
    `throw=False`) give NaN, not an error."""
    n = len(STATES)
    w = np.zeros((len(TS), 3))
    w[:, 0] = -1.0
    w[:4, 0] = [1.0, 0.5, 0.0, 0.5]
    w[0, 1] = 0.1
    nan = sweep["omega"][0].copy()
    nan[3] = np.nan
    omega = jnp.asarray(np.concatenate([sweep["omega"], [w, -w, nan]]))
    quat = np.concatenate([sweep["quat"], np.repeat(sweep["quat"][:1], 3, 0)])
    quat[-1, 3] = np.nan
    quat = jnp.asarray(quat)
    body = rj.RigidBody(np.concatenate([INERTIA, np.repeat(INERTIA[:1], 3, 0)]))
    traj = rj.Trajectory(omega, quat, ts=jnp.asarray(TS), stats={})
    got = np.asarray(_all(body, traj))
    assert got.shape == (n + 3, 4)
    np.testing.assert_allclose(got[:n], sweep["vals"], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got[n : n + 2, FLIP], TS[3] + DT * 0.5 / 1.5, rtol=1e-14)
    assert np.all(np.isnan(got[n + 2]))
    # ts (N, T): the layout of a Trajectory returned by jax.vmap(simulate)
    traj_b = eqx.tree_at(lambda t: t.ts, traj, jnp.broadcast_to(traj.ts, omega.shape[:-1]))
    np.testing.assert_allclose(jax.jit(ob.first_flip_time)(traj_b), got[:, FLIP], rtol=1e-14)


# ------------------------------------------------------------- a principal axis spun up or braked

TS_SPIN = np.linspace(0.0, 4.0, 41)


def _spin(x):
    """Rotation about the fixed principal axis e3 of I = (1, 2, I3) under a constant torque K
    along it, x = (w, K, I3): `Ω3 = w + K t / I3`, angle `w t + K t²/(2 I3)`."""
    w, K, I3 = x[0], x[1], x[2]
    ts = jnp.asarray(TS_SPIN)
    Om = w + K * ts / I3
    phi = w * ts + K * ts**2 / (2 * I3)
    zero = jnp.zeros_like(ts)
    omega = jnp.stack([zero, zero, Om], axis=-1)
    q = jnp.stack([jnp.cos(phi / 2), zero, zero, jnp.sin(phi / 2)], axis=-1)
    return rj.RigidBody(jnp.stack([1.0, 2.0, I3])), rj.Trajectory(omega, q, ts=ts, stats={})


@jax.jit
def _spin_values_and_jacobian(x):
    f = lambda x: _all(*_spin(x))  # noqa: E731
    return f(x), jax.jacrev(f)(x)


def test_spin_closed_forms_and_gradients():
    """Ω3 is linear in t, so the interpolated flip time is exact: `t* = −w I3/K`; the momentum
    `M = I3 Ω3 e3` (space) gives `max|M − M0|/|M0| = |K| t_end/(I3 |w|)`; the energy drift is
    `|Ω3²/w² − 1|` at the sample where it is largest; the nutation is 0. Their gradients
    (`jacrev`) against the derivatives of these formulas and central finite differences. A
    steady rotation (K = 0: nutation and drifts exactly 0 at every sample) and Ω = 0 (no flip,
    no division by 0) have finite gradients."""
    x = np.array([1.5, -1.2, 2.5])  # braked: flips at t* = 3.125
    rows = np.array([x, [1.5, -0.9, 2.5], [1.3, 0.0, 2.5], [0.0, 0.0, 2.5]])
    vals, jac = (np.stack(a) for a in zip(*map(_spin_values_and_jacobian, rows), strict=True))
    assert np.all(np.isfinite(jac))
    assert np.isinf(vals[1, FLIP])  # braked less: t* ≈ 4.17 comes after TS_SPIN
    np.testing.assert_array_equal(vals[2:], [[0, np.inf, 0, 0]] * 2)

    w, K, I3 = x
    t1 = TS_SPIN[-1]
    Om = w + K * TS_SPIN / I3
    dev = Om**2 / w**2 - 1
    j = np.argmax(np.abs(dev))
    assert vals[0, NUT] < 1e-15 and np.all(jac[0, NUT] == 0)
    np.testing.assert_allclose(vals[0, FLIP], -w * I3 / K, rtol=1e-14)
    np.testing.assert_allclose(vals[0, ENERGY], np.abs(dev[j]), rtol=1e-13)
    np.testing.assert_allclose(vals[0, MOMENTUM], -K * t1 / (I3 * w), rtol=1e-13)

    np.testing.assert_allclose(jac[0, FLIP], [-I3 / K, w * I3 / K**2, -w / K], rtol=1e-12)
    tj = TS_SPIN[j]
    dOm = np.array([1.0, tj / I3, -K * tj / I3**2])
    want = np.sign(dev[j]) * (2 * Om[j] * dOm / w**2 - np.array([2 * Om[j] ** 2 / w**3, 0, 0]))
    np.testing.assert_allclose(jac[0, ENERGY], want, rtol=1e-12)
    np.testing.assert_allclose(
        jac[0, MOMENTUM], [K * t1 / (I3 * w**2), -t1 / (I3 * w), K * t1 / (I3**2 * w)], rtol=1e-12
    )

    # central differences, through the same compiled program
    h = 1e-6
    v = np.array([_spin_values_and_jacobian(x + s * h * e)[0] for s in (1, -1) for e in np.eye(3)])
    fd = (v[:3] - v[3:]) / (2 * h)  # fd[i, k] = ∂ observable k / ∂ x_i
    np.testing.assert_allclose(fd.T, jac[0], rtol=1e-7, atol=1e-9)


# ------------------------------------------------------------- reverse mode through simulate


@pytest.mark.slow
def test_vmap_grad_through_simulate():
    """`jit(vmap(value_and_grad(observable ∘ simulate)))` with respect to (I, Ω0), one member per
    observable, fixed-step RK4 (so that finite differences see a smooth function and the drifts
    are the RK4 error, not rounding): the gradients match central finite differences of the same
    compiled values along random directions; the flip time's matches the closed form's.
    (~20 s: compiling reverse mode through the solve.)"""
    # the racket (turns over and flips); generic bodies spun 3× faster for the drifts, so that
    # the RK4 error (∝ (|Ω| DT)⁴, ~1e-8..1e-6) is far above rounding
    rows = [0, 0, 5, 6]
    speed = np.array([1.0, 1.0, 3.0, 3.0])[:, None]
    opts = dict(
        solver=rj.RK4(),
        stepsize_controller=diffrax.ConstantStepSize(),
        dt0=DT,
        max_steps=2,  # one step per output interval; DirectAdjoint compiles fastest at this size
        adjoint=diffrax.DirectAdjoint(),
    )

    def obs(x, k):
        body = rj.RigidBody(x[:3])
        return _all(body, rj.simulate(body, x[3:], Q0, TS, **opts))[k]

    f = jax.jit(jax.vmap(jax.value_and_grad(obs)))
    X = jnp.asarray(np.concatenate([INERTIA[rows], speed * OMEGA0[rows]], axis=1))
    k = jnp.arange(4)
    vals, grads = f(X, k)
    assert np.all(np.isfinite(vals)) and np.all(np.isfinite(grads))
    assert np.all((vals[2:] > 1e-9) & (vals[2:] < 1e-4))  # RK4 drifts: small, not rounding
    V = jax.random.normal(jax.random.PRNGKey(0), X.shape)
    # steps: small for the angle and the time, larger for the drifts (small values whose
    # rounding is ~1e-16; the maximum of an oscillating error over the samples)
    h = jnp.array([1e-6, 1e-6, 1e-4, 1e-4])[:, None]
    fd = (f(X + h * V, k)[0] - f(X - h * V, k)[0]) / (2 * h[:, 0])
    np.testing.assert_allclose(np.sum(grads * V, axis=1), fd, rtol=1e-4)
    g_closed = jax.grad(lambda x: rj.analytic.time_of_first_flip(x[:3], x[3:]))(X[1])
    np.testing.assert_allclose(grads[1], g_closed, rtol=2e-3)
