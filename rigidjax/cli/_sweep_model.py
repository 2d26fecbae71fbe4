"""The one-point model of a `rigidjax sweep` config (`_config.Config`): the body and initial state
with the point's factor values, the motion (free, or a closed loop of wheels, control law and,
with `[sensors]`, the estimator), and the chosen observables."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ._config import Config, fill


def make_model(c: Config) -> Callable[[dict], dict]:
    """The one-point model: the body and initial state with the point's factor values, the free
    motion over the config's times, and the chosen observables (plus `result`, so failed
    integrations get their status). Every point was checked eagerly (`check_points`), so the
    model skips the runtime checks: it compiles faster and fits the persistent cache.
    `first_flip_time` is the flip located by the solver (`events.flip_event`, not terminating:
    the motion is unchanged), not interpolated between samples."""
    import diffrax
    import jax.numpy as jnp

    from .. import observables as obs
    from .._integrate import SolveOptions
    from ..events import flip_event
    from ..mechanics.body import RigidBody
    from ..mechanics.dynamics import simulate
    from ..solvers import RK4

    dtype = jnp.float32 if c.float32 else jnp.float64
    ts = jnp.linspace(0.0, c.t_end, c.num, dtype=dtype)
    solver = {"tsit5": None, "dopri5": diffrax.Dopri5(), "dopri8": diffrax.Dopri8(), "rk4": RK4()}
    fixed = c.method == "rk4"
    options = SolveOptions(
        solver=solver[c.method],
        stepsize_controller=diffrax.ConstantStepSize() if fixed else None,
        rtol=c.rtol,
        atol=c.atol,
        dt0=c.dt,
        max_steps=c.max_steps,
        throw=False,
    )
    if c.control is not None:
        return _closed_loop_model(c, ts, options)
    compute = {
        "max_nutation": lambda body, tr: obs.max_nutation(tr),
        "first_flip_time": lambda body, tr: tr.event_t,
        "energy_drift": obs.energy_drift,
        "momentum_drift": obs.momentum_drift,
        "omega_end": lambda body, tr: tr.omega[-1],
        "quat_end": lambda body, tr: tr.quat[-1],
    }

    def model(p: dict) -> dict:
        body = RigidBody(fill(c.inertia, p, jnp).astype(dtype), check=False)
        w0, q0 = fill(c.omega0, p, jnp).astype(dtype), fill(c.q0, p, jnp).astype(dtype)
        flip = flip_event(w0, terminate=False) if "first_flip_time" in c.observables else None
        tr = simulate(
            body, w0, q0, ts, kinematics=c.kinematics, event=flip, options=options, check=False
        )
        return {n: compute[n](body, tr) for n in c.observables} | {"result": tr.result}

    return model


def _closed_loop_model(c: Config, ts, options) -> Callable[[dict], dict]:
    """The one-point model of a closed loop: a gyrostat with the config's wheels (each axis
    turned by its `tilt` about its perpendicular: `a cos t + p sin t`), the quaternion PD law
    on the nominal axes, sampled every `period` and held, and the `CLOSED_LOOP` observables.
    With `[sensors]`, the law acts on the MEKF's estimate (`rigidjax.estimation.estimated`),
    the point's noise drawn from a key folded from the seed and the point's factor values
    (the bits of each, in the design's order: reproducible, and distinct for distinct points),
    and the `ESTIMATED` observables are available. `settling_time` is exact, not a sample
    time: the sample grid brackets the last entry into the tolerance, and a second solve of
    the same motion locates it (`events.settling_event` after the last sample outside)."""
    import jax
    import jax.numpy as jnp

    from .. import observables as obs
    from ..control import quaternion_pd
    from ..estimation import control_error, estimated, knowledge_error
    from ..events import settling_event
    from ..mechanics import Gyrostat
    from ..mechanics.dynamics import simulate

    w, k, sn = c.wheels, c.control, c.sensors
    assert w is not None and k is not None  # `load` gives both or neither
    dtype = ts.dtype
    A0, perp = (jnp.asarray(w[key].T, dtype) for key in ("axes", "perp"))  # (3, n)
    target = jnp.asarray(k["target"], dtype)
    law = quaternion_pd(k["kp"], k["kd"], target, wheel_axes=A0)
    n = A0.shape[1]
    ctrl: Any = law
    if sn is not None:
        P0 = np.diag([sn["knowledge0"] ** 2] * 3 + [sn["bias"] ** 2] * 3)
        ctrl = estimated(
            law, arw=sn["arw"], rrw=sn["rrw"], sigma=jnp.asarray(sn["star_tracker"], dtype),
            P0=jnp.asarray(P0, dtype),
        )  # fmt: skip

    def point_key(p: dict):
        key = jax.random.key(sn["seed"] if sn is not None else 0)
        for name in sorted(p):
            words = jax.lax.bitcast_convert_type(jnp.asarray(p[name], dtype), jnp.uint32)
            for word in jnp.atleast_1d(words):
                key = jax.random.fold_in(key, word)
        return key

    def rms(x):
        return jnp.sqrt(jnp.mean(x[..., -max(1, x.shape[-1] // 2) :] ** 2, axis=-1))

    compute = {
        "knowledge_error_end": lambda tr: knowledge_error(tr)[..., -1],
        "knowledge_error_rms": lambda tr: rms(knowledge_error(tr)),
        "control_error_end": lambda tr: control_error(tr, target)[..., -1],
        "peak_wheel_speed": obs.peak_wheel_speed,
        "saturation_count": lambda tr: (
            obs.saturation_count(tr, w["torque_max"])
            if w["torque_max"] is not None
            else jnp.zeros((), jnp.int32)
        ),
        "pointing_error_end": lambda tr: obs.pointing_error(tr, target)[-1],
    }

    def model(p: dict) -> dict:
        tilt = fill(w["tilt"], p, jnp).astype(dtype)
        sc = Gyrostat(
            fill(c.inertia, p, jnp).astype(dtype),
            wheel_axes=A0 * jnp.cos(tilt) + perp * jnp.sin(tilt),
            wheel_inertia=jnp.full(n, w["inertia"], dtype),
            wheel_torque_max=w["torque_max"],
        )
        w0, q0 = fill(c.omega0, p, jnp).astype(dtype), fill(c.q0, p, jnp).astype(dtype)
        extra: dict[str, Any] = {} if sn is None else {"controller_key": point_key(p)}

        def run(event=None):
            return simulate(
                sc, w0, q0, ts, controller=ctrl, control_period=k["period"], options=options,
                check=False, event=event, **extra,
            )  # fmt: skip

        tr = run()
        out = {name: compute[name](tr) for name in c.observables if name != "settling_time"}
        if "settling_time" in c.observables:
            out["settling_time"] = settling(tr, run)
        return out | {"result": tr.result}

    def settling(tr, run):
        """The last entry into the tolerance, located in the sample interval that brackets it:
        `ts[0]` if never outside, `inf` if outside at the end, NaN for NaN states (as
        `observables.settling_time`)."""
        tol = k["tolerance"]
        before, grid = obs.settling_bracket(tr, target, tol)
        located = run(settling_event(target, tol, before)).event_t
        return jnp.where(jnp.isfinite(before) & jnp.isfinite(grid), located, grid)

    return model
