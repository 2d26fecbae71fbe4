"""An atlas of two Euler-angle charts whose gimbal locks are far apart (THEORY §4).

Lock set of a sequence. Intrinsic `"abc"`, `P = R_a(α) R_b(β) R_c(γ)`: since `R_a` fixes `e_a`
and `R_c` fixes `e_c`, `e_a · P e_c = e_a · R_b(β) e_c`, which is `cos β` (proper, c = a) or
`±sin β` (Tait–Bryan). So the chart is locked exactly where the body axis `v = e_c` is carried
onto the space axis `u = e_a`, `P v = ±u`, and its margin is
`|det J| = |u × P v| = √(1 − (u · P v)²) = |sin β|` (proper) or `|cos β|` (Tait–Bryan)
(`rigidjax.euler.jacobian`). An extrinsic `"abc"` is the intrinsic `"cba"`: `u = e_c`, `v = e_a`.

Partner. Keep `u` and the middle axis and take a body axis `v' ⟂ v`: intrinsic `"aba"` ↔
`"abc"` (c the third axis), e.g. `"ZXZ"` ↔ `"ZXY"`, `"XYZ"` ↔ `"XYX"`; extrinsic `"aba"` ↔
`"cba"`, `"abc"` ↔ `"cbc"`. The pairing is an involution and pairs a proper sequence with a
Tait–Bryan one of the same kind (intrinsic/extrinsic).

Theorem: at every attitude `m² + m'² ≥ 1` for the margins `m`, `m'` of a sequence and its
partner, so `max(m, m') ≥ 1/√2`. Proof: `P v` and `P v'` are orthonormal, so (Bessel)
`(u · P v)² + (u · P v')² ≤ |u|² = 1`, i.e. `(1 − m²) + (1 − m'²) ≤ 1`. Hence switching charts
when `m < s` (any `s < 1/√2`) lands in a chart with `m' ≥ √(1 − s²) > s`: the charts never lock,
and the switch back needs the attitude to move until `m ≥ √(1 − s²)` again (built-in hysteresis).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._custom_types import EulerSeq, Scalar, Vec3
from ..rotations import euler

__all__ = ["is_proper", "lock_axes", "margin", "partner"]


def _check_seq(seq: object) -> str:
    if not isinstance(seq, str) or seq not in euler.SEQUENCES:
        raise ValueError(
            "seq must be 3 letters from 'xyz', all upper case (intrinsic, rotating axes) or all "
            "lower case (extrinsic, fixed axes), with no two consecutive letters equal, "
            f"e.g. 'ZXZ', 'ZYX', 'xyz'; got seq={seq!r}"
        )
    return seq


def is_proper(seq: EulerSeq) -> bool:
    """True for proper Euler sequences (first axis = third, e.g. `"ZXZ"`), False for Tait–Bryan."""
    seq = _check_seq(seq)
    return seq[0] == seq[2]


def lock_axes(seq: EulerSeq) -> tuple[int, int]:
    """`(u, v)`: indices of the space axis `e_u` and body axis `e_v` with `seq` locked iff
    `P e_v = ±e_u`; margin `|det J| = |e_u × P e_v|` (module docstring)."""
    i, _, k = ("xyz".index(c) for c in _check_seq(seq).lower())
    return (i, k) if seq.isupper() else (k, i)


def partner(seq: EulerSeq) -> str:
    """The partner chart of `seq`: same space lock axis and middle axis, body lock axis turned by
    90° (intrinsic `"aba"` ↔ `"abc"`, extrinsic `"aba"` ↔ `"cba"`; module docstring)."""
    i, j, k = ("xyz".index(c) for c in _check_seq(seq).lower())
    if seq.isupper():  # replace the last axis
        k = 3 - i - j if k == i else i
    else:  # replace the first axis
        i = 3 - j - k if i == k else k
    out = "".join("xyz"[n] for n in (i, j, k))
    return out.upper() if seq.isupper() else out


def margin(angles: Vec3, seq: EulerSeq) -> Scalar:
    """`|det J|` of the kinematic Euler formulas of `seq` (`rigidjax.euler.jacobian`):
    `|sin β|` (proper) or `|cos β|` (Tait–Bryan) of the middle angle β; 0 at gimbal lock."""
    beta = angles[..., 1]
    return jnp.abs(jnp.sin(beta) if is_proper(seq) else jnp.cos(beta))
