"""Experiment design: the designed torque beats PRBS of the same duration and bound, and the
designed experiment identifies the absolute inertia (known torque) from SciPy data."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import design_excitation, identify_inertia
from rigidjax.fit import fisher_information, prbs
from rigidjax.fit.design import log_det_criterion
from tests.helpers import rigid_body_dop853

I_PRIOR = np.diag([1.0, 2.0, 2.6])
W0 = np.array([0.1, 0.05, -0.05])
BOUND, DURATION, S, M = 0.1, 20.0, 8, 10
SIGMA = 1e-3


@pytest.mark.slow  # compiles the gradient of the Fisher information through the flow
def test_designed_torque_beats_prbs():
    design = design_excitation(
        I_PRIOR,
        W0,
        DURATION,
        torque_bound=BOUND,
        n_segments=S,
        samples_per_segment=M,
        sigma_omega=SIGMA,
        steps=40,
        key=jax.random.PRNGKey(1),
    )
    assert design.torques.shape == (S, 3) and float(jnp.max(jnp.abs(design.torques))) <= BOUND
    assert float(design.history[-1]) >= float(design.history[0])

    @jax.jit
    def criterion(u):
        F = fisher_information(
            jnp.asarray(I_PRIOR), jnp.asarray(W0), u, design.ts, sigma_omega=SIGMA, substeps=4
        )
        return log_det_criterion(F), jnp.sqrt(jnp.diagonal(jnp.linalg.inv(F))[:6])

    phi_d, std_d = criterion(design.torques)
    prbs_phi, prbs_std = zip(
        *(criterion(prbs(jax.random.PRNGKey(k), S, BOUND)) for k in range(2, 22)), strict=True
    )
    assert float(phi_d) > max(map(float, prbs_phi))  # better than each of 20 PRBS draws
    # smaller predicted std (Cramér–Rao) than the average PRBS, entry by entry on the diagonal
    assert np.all(np.asarray(std_d)[:3] < np.mean(np.asarray(prbs_std), axis=0)[:3])
    np.testing.assert_allclose(np.diagonal(design.inertia_std), np.asarray(std_d)[:3], rtol=0.05)

    # the designed experiment, simulated by SciPy, identifies the absolute tensor
    def torque_np(t, w, q):
        k = min(int(np.searchsorted(np.asarray(design.edges), t, side="right")) - 1, S - 1)
        return np.asarray(design.torques)[k]

    ts = np.asarray(design.ts)
    W, _ = rigid_body_dop853(I_PRIOR, W0, [1.0, 0.0, 0.0, 0.0], ts, torque_np)
    data = W + SIGMA * np.random.default_rng(6).normal(size=W.shape)
    est = identify_inertia(ts, omega_obs=data, torque=design.torque, sigma_omega=SIGMA)
    assert bool(est.converged) and est.scale.startswith("absolute")
    err = np.asarray(est.inertia) - I_PRIOR
    assert np.all(np.abs(err) <= 4.5 * np.asarray(est.inertia_std) + 1e-12), err
    np.testing.assert_allclose(
        np.diagonal(est.inertia_std), np.diagonal(design.inertia_std), rtol=0.3
    )


def test_bad_design_input():
    with pytest.raises(ValueError, match="torque_bound must be a positive number"):
        design_excitation(I_PRIOR, W0, 10.0, torque_bound=0.0)
    with pytest.raises(ValueError, match=r"init must have shape \(8, 3\)"):
        design_excitation(I_PRIOR, W0, 10.0, torque_bound=0.1, init=np.zeros((4, 3)))
    # (a zero or NaN noise level gave a NaN design silently; step_angle = 0 a ZeroDivisionError;
    # q0 was named q; a traced prior a ConcretizationTypeError)
    bad = [
        (dict(sigma_omega=0.0), "sigma_omega must be a positive number"),
        (dict(sigma_angle=np.nan), "sigma_angle must be a positive number"),
        (dict(step_angle=0.0), "step_angle must be a positive number"),
        (dict(n_segments=0), "n_segments must be a positive integer"),
        (dict(q0=np.zeros(4)), "q0 is a zero quaternion"),
    ]
    for kw, needle in bad:
        with pytest.raises(ValueError, match=needle):
            design_excitation(I_PRIOR, W0, 10.0, torque_bound=0.1, **kw)
    with pytest.raises(ValueError, match="inertia must be concrete"):
        jax.jit(lambda I: design_excitation(I, W0, 10.0, torque_bound=0.1).log_det)(I_PRIOR)
