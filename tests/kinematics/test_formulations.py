"""The kinematics formulations called directly on batches of states: each method maps leading
batch dimensions as `jax.vmap` of one state does (`AbstractKinematics` says so; the rotation
vector's `Z @ w` and the Cayley–Klein layout `(2, *batch, 2, 2)` broke it)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax.kinematics import METHODS


@pytest.mark.parametrize("frame", ["space", "body"])
@pytest.mark.parametrize("method", sorted(METHODS))
def test_batches_as_vmap(method, frame):
    kin = METHODS[method](frame=frame)
    P = jnp.asarray(
        Rotation.from_rotvec([[0.3, -0.2, 0.5], [1.0, 0.4, -2.0], [0.0, 2.5, 0.1]]).as_matrix()
    )
    w = jnp.array([[0.1, 0.2, -0.3], [1.0, -0.5, 0.2], [0.0, 0.3, 2.0]])
    y = kin.from_matrix(P)
    np.testing.assert_allclose(y, jax.vmap(kin.from_matrix)(P), rtol=0, atol=1e-15)
    np.testing.assert_allclose(kin.to_matrix(y), P, atol=1e-14)
    dy = kin.vector_field(y, w)
    np.testing.assert_allclose(dy, jax.vmap(kin.vector_field)(y, w), rtol=1e-14, atol=1e-15)
    # independent of the formulation: the state's rate carries P along Poisson's equation,
    # Ṗ = ω̂ P (space) or P Ω̂ (body) (Zhilin 3.12.2)
    P_dot = jax.jvp(kin.to_matrix, (y,), (dy,))[1]
    W = jnp.cross(w[:, None, :], jnp.eye(3)[None], axis=-1).swapaxes(-1, -2)  # ŵ a = w × a
    poisson = W @ P if frame == "space" else P @ W
    np.testing.assert_allclose(P_dot, poisson, atol=1e-13)
    scaled = jax.tree_util.tree_map(lambda a: a * 2, y) if method in ("quat", "cayley_klein") else y
    np.testing.assert_allclose(
        kin.step_end(scaled)[0], jax.vmap(lambda s: kin.step_end(s)[0])(scaled), atol=1e-15
    )
