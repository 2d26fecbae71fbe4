"""SolveOptions: one options object for every integrating entry point; AbstractTrajectory."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax._tolerances import default_tolerances
from rigidjax._trajectory import AbstractTrajectory
from rigidjax.mechanics import heavy_top, kepler, satellite, sixdof
from tests.rotations.test_bad_input import raises_in_jit

TS = jnp.linspace(0.0, 2.0, 5)
BODY = rj.RigidBody(jnp.array([1.0, 2.0, 3.0]))
W0 = jnp.array([0.3, 1.0, -0.2])


def _entry_points():
    """Every integrating entry point, as `options -> trajectory-like` on a short problem."""
    top = heavy_top.HeavyTop(jnp.array([1.0, 1.0, 0.5]), 1.0, jnp.array([0.0, 0.0, 0.3]))
    r0, v0 = jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.1, 0.0])
    R0, V0 = satellite.circular_orbit(1.0, 1.0)
    return {
        "darboux": lambda o: rj.darboux(lambda t: jnp.array([1.0, t, 0.5]), TS, options=o),
        "simulate": lambda o: rj.simulate(BODY, W0, None, TS, options=o),
        "heavy_top": lambda o: rj.simulate_heavy_top(
            top, W0, jnp.array([0.0, 0.0, 1.0]), TS, options=o
        ),
        "6dof": lambda o: sixdof.simulate_6dof(BODY, r0, v0, None, W0, TS, options=o),
        "central": lambda o: kepler.simulate_central(r0, v0, TS, alpha=1.0, options=o),
        "two_body": lambda o: kepler.simulate_two_body(
            r0, v0, -r0, -v0, TS, m1=1.0, m2=1.0, alpha=1.0, options=o
        ),
        "satellite": lambda o: satellite.simulate_satellite(
            BODY, R0, V0, None, W0, TS, 1.0, options=o
        ),
    }


@pytest.mark.parametrize("name", list(_entry_points()))
def test_every_entry_point_takes_options(name):
    run = _entry_points()[name]
    # the options reach the solver: two steps per interval cannot cover it
    if name == "darboux":
        with pytest.raises(Exception, match="maximum number of solver steps"):
            run(rj.SolveOptions(max_steps=2))
        return
    out = run(rj.SolveOptions(max_steps=2, throw=False))
    assert isinstance(out, AbstractTrajectory)
    assert out.result == diffrax.RESULTS.max_steps_reached
    assert not out.successful
    assert out.ts.shape == TS.shape
    # each of the 4 output intervals stopped at its step limit
    assert int(out.stats["num_steps"]) == 2 * (TS.shape[0] - 1)


def test_keywords_are_shorthand_for_options():
    a = rj.simulate(BODY, W0, None, TS, rtol=1e-7, atol=1e-9)
    b = rj.simulate(BODY, W0, None, TS, options=rj.SolveOptions(rtol=1e-7, atol=1e-9))
    np.testing.assert_array_equal(a.omega, b.omega)
    assert int(a.stats["num_steps"]) == int(b.stats["num_steps"])
    # a keyword overrides the field of `options`
    c = rj.simulate(
        BODY, W0, None, TS, options=rj.SolveOptions(rtol=1e-3, atol=1e-3), rtol=1e-7, atol=1e-9
    )
    np.testing.assert_array_equal(a.omega, c.omega)


def test_fixed_steps_through_options():
    opts = rj.SolveOptions(solver=rj.RK4(), stepsize_controller=diffrax.ConstantStepSize(), dt0=0.1)
    tr = rj.simulate(BODY, W0, None, TS, options=opts)
    assert int(tr.stats["num_steps"]) == 20


def test_bad_options_are_clear_errors():
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) \['rtl'\]"):
        rj.simulate(BODY, W0, None, TS, rtl=1e-6)
    # (with the jaxtyping import hook on, its TypeCheckError names the parameter and the type)
    with pytest.raises(TypeError, match=r"(?s)options.*SolveOptions"):
        rj.simulate(BODY, W0, None, TS, options={"rtol": 1e-6})
    for field in ("rtol", "atol", "dt0"):
        # arrays and NumPy scalars too (they ran: a negative dt0 stepped backwards)
        infinite = () if field == "dt0" else (np.inf,)  # dt0 = inf: one step per interval
        for bad in (0.0, -1e-3, np.nan, jnp.array(-1e-3), np.float32(-1e-3), True, *infinite):
            with pytest.raises(ValueError, match=f"{field} must be a positive number"):
                rj.SolveOptions(**{field: bad})
    for bad in (0, -3, True, 2.0, np.int64(0)):
        with pytest.raises(ValueError, match="max_steps must be a positive integer"):
            rj.SolveOptions(max_steps=bad)
    # a NumPy integer is an integer (it was refused); stored as a Python int, as a static field
    assert type(rj.SolveOptions(max_steps=np.int64(7)).max_steps) is int
    with pytest.raises(ValueError, match="dt0"):
        rj.simulate(BODY, W0, None, TS, stepsize_controller=diffrax.ConstantStepSize())


@pytest.mark.slow  # ~11 s: run-time checks and derivatives under jit
def test_traced_step_and_tolerances():
    """Under jit a bad dt0 or rtol is a run-time error; derivatives with respect to them are
    zero (fixed steps round to a whole number per interval; they were a tracer leak), and a
    vmapped dt0 maps the kernel's steps (it was a shape error)."""
    fixed = {"solver": rj.RK4(), "stepsize_controller": diffrax.ConstantStepSize()}

    def end(dt0):
        return rj.simulate(BODY, W0, None, TS, dt0=dt0, **fixed).omega[-1, 0]

    with raises_in_jit("dt0 must be a positive number"):
        jax.jit(end)(-0.1).block_until_ready()
    for bad in (-1e-8, jnp.inf):  # (a traced inf ran into max_steps)
        with raises_in_jit("rtol must be a positive number"):
            jax.jit(lambda r: rj.simulate(BODY, W0, None, TS, rtol=r).omega)(
                bad
            ).block_until_ready()
    # (with the jaxtyping import hook on, its TypeCheckError names dt0 and the shape first)
    with pytest.raises((ValueError, TypeError), match=r"(?s)dt0.*(shape \(2,\)|f64\[2\])"):
        jax.jit(end)(jnp.array([0.1, 0.2]))
    assert float(jax.grad(end)(0.1)) == 0.0
    assert float(jax.jit(jax.grad(end))(0.1)) == 0.0
    dts = jnp.array([0.1, 0.07])
    np.testing.assert_array_equal(jax.vmap(end)(dts), [end(dt) for dt in dts])


@pytest.mark.slow  # ~13 s: the float32 solve eagerly and under jit
def test_float64_tolerance_of_a_float32_solve():
    """A float64 rtol (a NumPy scalar, or traced) leaves a float32 solve in float32 (it
    promoted Diffrax's controller state: a TypeError), eagerly and under jit."""
    f32 = np.float32
    body, w0, ts = rj.RigidBody(np.array([1.0, 2.0, 3.0], f32)), W0.astype(f32), TS.astype(f32)

    def omega(r):
        return rj.simulate(body, w0, None, ts, kinematics="rotvec", rtol=r, atol=1e-6).omega

    eager, traced = omega(np.float64(1e-5)), jax.jit(omega)(np.float64(1e-5))
    assert eager.dtype == traced.dtype == np.float32
    np.testing.assert_allclose(eager, traced, atol=1e-6)


def test_default_tolerances_per_dtype():
    assert default_tolerances(jnp.float64) == (1e-10, 1e-10)
    assert default_tolerances(jnp.float64, tight=True) == (1e-12, 1e-12)
    assert default_tolerances(jnp.float32) == (1e-6, 1e-6)
    assert default_tolerances(jnp.float32, tight=True) == (1e-6, 1e-6)


def test_throw_false_keeps_the_states_reached():
    """A failed solve comes back with its result instead of raising; the default raises."""
    with pytest.raises(Exception, match="maximum number of solver steps"):
        rj.simulate(BODY, W0, None, TS, max_steps=2)
    tr = rj.simulate(BODY, W0, None, TS, max_steps=2, throw=False)
    assert tr.result == diffrax.RESULTS.max_steps_reached
    np.testing.assert_allclose(tr.omega[0], W0)
    assert np.all(np.isfinite(np.asarray(tr.omega)))
