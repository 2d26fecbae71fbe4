"""Models with a jump map (a held command) for the Pallas kernels' tests: a damped oscillator
with a sampled law, and a closed loop (a gyrostat with four wheels under a quaternion PD law)."""

import jax.numpy as jnp
import numpy as np

import rigidjax as rj

AXES = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.6], [0.0, 0.0, 1.0, 0.52915026]])
Q_T = np.array([np.cos(0.6), np.sin(0.6) * 0.6, np.sin(0.6) * 0.8, 0.0])


def closed_loop() -> tuple[rj.Gyrostat, rj.control.laws.QuaternionPD]:
    """The spacecraft and its law: four wheels, a quaternion PD toward `Q_T`."""
    sat = rj.Gyrostat(
        np.array([1.0, 1.5, 2.0]), wheel_axes=AXES, wheel_inertia=[0.01] * 4,
        wheel_torque_max=0.05,
    )  # fmt: skip
    return sat, rj.control.quaternion_pd(0.4, 0.9, Q_T, wheel_axes=AXES)


def held(t, y, p):
    """A damped oscillator driven by a held command y[2] (its rate 0)."""
    return jnp.stack([y[1], -p[0] * y[0] - 0.1 * y[1] + y[2], 0.0 * y[2]])


def sample_law(t, y, p):
    """The jump map: the command sampled from the state, `u = −2 x − v + sin t`."""
    return jnp.stack([y[0], y[1], -2.0 * y[0] - y[1] + jnp.sin(t)])
