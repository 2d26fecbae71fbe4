"""quat.rotation_group and quat.reduce against SciPy's create_group and reduce; quat.power,
inv, magnitude and approx_equal against SciPy's __pow__, inv, magnitude and approx_equal (with
derivatives against finite differences); the SciPy and jaxlie conversions."""

import sys
import types
import warnings
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import quat

GROUPS = ["I", "O", "T", "C1", "C2", "C5", "D1", "D2", "D7"]
REDUCE = jax.jit(partial(quat.reduce, return_indices=True))
POWER = jax.jit(quat.power)


def sf(r: Rotation) -> np.ndarray:
    return r.as_quat(scalar_first=True)


def same_up_to_sign(q, ref, atol=1e-13):
    q, ref = np.asarray(q), np.asarray(ref)
    err = np.minimum(np.abs(q - ref).max(-1), np.abs(q + ref).max(-1))
    assert err.max() <= atol, err.max()


def test_rotation_groups_match_scipy():
    for name in GROUPS:
        for axis in ("x", "Y", "z"):
            g = quat.rotation_group(name, axis)
            np.testing.assert_allclose(g, sf(Rotation.create_group(name, axis)), atol=1e-15)
    sizes = {n: len(quat.rotation_group(n)) for n in ("I", "O", "T", "C3", "D3")}
    assert sizes == {"I": 60, "O": 24, "T": 12, "C3": 3, "D3": 6}
    assert quat.rotation_group("O", dtype=jnp.float32).dtype == jnp.float32
    # a group: closed under products (every product is ± an element)
    g = np.asarray(quat.rotation_group("I"))
    prod = np.asarray(quat.mul(g[:, None], g[None]))
    dots = np.abs(np.einsum("abi,ci->abc", prod, g)).max(-1)
    np.testing.assert_allclose(dots, 1.0, atol=1e-13)


def test_rotation_group_errors():
    for bad, match in [
        (3, "`group` argument must be a string"),
        ("Q", "`group` must be one of 'I', 'O', 'T', 'Dn', 'Cn'"),
        ("Cx", "`group` must be one of"),
        ("C0", "Group order must be positive"),
        ("D0", "Group order must be positive"),
    ]:
        with pytest.raises(ValueError, match=match):
            quat.rotation_group(bad)  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="`axis` must be one of"):
        quat.rotation_group("C4", "w")  # pyright: ignore[reportArgumentType]


@pytest.mark.parametrize(
    "cases",
    [[("T", None), ("D3", "C4")], pytest.param([(None, "O"), ("I", "I")], marks=pytest.mark.slow)],
)
def test_reduce_matches_scipy(cases):
    p = Rotation.random(20, rng=np.random.default_rng(0))
    q = sf(p)
    for left, right in cases:
        L = None if left is None else Rotation.create_group(left)
        R = None if right is None else Rotation.create_group(right)
        ref, li_ref, ri_ref = p.reduce(L, R, return_indices=True)
        red, li, ri = REDUCE(q, None if L is None else sf(L), None if R is None else sf(R))
        # the smallest rotation, l ∘ q ∘ r of the returned indices (checked with SciPy)
        red_r = Rotation.from_quat(np.asarray(red), scalar_first=True)
        np.testing.assert_allclose(red_r.magnitude(), ref.magnitude(), atol=1e-13)
        lq = p if L is None else L[np.asarray(li)] * p
        assert (
            red_r.inv() * (lq if R is None else lq * R[np.asarray(ri)])
        ).magnitude().max() < 1e-13
        assert (li is None) == (L is None) and (ri is None) == (R is None)
        if left != "I":  # I on both sides: many (l, r) pairs tie; rounding picks one
            same_up_to_sign(red, sf(ref))
            for idx, idx_ref in ((li, li_ref), (ri, ri_ref)):
                if idx is not None:
                    np.testing.assert_array_equal(idx, idx_ref)
    # a single rotation: indices of the batch shape (); no groups: q itself
    red, li, ri = quat.reduce(q[0], sf(Rotation.create_group("T")), return_indices=True)
    assert red.shape == (4,) and li is not None and li.shape == () and ri is None
    np.testing.assert_allclose(quat.reduce(q), q, atol=1e-15)


@pytest.mark.slow
def test_reduce_of_an_empty_batch():
    """An empty batch reduces to an empty batch (reshape with -1 of zero elements was a
    ZeroDivisionError)."""
    g = quat.rotation_group("O")
    assert quat.reduce(jnp.zeros((0, 4)), left=g).shape == (0, 4)
    red, li, ri = quat.reduce(jnp.zeros((2, 0, 4)), g, g, return_indices=True)
    assert red.shape == (2, 0, 4) and li.shape == ri.shape == (2, 0)


def test_reduce_gradient():
    q = sf(Rotation.from_rotvec([0.3, 2.0, -0.4]))
    g = sf(Rotation.create_group("O"))
    f = jax.jit(lambda x: quat.reduce(x, g))
    J = jax.jacfwd(f)(q)
    h = 1e-6
    fd = np.stack([(f(q + h * e) - f(q - h * e)) / (2 * h) for e in np.eye(4)], -1)
    np.testing.assert_allclose(J, fd, atol=1e-8)


def test_power_inv_magnitude_match_scipy():
    r = Rotation.random(12, rng=np.random.default_rng(1))
    r = Rotation.concatenate([r, Rotation.identity(), Rotation.from_rotvec([np.pi, 0, 0])])
    q = sf(r)
    for p in (0.0, 1.0, -1.0, 0.5, -2.5, 1e-8, 3.0):
        same_up_to_sign(POWER(q, p), sf(r**p), atol=1e-12)
    np.testing.assert_allclose(POWER(-q, 1.0), -q, atol=1e-15)  # special cases keep the sign
    np.testing.assert_array_equal(POWER(q, 0.0), np.tile([1.0, 0, 0, 0], (len(q), 1)))
    np.testing.assert_allclose(POWER(q, -1.0), sf(r.inv()), atol=1e-15)
    np.testing.assert_allclose(quat.inv(q), sf(r.inv()), atol=1e-15)
    np.testing.assert_allclose(quat.magnitude(q), r.magnitude(), atol=1e-15)
    # p broadcast against the batch
    ps = np.linspace(-2, 2, len(q))
    ref = np.stack([sf(ri**pi) for ri, pi in zip(r, ps, strict=True)])
    same_up_to_sign(quat.power(q, ps), ref, 1e-12)


@pytest.mark.slow
def test_power_gradients_match_finite_differences():
    q = sf(Rotation.from_rotvec([0.3, -1.2, 0.4]))
    f = jax.jit(lambda q, p: quat.power(q, p))
    for p in (0.0, 1.0, -1.0, 0.7):
        g = jax.jacfwd(f, argnums=1)(q, p)
        h = 1e-6
        np.testing.assert_allclose(g, (f(q, p + h) - f(q, p - h)) / (2 * h), atol=1e-8)
        Jq = jax.jacfwd(f)(q, p)
        fd = np.stack([(f(q + h * e, p) - f(q - h * e, p)) / (2 * h) for e in np.eye(4)], -1)
        np.testing.assert_allclose(Jq, fd, atol=1e-8)
    # identity and the zero subgradient of the magnitude: finite
    e = jnp.array([1.0, 0, 0, 0])
    assert np.all(np.isfinite(jax.jacfwd(f)(e, 0.5)))
    assert np.all(np.isfinite(jax.grad(quat.magnitude)(e)))


def test_approx_equal_matches_scipy():
    r = Rotation.random(10, rng=np.random.default_rng(2))
    s = r * Rotation.from_rotvec(np.linspace(0, 2e-3, 10)[:, None] * [0, 0, 1])
    for atol, degrees in [(None, False), (1e-3, False), (0.05, True)]:
        np.testing.assert_array_equal(
            quat.approx_equal(sf(r), sf(s), atol, degrees),
            r.approx_equal(s, atol, degrees),
        )
    assert quat.approx_equal(sf(r[0]), -sf(r[0]))  # q and −q
    with pytest.warns(UserWarning, match="atol must be set"):
        quat.approx_equal(sf(r), sf(s), degrees=True)
    with pytest.raises(ValueError, match="broadcastable shapes"):
        quat.approx_equal(sf(r), sf(s)[:3])


def test_scipy_conversion_round_trip():
    r = Rotation.from_quat(np.random.default_rng(3).normal(size=(3, 2, 4)))
    q = quat.from_scipy(r)
    assert q.shape == (3, 2, 4)
    np.testing.assert_array_equal(q, r.as_quat(scalar_first=True))
    back = quat.to_scipy(q)
    assert isinstance(back, Rotation)
    np.testing.assert_allclose(back.as_quat(), r.as_quat(), atol=1e-15)
    single = quat.to_scipy([0.0, 0, 0, 2])
    assert single.single
    np.testing.assert_allclose(single.as_quat(), [0, 0, 1, 0])
    with pytest.raises(TypeError, match="scipy.spatial.transform.Rotation"):
        quat.from_scipy(q)
    with pytest.raises(ValueError, match="zero quaternion"):
        quat.to_scipy(np.zeros(4))


def test_jaxlie_conversion(monkeypatch):
    """Against jaxlie if installed; else against a stand-in module with jaxlie's SO3(wxyz=...)."""
    try:
        import jaxlie  # noqa: F401
    except ImportError:
        fake = types.ModuleType("jaxlie")

        class SO3:
            def __init__(self, wxyz):
                self.wxyz = wxyz

        fake.SO3 = SO3  # pyright: ignore[reportAttributeAccessIssue]
        monkeypatch.setitem(sys.modules, "jaxlie", fake)
    q = sf(Rotation.random(4, rng=np.random.default_rng(4)))
    so3 = quat.to_jaxlie(2 * q)
    np.testing.assert_allclose(so3.wxyz, q, atol=1e-15)
    np.testing.assert_allclose(quat.from_jaxlie(so3), q, atol=1e-15)
    with pytest.raises(TypeError, match="jaxlie.SO3"):
        quat.from_jaxlie(q)


def test_jaxlie_missing_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "jaxlie", None)  # import fails
    with warnings.catch_warnings(), pytest.raises(ImportError, match="pip install jaxlie"):
        quat.to_jaxlie([1.0, 0, 0, 0])
