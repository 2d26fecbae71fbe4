"""The robust losses: ρ, the transformed residual, ψ = ρ' and ψ' = ρ'' agree."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax.fit.losses import LOSSES, make_loss


@pytest.mark.parametrize("name", LOSSES)
def test_loss_pieces_agree(name):
    loss = make_loss(name, None, jnp.float64)
    z = jnp.array([-30.0, -2.0, -1.0, -0.3, -1e-6, 0.0, 1e-6, 0.5, 1.2, 1.4, 3.0, 50.0])

    @jax.jit
    def pieces(z):
        rho_grad = jax.vmap(jax.grad(lambda x: loss.rho(x)))(z)
        psi_grad = jax.vmap(jax.grad(lambda x: loss.psi(x)))(z)
        t_grad = jax.vmap(jax.grad(lambda x: loss.transform(x)))(z)
        return loss.rho(z), loss.transform(z), loss.psi(z), loss.dpsi(z), rho_grad, psi_grad, t_grad

    rho, t, psi, dpsi, rho_grad, psi_grad, t_grad = pieces(z)
    np.testing.assert_allclose(t**2 / 2, rho, rtol=1e-12, atol=1e-15)  # Σ z̃²/2 = Σ ρ
    np.testing.assert_allclose(np.sign(t), np.sign(z))
    np.testing.assert_allclose(psi, rho_grad, rtol=1e-12, atol=1e-15)
    keep = np.abs(np.abs(z) - float(loss.c)) > 1e-3  # Huber's ψ' jumps at |z| = c
    np.testing.assert_allclose(np.asarray(dpsi)[keep], np.asarray(psi_grad)[keep], atol=1e-12)
    assert np.all(np.isfinite(t_grad)) and abs(float(t_grad[5]) - 1) < 1e-12  # z̃ ≈ z at 0
    small = np.abs(z) < 0.5
    np.testing.assert_allclose(np.asarray(t)[small], np.asarray(z)[small], rtol=0.03)
    if name != "l2":  # bounded influence: large residuals count less than in least squares
        assert float(rho[-1]) < 0.5 * 50.0**2 / 10


def test_bad_loss():
    with pytest.raises(ValueError, match="loss must be one of"):
        make_loss("tukey", None, jnp.float64)
    with pytest.raises(ValueError, match="loss_scale must be a positive number"):
        make_loss("huber", -1.0, jnp.float64)
