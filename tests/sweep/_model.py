"""The sweep model shared by the tests and their subprocesses: the tennis-racket body of
moments (1, I2, 2.5) spun about its middle axis with an offset, fixed-step RK4 (short, so it
compiles fast); observables: the smallest Ω2 and the final body angular velocity."""

import diffrax
import jax.numpy as jnp
import numpy as np

import rigidjax as rj
from rigidjax import sweep

TS = jnp.linspace(0.0, 8.0, 9)
FIXED = dict(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.25)


def model(p):
    body = rj.RigidBody(jnp.stack([1.0, p["I2"], 2.5]), check=False)
    w0 = jnp.stack([p["offset"], 1.0, p["offset"]])
    tr = rj.simulate(body, w0, None, TS, throw=False, **FIXED)
    return {"min_w2": jnp.min(tr.omega[:, 1]), "omega_end": tr.omega[-1], "result": tr.result}


def design():
    return sweep.grid(I2=np.linspace(1.6, 2.4, 5), offset=np.array([0.01, 0.05, 0.1]))
