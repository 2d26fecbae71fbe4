"""rigidjax.mrp against SciPy `as_mrp`/`from_mrp`."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from rigidjax import mrp
from tests.helpers import scalar_first as sp


def rotations():
    """Random rotations plus identity, 1e-12 turn, exactly π about x and an arbitrary axis."""
    extra = Rotation.from_rotvec(
        [[0, 0, 0], [1e-12, 0, 0], [np.pi, 0, 0], [0.6 * np.pi, 0, -0.8 * np.pi]]
    )
    return Rotation.concatenate([Rotation.random(28, random_state=21), extra])


@jax.jit
def _all(q, P, p, p2, v):
    return {
        "from_quat": mrp.from_quat(q),
        "from_quat_neg": mrp.from_quat(-2 * q),
        "from_matrix": mrp.from_matrix(P),
        "to_matrix": mrp.to_matrix(p),
        "to_quat": mrp.to_quat(p),
        "rotate": mrp.rotate(p, v),
        "compose": mrp.compose(p, p2),
    }


def test_mrp_matches_scipy(rng):
    r, r2 = rotations(), Rotation.random(32, random_state=22)
    p, p2 = r.as_mrp(), r2.as_mrp()
    assert np.all(np.linalg.norm(p, axis=-1) <= 1 + 1e-15)
    v = rng.normal(size=(32, 3))
    out = _all(sp(r), r.as_matrix(), p, p2, v)
    # at exactly π both ±p are valid MRPs of norm 1
    ok = np.minimum(
        np.abs(np.asarray(out["from_quat"]) - p).max(-1),
        np.abs(np.asarray(out["from_quat"]) + p).max(-1),
    )
    assert ok.max() < 1e-15
    np.testing.assert_allclose(out["from_quat_neg"], out["from_quat"], atol=1e-15)
    np.testing.assert_allclose(out["from_matrix"][:30], p[:30], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(out["from_matrix"], axis=-1)[30:], 1, atol=1e-15)
    np.testing.assert_allclose(out["to_matrix"], r.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(mrp.to_matrix(out["from_matrix"]), r.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(out["rotate"], r.apply(v), atol=1e-13)
    q = np.asarray(out["to_quat"])
    err = np.minimum(np.abs(q - sp(r)).max(-1), np.abs(q + sp(r)).max(-1))
    assert err.max() < 1e-15
    np.testing.assert_allclose(out["compose"], (r * r2).as_mrp(), atol=1e-13)


def test_shadow(rng):
    p = rng.normal(size=(32, 3))  # many with |p| > 1
    s = np.asarray(mrp.shadow(p))
    n2 = (p * p).sum(-1, keepdims=True)
    np.testing.assert_allclose(s, np.where(n2 > 1, -p / n2, p), atol=0)
    assert np.all(np.linalg.norm(s, axis=-1) <= 1 + 1e-15)
    # same rotation, and SciPy's from_mrp accepts the non-shadow set
    np.testing.assert_allclose(mrp.to_matrix(p), Rotation.from_mrp(p).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(mrp.to_matrix(s), Rotation.from_mrp(p).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(s, Rotation.from_mrp(p).as_mrp(), atol=1e-14)


def test_gradients_finite():
    @jax.jit
    def run(z, q180):
        return (
            jax.jacrev(mrp.shadow)(z),
            jax.jacrev(mrp.to_matrix)(z),
            jax.jacrev(mrp.from_quat)(jnp.array([1.0, 0, 0, 0])),
            jax.jacrev(mrp.from_quat)(q180),
            jax.jacrev(mrp.compose)(z, z),
        )

    J = run(jnp.zeros(3), jnp.array([0.0, 0.6, 0.0, -0.8]))
    assert all(np.all(np.isfinite(j)) for j in J)
    np.testing.assert_allclose(J[0], np.eye(3), atol=0)
    # p = λ/(1 + λ0): dp/dλ = E/2 at the identity
    np.testing.assert_allclose(J[2], np.c_[np.zeros(3), 0.5 * np.eye(3)], atol=1e-15)


def test_float32():
    r = Rotation.random(8, random_state=23)
    p = r.as_mrp().astype(np.float32)
    out = jax.jit(lambda p: (mrp.to_matrix(p), mrp.from_quat(mrp.to_quat(p))))(p)
    assert all(o.dtype == jnp.float32 for o in out)
    np.testing.assert_allclose(out[0], r.as_matrix(), atol=2e-6)
    np.testing.assert_allclose(out[1], p, atol=1e-6)
