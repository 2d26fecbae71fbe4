"""Trajectories return the quaternion as integrated: unit, continuous in sign, starting at q0,
and equal (sign included) to SciPy's solution of q̇ = ½ q ∘ (0, Ω) — also through a flip."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rigidjax as rj
from rigidjax import quat
from tests.helpers import rigid_body_dop853

# the tennis-racket flip of the issue: I = (1, 2, 3), ω0 = (0.01, 1, 0.01), 401 samples in 40 s
I = np.array([1.0, 2.0, 3.0])
W0 = np.array([0.01, 1.0, 0.01])
TS = np.linspace(0.0, 40.0, 401)
Q0 = Rotation.from_rotvec([0.4, -2.9, 0.3]).as_quat(scalar_first=True)  # λ0 < 0 on the way


@pytest.fixture(scope="module")
def reference():
    return rigid_body_dop853(I, W0, Q0, TS)[1]


@pytest.mark.parametrize("kinematics", ["quat", "rotvec"])
def test_sign_follows_the_ode_through_the_flip(kinematics, reference):
    tr = rj.simulate(rj.RigidBody(I), W0, Q0, TS, kinematics=kinematics, rtol=1e-11, atol=1e-11)
    q = np.asarray(tr.quat)
    np.testing.assert_array_equal(q[0], Q0)  # as given, not canonicalised
    assert np.all(np.sum(q[1:] * q[:-1], axis=-1) > 0.9)  # no jump between samples
    assert np.any(q[:, 0] < 0) and np.any(q[:, 0] > 0)  # the test passes through λ0 = 0
    np.testing.assert_allclose(q, reference, atol=1e-7)  # the ODE's solution, sign included


def test_canonical_gives_the_nonnegative_representative(reference):
    c = np.asarray(quat.canonical(reference))
    assert np.all(c[:, 0] >= 0)
    np.testing.assert_allclose(np.abs(np.sum(c * reference, -1)), 1.0, atol=1e-12)


def test_continuous_repairs_sign_jumps(reference):
    flipped = reference * np.where(np.arange(len(TS)) % 3 == 0, -1.0, 1.0)[:, None]
    fixed = np.asarray(quat.continuous(flipped))
    np.testing.assert_allclose(fixed, reference * np.sign(flipped[0, 0] / reference[0, 0]))
    # batches: the time axis is −2
    both = np.asarray(quat.continuous(jnp.stack([flipped, -flipped])))
    np.testing.assert_allclose(both[1], -both[0])
