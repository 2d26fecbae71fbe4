"""`degrees=` and Euler sequences of 1, 2 or 3 axes against SciPy's from_euler/as_euler,
from_rotvec/as_rotvec and from_davenport/as_davenport; SciPy's errors for bad sequences."""

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import euler, quat

SEQS = ["x", "Z", "xy", "ZX", "yz", "XYZ", "zxz", "YXY"]


def test_euler_sequences_of_1_to_3_axes_match_scipy():
    rng = np.random.default_rng(0)
    for seq in SEQS:
        a = rng.uniform(-180, 180, (8, len(seq)))
        r = Rotation.from_euler(seq, a, degrees=True)
        np.testing.assert_allclose(
            euler.to_quat(a, seq, degrees=True), r.as_quat(scalar_first=True), atol=1e-15
        )
        np.testing.assert_allclose(euler.to_matrix(np.deg2rad(a), seq), r.as_matrix(), atol=1e-15)
    # one axis: a scalar angle gives one rotation, (N, 1) angles N rotations
    np.testing.assert_allclose(
        euler.to_quat(90.0, "z", degrees=True), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15
    )
    assert euler.to_quat([[30.0], [20.0]], "x").shape == (2, 4)
    # intrinsic "Z" and extrinsic "z" agree for one axis
    np.testing.assert_allclose(euler.to_matrix(0.7, "Z"), euler.to_matrix(0.7, "z"), atol=0)


def test_degrees_out_match_scipy():
    r = Rotation.random(10, rng=np.random.default_rng(1))
    q, P = r.as_quat(scalar_first=True), r.as_matrix()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = r.as_euler("ZXZ", degrees=True)
        np.testing.assert_allclose(euler.from_quat(q, "ZXZ", degrees=True), ref, atol=1e-11)
        np.testing.assert_allclose(euler.from_matrix(P, "ZXZ", degrees=True), ref, atol=1e-11)
    rv = r.as_rotvec(degrees=True)
    np.testing.assert_allclose(quat.to_rotvec(q, degrees=True), rv, atol=1e-11)
    np.testing.assert_allclose(
        quat.from_rotvec(rv, degrees=True),
        Rotation.from_rotvec(rv, degrees=True).as_quat(scalar_first=True),
        atol=1e-15,
    )


def test_davenport_degrees_match_scipy():
    axes = np.array([[1.0, 0, 0], [0, 1, 0], [0.6, 0, 0.8]])
    rng = np.random.default_rng(2)
    ang = rng.uniform(-170, 170, (6, 3))
    ang[:, 1] = rng.uniform(-30, 120, 6)
    r = Rotation.from_davenport(axes, "intrinsic", ang, degrees=True)
    np.testing.assert_allclose(
        euler.davenport_to_quat(ang, axes, degrees=True), r.as_quat(scalar_first=True), atol=1e-14
    )
    ref = r.as_davenport(axes, "intrinsic", degrees=True)
    np.testing.assert_allclose(
        euler.davenport_from_quat(r.as_quat(scalar_first=True), axes, degrees=True), ref, atol=1e-10
    )


@pytest.mark.parametrize(
    "seq, match",
    [
        ("xyzx", "Expected axis specification to be a non-empty string of up to 3 characters"),
        ("", "Expected axis specification"),
        ("xYz", r"Expected axes from `seq` to be from \['x', 'y', 'z'\] or \['X', 'Y', 'Z'\]"),
        ("abc", "Expected axes from `seq`"),
        ("xxz", "Expected consecutive axes to be different, got xxz"),
        ("zz", "Expected consecutive axes to be different"),
        (3, "Expected `seq` to be a string"),
    ],
)
def test_bad_sequences_raise_scipys_errors(seq, match):
    with pytest.raises(ValueError, match=match) as info:
        euler.to_quat(np.zeros(3), seq)
    assert "seq must be" in str(info.value)  # and the fix


def test_angle_count_and_three_axis_errors():
    with pytest.raises(ValueError, match="Expected last dimension of `angles` to match number"):
        euler.to_quat(np.zeros(2), "x")
    with pytest.raises(ValueError, match="Expected last dimension of `angles`"):
        euler.to_matrix(np.zeros(1), "XYZ")
    for fn, arg in ((euler.from_quat, [1.0, 0, 0, 0]), (euler.from_matrix, np.eye(3))):
        with pytest.raises(ValueError, match=r"Expected 3 axes, got xy\."):
            fn(arg, "xy")
    with pytest.raises(ValueError, match="Expected 3 axes"):
        euler.jacobian(np.zeros(3), "ZX")
