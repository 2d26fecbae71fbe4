"""`ExactFreeBody`: every step is the exact Euler–Poinsot flow of (Ω, q). Checked against SciPy
DOP853 at rtol = atol = 1e-13 (tests.helpers, independent of rigidjax) for step sizes 0.05 to 5
in every regime, for conservation to rounding, and for gradients against finite differences.

All cases run as ONE batch with the same output times, so `simulate` compiles once per module
(the step size `dt0` is traced: no recompilation per step size)."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax.solvers import ExactFreeBody
from tests.helpers import rigid_body_dop853

S3 = np.sqrt(3.0)
# (name, principal moments, Ω0): every regime of the free rigid body
CASES = [
    ("about largest axis", (1.0, 2.0, 3.0), (0.3, 0.2, 1.0)),
    ("about smallest axis", (1.0, 2.0, 3.0), (1.0, 0.3, 0.2)),
    # M² − 2E I2 = 3 Ω3² − Ω1² (I = 1, 2, 3): 1e-7 of the scale away from the separatrix
    ("near separatrix", (1.0, 2.0, 3.0), (0.2 * S3 * (1 + 5e-8), 0.7, 0.2)),
    ("on separatrix", (1.0, 2.0, 3.0), (0.2 * S3, 0.7, 0.2)),
    ("oblate symmetric", (2.0, 2.0, 3.0), (0.3, 0.5, 1.0)),
    ("prolate symmetric", (1.0, 3.0, 3.0), (0.3, 0.5, 1.0)),
    ("sphere", (2.0, 2.0, 2.0), (0.3, -0.5, 1.0)),
    ("permuted moments", (3.0, 1.0, 2.5), (-0.4, 0.9, 0.5)),
]
NAMES = [c[0] for c in CASES]
TS = np.array([0.0, 5.0, 10.0, 15.0])


def _q0s():
    q = np.random.default_rng(15).normal(size=(len(CASES), 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def batch():
    I = np.array([c[1] for c in CASES])
    w = np.array([c[2] for c in CASES])
    return I, w, _q0s()


@pytest.fixture(scope="module")
def reference(batch):
    I, w, q = batch
    return [rigid_body_dop853(I[k], w[k], q[k], TS) for k in range(len(CASES))]


def _run(batch, dt0=None):
    I, w, q = batch
    return rj.simulate(rj.RigidBody(I), w, q, TS, solver=ExactFreeBody(), dt0=dt0)


def _check_against_reference(traj, reference):
    for k, name in enumerate(NAMES):
        w_ref, q_ref = reference[k]
        # the separatrix is unstable: the reference's 1e-13 grows like e^{λt} there
        tol = 3e-10 if "separatrix" in name else 2e-11
        np.testing.assert_allclose(traj.omega[k], w_ref, atol=tol, rtol=0, err_msg=name)
        np.testing.assert_allclose(traj.quat[k], q_ref, atol=tol, rtol=0, err_msg=name)


@pytest.mark.parametrize("dt0", [0.05, 0.7, 5.0])
def test_exact_for_any_step(batch, reference, dt0):
    """Ω and q (with its sign: continuous, q(0) = q0) agree with DOP853 at 1e-13 to within the
    reference's own error, for Diffrax steps of 0.05, 0.7 and 5 (one compilation: dt0 is
    traced)."""
    traj = _run(batch, dt0)
    # the batch is one state: 3 output intervals of 5 time units, ceil(5/dt0) steps each
    assert int(traj.stats["num_steps"]) == {0.05: 300, 0.7: 24, 5.0: 3}[dt0]
    _check_against_reference(traj, reference)


@pytest.mark.slow
def test_default_one_step_from_start(batch, reference):
    """Without dt0 each output time is one exact step from ts[0] (no Diffrax loop); a single
    body gives the batch member's numbers."""
    traj = _run(batch)
    assert int(traj.stats["num_steps"]) == len(TS) - 1
    _check_against_reference(traj, reference)
    I, w, q = batch
    one = rj.simulate(rj.RigidBody(I[0]), w[0], q[0], TS, solver=ExactFreeBody())
    np.testing.assert_allclose(one.omega, traj.omega[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(one.quat, traj.quat[0], rtol=0, atol=1e-15)


def test_conserved_to_rounding(batch):
    """Energy, the space angular momentum P I Ω and |q| after 300 exact steps: rounding errors
    only (a random walk of a few ulps per step), no truncation error."""
    I, _, _ = batch
    traj = _run(batch, 0.05)
    M = I[:, None, :] * np.asarray(traj.omega)
    energy = np.sum(M * np.asarray(traj.omega), -1)
    M_space = np.asarray(rj.quat.rotate(traj.quat, jnp.asarray(M)))
    scale = np.linalg.norm(M, axis=-1)[:, :1]
    np.testing.assert_allclose(energy, energy[:, :1] * np.ones_like(energy), rtol=3e-14)
    np.testing.assert_allclose(
        M_space, M_space[:, :1] * np.ones_like(M_space), atol=3e-14 * scale.max()
    )
    np.testing.assert_allclose(np.linalg.norm(traj.quat, axis=-1), 1.0, atol=4e-16)
    np.testing.assert_array_equal(traj.quat[:, 0], _q0s())


def test_clear_errors():
    body = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
    w, ts = jnp.array([0.1, 0.2, 0.3]), jnp.linspace(0.0, 1.0, 3)
    with pytest.raises(ValueError, match="torque-free"):
        rj.simulate(body, w, None, ts, torque=lambda t, w, q: w, solver=ExactFreeBody())
    with pytest.raises(ValueError, match="principal axes"):
        rj.simulate(
            rj.RigidBody(jnp.diag(jnp.array([1.0, 2.0, 3.0]))), w, None, ts, solver=ExactFreeBody()
        )
    with pytest.raises(ValueError, match="kinematics='quat'"):
        rj.simulate(body, w, None, ts, kinematics="rotvec", solver=ExactFreeBody())
    with pytest.raises(ValueError, match="fixed steps"):
        rj.simulate(
            body,
            w,
            None,
            ts,
            solver=ExactFreeBody(),
            stepsize_controller=diffrax.PIDController(1e-8, 1e-8),
        )


def _loss(I, w, q):
    """A scalar of the final state of every batch member, differentiated below."""
    # I = (1, 2, 3) is a flat plate, on the edge of the triangle inequality: no check
    traj = rj.simulate(rj.RigidBody(I, check=False), w, q, TS[:2], solver=ExactFreeBody())
    weights = jnp.arange(1.0, 8.0)
    state = jnp.concatenate([traj.omega[:, -1], traj.quat[:, -1]], -1)
    return jnp.sum(state * weights, -1)


@pytest.mark.slow
def test_gradients_match_finite_differences(batch):
    """d/d(inertia, Ω0, q0) of the state after 5 time units (one exact step) against central
    differences, in every regime off the separatrix and the sphere; finite everywhere (on the
    separatrix and for the sphere only finiteness: there the branch is a set of measure zero)."""
    I, w, q = (jnp.asarray(a) for a in batch)
    # the members are independent: the gradient of the sum is each member's own gradient
    grads = jax.grad(lambda I, w, q: jnp.sum(_loss(I, w, q)), argnums=(0, 1, 2))(I, w, q)
    for g in grads:
        assert np.all(np.isfinite(g))
    f = jax.jit(_loss)
    eps = 1e-6
    for which, x in enumerate((I, w, q)):
        for i in range(x.shape[1]):
            e = jnp.zeros_like(x).at[:, i].set(eps)
            args_p = [I, w, q]
            args_m = [I, w, q]
            args_p[which] = x + e
            args_m[which] = x - e
            fd = (f(*args_p) - f(*args_m)) / (2 * eps)
            ad = grads[which][:, i]
            for k, name in enumerate(NAMES):
                if name == "on separatrix" or (
                    which == 0 and name in ("near separatrix", "sphere")
                ):
                    continue  # the differences would cross the separatrix / leave the sphere
                np.testing.assert_allclose(
                    ad[k], fd[k], rtol=2e-5, atol=2e-5, err_msg=f"{name}, argument {which}, {i}"
                )
