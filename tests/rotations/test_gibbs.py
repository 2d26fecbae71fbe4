"""rigidjax.gibbs against SciPy (`θ_G = 2 tan(χ/2) e` from `as_rotvec`) and rotation matrices."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import gibbs
from tests.helpers import scalar_first as sp


def gibbs_ref(r: Rotation) -> np.ndarray:
    """2 tan(χ/2) e from SciPy's rotation vector χ e."""
    rv = r.as_rotvec()
    chi = np.linalg.norm(rv, axis=-1, keepdims=True)
    e = rv / np.where(chi > 0, chi, 1)
    return 2 * np.tan(chi / 2) * e


def rotations():
    """Random rotations plus identity, a 1e-12 turn and χ = π − 1e-3."""
    extra = Rotation.from_rotvec(
        [[0, 0, 0], [1e-12, 0, 0], [0, (np.pi - 1e-3) * 0.6, 0.8 * (np.pi - 1e-3)]]
    )
    return Rotation.concatenate([Rotation.random(29, random_state=11), extra])


@jax.jit
def _all(q, P, g, g2, v):
    return {
        "from_quat": gibbs.from_quat(q),
        "from_quat_neg": gibbs.from_quat(-3 * q),
        "from_matrix": gibbs.from_matrix(P),
        "to_matrix": gibbs.to_matrix(g),
        "to_quat": gibbs.to_quat(g),
        "rotate": gibbs.rotate(g, v),
        "rotate_one": gibbs.rotate(g[0], v),
        "compose": gibbs.compose(g, g2),
        "matrix_product": gibbs.to_matrix(g) @ gibbs.to_matrix(g2),
    }


def test_gibbs_matches_scipy(rng):
    r = rotations()
    r2 = Rotation.random(32, random_state=12)
    g, g2 = gibbs_ref(r), gibbs_ref(r2)
    v = rng.normal(size=(32, 3))
    out = _all(sp(r), r.as_matrix(), g, g2, v)
    tol = dict(rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(out["from_quat"], g, **tol)
    np.testing.assert_allclose(out["from_quat_neg"], g, **tol)  # sign and scale invariant
    np.testing.assert_allclose(out["from_matrix"], g, rtol=1e-9, atol=1e-15)  # near π: cond ~1e3
    np.testing.assert_allclose(out["to_matrix"], r.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(
        out["to_quat"], np.where(sp(r)[:, :1] < 0, -sp(r), sp(r)), atol=1e-15
    )
    # r' − r = θ_G × (r + ½ θ_G × r)/(1 + θ_G²/4)  (Borisov–Mamaev)
    np.testing.assert_allclose(out["rotate"], r.apply(v), atol=1e-13)
    np.testing.assert_allclose(out["rotate_one"], r[0].apply(v), atol=1e-13)
    # composition: Gibbs vector of P(g1) P(g2), against SciPy and against the matrix product
    np.testing.assert_allclose(out["compose"], gibbs_ref(r * r2), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(out["matrix_product"], (r * r2).as_matrix(), atol=1e-13)
    # the cross term matters: composition does not commute
    swapped = gibbs.compose(g2, g)
    assert np.abs(np.asarray(swapped) - np.asarray(out["compose"])).max() > 1e-2


def test_to_matrix_is_cayley_transform(rng):
    g = rng.normal(size=(8, 3))
    R = np.cross(g[:, None, :], -np.eye(3)[None])  # hat(g): R @ a = g × a
    np.testing.assert_allclose(R[0] @ np.ones(3), np.cross(g[0], np.ones(3)), atol=1e-15)
    E = np.eye(3)
    ref = np.linalg.solve(E - R / 2, E + R / 2)
    np.testing.assert_allclose(gibbs.to_matrix(g), ref, atol=1e-13)


@pytest.mark.parametrize(
    "call, what",
    [
        (lambda: gibbs.from_quat(jnp.array([0.0, 0.6, 0.0, -0.8])), "q"),
        (lambda: gibbs.from_matrix(jnp.diag(jnp.array([1.0, -1.0, -1.0]))), "P"),
        # two quarter turns about x make a half turn: 1 − g1·g2/4 = 0
        (lambda: gibbs.compose(jnp.array([2.0, 0, 0]), jnp.array([2.0, 0, 0])), r"P\(g1\) P\(g2\)"),
        (lambda: jax.jit(gibbs.from_quat)(jnp.array([[1.0, 0, 0, 0], [0.0, 0, 0, 1]])), "q"),
    ],
    ids=["from_quat", "from_matrix", "compose", "jit"],
)
def test_error_at_pi(call, what):
    with pytest.raises(Exception, match=what + " is a rotation by χ = π.*MRP"):
        call()


def test_gradients_finite_at_identity():
    @jax.jit
    def run(q, g):
        v = jnp.array([0.3, -1.0, 2.0])
        return (
            jax.jacrev(gibbs.from_quat)(q),
            jax.jacrev(gibbs.to_quat)(g),
            jax.jacrev(gibbs.to_matrix)(g),
            jax.jacrev(gibbs.rotate)(g, v),
            jax.jacrev(gibbs.compose)(g, g),
        )

    J = run(jnp.array([1.0, 0, 0, 0]), jnp.zeros(3))
    assert all(np.all(np.isfinite(j)) for j in J)
    # θ_G = 2λ/λ0: d/dλ = 2E at the identity; dθ_G/dq0 = 0
    np.testing.assert_allclose(J[0], np.c_[np.zeros(3), 2 * np.eye(3)], atol=1e-15)


def test_float32(rng):
    r = Rotation.random(8, random_state=13)
    g = gibbs_ref(r).astype(np.float32)
    v = rng.normal(size=(8, 3)).astype(np.float32)
    out = jax.jit(
        lambda g, v: (gibbs.to_matrix(g), gibbs.rotate(g, v), gibbs.from_quat(gibbs.to_quat(g)))
    )(g, v)
    assert all(o.dtype == jnp.float32 for o in out)
    np.testing.assert_allclose(out[0], r.as_matrix(), atol=3e-6)
    np.testing.assert_allclose(out[1], r.apply(v), atol=1e-5)
    np.testing.assert_allclose(out[2], g, rtol=1e-5, atol=1e-6)
