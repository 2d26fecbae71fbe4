"""The multiplicative EKF of attitude and gyro bias in plain NumPy, a Python loop over the steps
vectorised over the runs: the baseline of `benchmarks/bench_estimation.py` and the independent
reference of `tests/estimation` (written apart from `rigidjax.estimation.mekf`: Rodrigues'
formulas with NumPy's trigonometry, the gain by `numpy.linalg.solve`, the log-determinant by
`numpy.linalg.slogdet`).

Conventions as `rigidjax.estimation.mekf`: quaternions scalar-first, Hamilton product, `q` body
→ space, error state `(δθ, δb)` in body axes with `q = q̂ ∘ δq(δθ)`."""

from __future__ import annotations

import numpy as np


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of `(..., 4)` quaternions."""
    a0, a1, a2, a3 = np.moveaxis(a, -1, 0)
    b0, b1, b2, b3 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
        ],
        axis=-1,
    )


def qexp(v: np.ndarray) -> np.ndarray:
    """The unit quaternion of the rotation vector `v (..., 3)`."""
    a = np.linalg.norm(v, axis=-1, keepdims=True)
    safe = np.where(a > 0, a, 1.0)
    s = np.where(a > 1e-8, np.sin(safe / 2) / safe, 0.5 - a**2 / 48)
    return np.concatenate([np.cos(a / 2), s * v], axis=-1)


def qlog(q: np.ndarray) -> np.ndarray:
    """The rotation vector (|θ| ≤ π) of the quaternion `q (..., 4)`."""
    q = np.where(q[..., :1] < 0, -q, q)
    n = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    safe = np.where(n > 0, n, 1.0)
    f = np.where(n > 1e-12, 2 * np.arctan2(n, q[..., :1]) / safe, 2 / q[..., :1])
    return f * q[..., 1:]


def skew(v: np.ndarray) -> np.ndarray:
    z = np.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2
    )


def mekf_numpy(ts, gyro, q_meas, *, arw, rrw, sigma, q0, bias0=None, P0=None):
    """`(quat (B, T, 4), bias (B, T, 3), cov (B, T, 6, 6), log_likelihood (B,))` of the MEKF on
    `B` runs: `ts (T,)`, `gyro (B, T−1, 3)`, `q_meas (B, T, 4)` (NaN rows: no update), noise
    levels scalars or `(3,)`, `q0 (B, 4)`, `bias0 (B, 3)`, `P0 (6, 6)`."""
    gyro, q_meas = np.asarray(gyro, float), np.asarray(q_meas, float)
    B, T = q_meas.shape[:2]
    v2 = np.broadcast_to(np.asarray(arw, float) ** 2, (3,))
    u2 = np.broadcast_to(np.asarray(rrw, float) ** 2, (3,))
    R = np.diag(np.broadcast_to(np.asarray(sigma, float) ** 2, (3,)))
    q = np.broadcast_to(np.asarray(q0, float), (B, 4)).copy()
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    b = np.zeros((B, 3)) if bias0 is None else np.broadcast_to(bias0, (B, 3)).astype(float)
    if P0 is None:
        P0 = np.diag([1e-2] * 3 + [1e-6] * 3)
    P = np.broadcast_to(np.asarray(P0, float), (B, 6, 6)).copy()
    out_q, out_b = np.empty((B, T, 4)), np.empty((B, T, 3))
    out_P = np.empty((B, T, 6, 6))
    ll = np.zeros(B)
    eye3, eye6 = np.eye(3), np.eye(6)
    for k in range(T):
        if k > 0:
            dt = ts[k] - ts[k - 1]
            w = gyro[:, k - 1] - b
            th = np.linalg.norm(w, axis=-1)[:, None, None] * dt
            W = skew(w)
            wn = np.linalg.norm(w, axis=-1)[:, None, None]
            small = th < 1e-6
            wn_s = np.where(small, 1.0, wn)
            th_s = np.where(small, 1.0, th)
            c1 = np.where(small, dt, np.sin(th_s) / wn_s)
            c2 = np.where(small, dt**2 / 2, (1 - np.cos(th_s)) / wn_s**2)
            c3 = np.where(small, dt**3 / 6, (th_s - np.sin(th_s)) / wn_s**3)
            WW = W @ W
            F11 = eye3 - c1 * W + c2 * WW
            F12 = -(eye3 * dt - c2 * W + c3 * WW)
            Phi = np.zeros((B, 6, 6))
            Phi[:, :3, :3], Phi[:, :3, 3:], Phi[:, 3:, 3:] = F11, F12, eye3
            Q = np.zeros((6, 6))
            Q[:3, :3] = np.diag(v2 * dt + u2 * dt**3 / 3)
            Q[:3, 3:] = Q[3:, :3] = np.diag(-u2 * dt**2 / 2)
            Q[3:, 3:] = np.diag(u2 * dt)
            P = Phi @ P @ np.swapaxes(Phi, -1, -2) + Q
            P = 0.5 * (P + np.swapaxes(P, -1, -2))
            q = qmul(q, qexp(w * dt))
            q /= np.linalg.norm(q, axis=-1, keepdims=True)
        zq = q_meas[:, k]
        ok = np.all(np.isfinite(zq), axis=-1)
        if np.any(ok):
            conj = q * np.array([1.0, -1, -1, -1])
            y = qlog(qmul(conj, np.where(ok[:, None], zq, q)))
            S = P[:, :3, :3] + R
            K = np.swapaxes(np.linalg.solve(S, np.swapaxes(P[:, :, :3], -1, -2)), -1, -2)
            KH = np.zeros((B, 6, 6))
            KH[:, :, :3] = K
            A = eye6 - KH
            Pn = A @ P @ np.swapaxes(A, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
            dx = np.einsum("bij,bj->bi", K, y)
            qn = qmul(q, qexp(dx[:, :3]))
            qn /= np.linalg.norm(qn, axis=-1, keepdims=True)
            _, logdet = np.linalg.slogdet(S)
            nis = np.einsum("bi,bi->b", y, np.linalg.solve(S, y[..., None])[..., 0])
            ll += np.where(ok, -0.5 * (nis + logdet + 3 * np.log(2 * np.pi)), 0.0)
            q = np.where(ok[:, None], qn, q)
            b = np.where(ok[:, None], b + dx[:, 3:], b)
            P = np.where(ok[:, None, None], 0.5 * (Pn + np.swapaxes(Pn, -1, -2)), P)
        out_q[:, k], out_b[:, k], out_P[:, k] = q, b, P
    return out_q, out_b, out_P, ll
