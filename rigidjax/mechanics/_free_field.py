"""The torque-free rigid body in principal axes with its body-frame attitude quaternion, written
component by component: the one formula of the free body's model (`_rigid_model`), which every
backend evaluates, so that their numbers agree."""

from __future__ import annotations

from jaxtyping import Array

Vec3 = tuple[Array, Array, Array]
Quat = tuple[Array, Array, Array, Array]


def free_field(c: Vec3, w: Vec3, q: Quat) -> tuple[Vec3, Quat]:
    """`(Ω̇, q̇)` of a torque-free body: Euler's equations in principal axes
    `Ω̇1 = c1 Ω2 Ω3`, `c1 = (I2 − I3)/I1` (cyclic; Zegrya–Parshin 004), and the kinematics
    `q̇ = ½ q ∘ (0, Ω)` (Borisov–Mamaev 001; exercises 002 #101); every component an array of
    the same shape (one entry per body) or a scalar."""
    w0, w1, w2 = w
    dw = (c[0] * w1 * w2, c[1] * w2 * w0, c[2] * w0 * w1)
    return dw, quat_rate(w, q)


def quat_rate(w: Vec3, q: Quat) -> Quat:
    """`q̇ = ½ q ∘ (0, Ω)` with the body angular velocity Ω (Borisov–Mamaev 001), component by
    component."""
    w0, w1, w2 = w
    q0, q1, q2, q3 = q
    return (
        -0.5 * (q1 * w0 + q2 * w1 + q3 * w2),
        0.5 * (q0 * w0 + q2 * w2 - q3 * w1),
        0.5 * (q0 * w1 + q3 * w0 - q1 * w2),
        0.5 * (q0 * w2 + q1 * w1 - q2 * w0),
    )
