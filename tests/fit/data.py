"""Test data generated with SciPy (DOP853), independently of rigidjax's integrators."""

import numpy as np
from scipy.spatial.transform import Rotation

from tests.helpers import rigid_body_dop853

R_TRUE = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
I_TRUE = R_TRUE @ np.diag([1.0, 2.0, 2.6]) @ R_TRUE.T  # full, non-diagonal tensor
I_REF = I_TRUE / np.trace(I_TRUE)  # what a torque-free fit (trace 1) estimates
MOMENTS_REF = np.array([1.0, 2.0, 2.6]) / 5.6
W0S = np.array([[0.4, 1.1, -0.7], [1.0, -0.3, 0.5], [-0.2, 0.6, 1.2]])
Q0S = Rotation.from_rotvec([[0.1, 0.2, -0.3], [1.0, 0.0, 0.5], [-0.4, 2.0, 0.1]]).as_quat(
    scalar_first=True
)
TS = np.linspace(0.0, 8.0, 61)
BIAS = np.array([0.02, -0.01, 0.015])


def experiments(ts=TS, torque=None, n=3):
    """Clean Ω (E, T, 3) and q (E, T, 4) of `n` experiments of the body I_TRUE; `ts` (T,) or
    (E, T); `torque(t, Ω, q)` body frame."""
    ts = np.broadcast_to(ts, (n, np.shape(ts)[-1]))
    out = [rigid_body_dop853(I_TRUE, W0S[e], Q0S[e], ts[e], torque) for e in range(n)]
    return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])


def attitude_noise(q, sigma, rng):
    """q ∘ exp(δ), δ ~ N(0, σ² E) (body-frame attitude errors)."""
    noisy = Rotation.from_quat(q.reshape(-1, 4), scalar_first=True) * Rotation.from_rotvec(
        sigma * rng.normal(size=(q.size // 4, 3))
    )
    return noisy.as_quat(scalar_first=True).reshape(q.shape)
