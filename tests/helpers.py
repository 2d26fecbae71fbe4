"""Independent NumPy/SciPy references and helpers shared by the tests (no rigidjax code)."""

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation


def scalar_first(r: Rotation) -> np.ndarray:
    """A SciPy rotation as a scalar-first quaternion (independent of rigidjax's `from_xyzw`)."""
    x = r.as_quat()
    return np.concatenate([x[..., 3:], x[..., :3]], axis=-1)


def rigid_body_dop853(I, w0, q0, ts, torque_body=None):
    """Euler's equations `I Ω̇ = K − Ω × IΩ` and `q̇ = ½ q ∘ (0, Ω)` (scalar-first q) with SciPy
    DOP853 at rtol = atol = 1e-13; returns Ω (T, 3) and unit q (T, 4) at `ts`."""
    I = np.asarray(I, float)
    I_inv = np.linalg.inv(I)

    def rhs(t, y):
        w, q = y[:3], y[3:]
        K = np.zeros(3) if torque_body is None else torque_body(t, w, q)
        dw = I_inv @ (K - np.cross(w, I @ w))
        dq = 0.5 * np.concatenate([[-q[1:] @ w], q[0] * w + np.cross(q[1:], w)])
        return np.concatenate([dw, dq])

    ts = np.asarray(ts)
    sol = solve_ivp(
        rhs,
        (ts[0], ts[-1]),
        np.concatenate([w0, q0]),
        method="DOP853",
        t_eval=ts,
        rtol=1e-13,
        atol=1e-13,
    )
    q = sol.y[3:].T
    return sol.y[:3].T, q / np.linalg.norm(q, axis=-1, keepdims=True)
