"""Independent NumPy/SciPy references and helpers shared by the tests (no rigidjax code).

Import them as `from tests.helpers import ...` (`tests` is a package, so that test modules of
the same name in different folders do not clash)."""

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

DOP853_TIGHT = dict(method="DOP853", rtol=1e-13, atol=1e-13)


def scalar_first(r: Rotation) -> np.ndarray:
    """A SciPy rotation as a scalar-first quaternion (independent of rigidjax's `from_xyzw`)."""
    x = r.as_quat()
    return np.concatenate([x[..., 3:], x[..., :3]], axis=-1)


def zxz_quaternion(psi, theta, phi) -> np.ndarray:
    """Borisov–Mamaev (001), THEORY §3: the quaternion λ of the classical Euler angles (ψ, θ, φ),
    P = Rz(ψ) Rx(θ) Rz(φ), with its sign (no flip to λ0 ≥ 0)."""
    return np.stack(
        [
            np.cos(theta / 2) * np.cos((psi + phi) / 2),
            np.sin(theta / 2) * np.cos((psi - phi) / 2),
            np.sin(theta / 2) * np.sin((psi - phi) / 2),
            np.cos(theta / 2) * np.sin((psi + phi) / 2),
        ],
        -1,
    )


def cross(a, b) -> np.ndarray:
    """`np.cross` of two 3-vectors written out: the same floating-point operations, several times
    faster on single vectors (the SciPy right-hand sides call it at every stage)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def rigid_body_rhs(I, torque_body=None):
    """Euler's equations `I Ω̇ = K − Ω × IΩ` and `q̇ = ½ q ∘ (0, Ω)` (scalar-first q) as the
    right-hand side `f(t, y)` of y = (Ω, q); `I` principal moments (3,) or a tensor (3, 3);
    `torque_body(t, Ω, q)` the body-frame torque K (zero if None)."""
    I = np.asarray(I, float)
    if I.ndim == 1:  # principal axes: I Ω̇ = IΩ × Ω + K component-wise

        def omega_dot(w, K):
            return (cross(I * w, w) + K) / I

    else:
        I_inv = np.linalg.inv(I)

        def omega_dot(w, K):
            return I_inv @ (K - cross(w, I @ w))

    def rhs(t, y):
        w, q = y[:3], y[3:]
        K = np.zeros(3) if torque_body is None else torque_body(t, w, q)
        dq = 0.5 * np.concatenate([[-q[1:] @ w], q[0] * w + cross(q[1:], w)])
        return np.concatenate([omega_dot(w, K), dq])

    return rhs


def rigid_body_dop853(I, w0, q0, ts, torque_body=None, t0=None):
    """`rigid_body_rhs` integrated by SciPy DOP853 at rtol = atol = 1e-13 from (Ω, q) = (w0, q0)
    at `t0` (default `ts[0]`); `ts` may lie on both sides of `t0`, in any order. Returns Ω (T, 3)
    and unit q (T, 4) at `ts`."""
    rhs = rigid_body_rhs(I, torque_body)
    ts = np.asarray(ts, float)
    t0 = ts[0] if t0 is None else float(t0)
    y0 = np.concatenate([np.asarray(w0, float), np.asarray(q0, float)])
    out = np.empty((len(ts), 7))
    fwd, bwd = ts >= t0, ts < t0
    for mask in (fwd, bwd):
        if mask.any():
            tt = ts[mask]
            end = tt.max() if mask is fwd else tt.min()
            order = np.argsort(tt) if mask is fwd else np.argsort(-tt)
            sol = solve_ivp(rhs, (t0, end), y0, t_eval=tt[order], **DOP853_TIGHT)
            assert sol.success, sol.message
            out[np.flatnonzero(mask)[order]] = sol.y.T
    q = out[:, 3:]
    return out[:, :3], q / np.linalg.norm(q, axis=-1, keepdims=True)


def fd_jacobian(f, x, h=1e-6) -> np.ndarray:
    """Central differences of `f` at `x`: `(*f(x).shape, x.size)` (the inputs flattened)."""
    x = np.asarray(x, float)
    cols = []
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = h
        e = e.reshape(x.shape)
        cols.append((np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h))
    return np.stack(cols, axis=-1)
