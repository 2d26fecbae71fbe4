"""Bad input that used to return numbers or NaN, or an error naming the wrong cause (issue 26):
each is one clear error naming the argument and the fix."""

import subprocess
import sys

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax as rj
from rigidjax import analytic, euler, so3
from rigidjax.mechanics import kepler
from tests.rotations.test_bad_input import raises_in_jit

TS = np.linspace(0.0, 1.0, 3)
W0 = np.array([0.3, 1.0, -0.2])
NAN = np.nan


@pytest.mark.parametrize(
    ("inertia", "message"),
    [
        ([1.0, 2.0, NAN], r"inertia must be finite, got inertia = \[ ?1\., 2\., nan\]"),
        (
            [1.0, -2.0, 2.5],
            r"inertia must be positive, got inertia = \[ 1\. , -2\. , 2\.5\]; give three",
        ),
        ([0.0, 2.0, 2.0], r"inertia must be positive"),
    ],
)
def test_closed_forms_check_the_moments(inertia, message):
    calls = [
        lambda: analytic.free_rigid_body(inertia, W0, TS),
        lambda: analytic.free_rigid_body_attitude(inertia, W0, None, TS),
        lambda: analytic.free_rigid_body_parameters(inertia, W0),
        lambda: analytic.flip_period(inertia, W0),
        lambda: analytic.time_of_first_flip(inertia, W0),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=message):
            call()


def test_closed_forms_reject_moments_no_body_has():
    """Moments against the triangle inequality (issue 26): one error naming them and the fix,
    in every closed form; `check=False` admits them (Principia's formal I = (3, 5, 9)); a flat
    body (equality) passes."""
    tri = r"inertia violates the triangle inequality .*, got inertia = \[9\., 3\., 5\.\]"
    top = r"\(I1, I1, I3\) violates the triangle inequality"
    calls = [
        (lambda **k: analytic.free_rigid_body([9.0, 3.0, 5.0], W0, TS, **k), tri),
        (lambda **k: analytic.free_rigid_body_attitude([9.0, 3.0, 5.0], W0, None, TS, **k), tri),
        (lambda **k: analytic.free_rigid_body_parameters([9.0, 3.0, 5.0], W0, **k), tri),
        (lambda **k: analytic.flip_period([9.0, 3.0, 5.0], W0, **k), tri),
        (lambda **k: analytic.time_of_first_flip([9.0, 3.0, 5.0], W0, **k), tri),
        (lambda **k: analytic.symmetric_top(1.0, 2.5, W0, TS, **k), top),
        (lambda **k: analytic.symmetric_top_attitude(1.0, 2.5, W0, None, TS, **k), top),
        (lambda **k: analytic.symmetric_top_precession(1.0, 2.5, W0, **k), top),
    ]
    for call, message in calls:
        with pytest.raises(ValueError, match=message) as e:
            call()
        assert "check=False" in str(e.value)
        assert not np.any(np.isnan(np.asarray(jax.tree_util.tree_leaves(call(check=False))[0])))
    w = analytic.free_rigid_body([9.0, 3.0, 5.0], W0, TS, check=False)
    np.testing.assert_allclose(w[0], W0, atol=1e-15)
    analytic.free_rigid_body([1.0, 2.0, 3.0], W0, TS)  # equality: a flat body
    with raises_in_jit("inertia violates the triangle inequality"):
        jax.block_until_ready(jax.jit(analytic.free_rigid_body)(jnp.array([1.0, 2, 4]), W0, TS))


def test_closed_forms_check_the_moments_under_jit():
    f = jax.jit(analytic.free_rigid_body)
    with raises_in_jit("inertia must be positive"):
        jax.block_until_ready(f(jnp.array([1.0, -2.0, 3.0]), W0, TS))
    np.testing.assert_allclose(f(jnp.array([1.0, 2.0, 3.0]), W0, TS)[0], W0, atol=1e-14)


def test_closed_forms_check_omega0_and_times():
    I = [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match=r"omega0 must be finite: omega0\[1\] = nan"):
        analytic.free_rigid_body(I, [0.3, NAN, 1.0], TS)
    with pytest.raises(ValueError, match=r"ts must be finite: ts\[1\] = nan"):
        analytic.free_rigid_body(I, W0, [0.0, NAN])
    with pytest.raises(ValueError, match=r"t0 must be finite"):
        analytic.free_rigid_body(I, W0, TS, t0=NAN)
    with pytest.raises(ValueError, match=r"ts must be finite"):
        analytic.free_rigid_body_attitude(I, W0, None, [NAN, 1.0])


def test_symmetric_top_checks():
    with pytest.raises(ValueError, match=r"\(I1, I1, I3\) must be positive"):
        analytic.symmetric_top_precession(-1.0, 1.5, W0)
    with pytest.raises(ValueError, match=r"\(I1, I1, I3\) must be positive"):
        analytic.symmetric_top(1.0, 0.0, W0, TS)
    with pytest.raises(ValueError, match=r"\(I1, I1, I3\) must be finite"):
        analytic.symmetric_top_attitude(NAN, 1.5, W0, None, TS)
    with pytest.raises(ValueError, match=r"omega0 must be finite"):
        analytic.symmetric_top(1.0, 1.5, [NAN, 0.0, 1.0], TS)
    with pytest.raises(ValueError, match=r"ts must be finite"):
        analytic.symmetric_top(1.0, 1.5, W0, [0.0, NAN])
    # a valid top still agrees with its closed form Ω3 = const
    out = analytic.symmetric_top(1.0, 1.5, W0, TS)
    np.testing.assert_allclose(out[:, 2], W0[2], rtol=0, atol=0)


def test_so3_exp_of_a_nan_vector():
    with pytest.raises(ValueError, match=r"theta must be finite, got theta = \[nan, 0\., 0\.\]"):
        so3.exp(np.array([NAN, 0.0, 0.0]))


@pytest.mark.parametrize("fn", [so3.Z, so3.Z_inv, so3.shadow, lambda v: so3.rotate(v, W0)])
def test_so3_integrator_algebra_names_a_nan_vector(fn):
    """As `exp` (they returned NaN): eager only, the traced hot path stays without checks."""
    with pytest.raises(ValueError, match=r"theta must be finite, got theta\[1\] = \[ ?0\., inf"):
        fn(np.array([[0.1, 0.2, 0.3], [0.0, np.inf, 0.0]]))
    with pytest.raises(ValueError, match=r"a must be finite"):
        so3.rotate(W0, np.array([NAN, 0.0, 0.0]))


def _errors_without_type_checks(calls: str, error: str) -> tuple[list[str], str]:
    """The messages of the `error`s the `calls` (lambdas of `diffrax`, `np` and `rj`, comma
    separated) raise in a process without the tests' jaxtyping type checks (a user's)."""
    code = (
        "import diffrax, numpy as np, rigidjax as rj\n"
        f"for f in ({calls}):\n"
        "    try:\n"
        "        f()\n"
        f"    except {error} as e:\n"
        "        print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.splitlines(), out.stdout + out.stderr


def test_messages_without_runtime_type_checks():
    """`so3.log(None)`, `energy(array, ω)`, `simulate(array, ...)` and `simulate_heavy_top` of
    a RigidBody: the tests run with jaxtyping's type checks, which catch these first; a user's
    process has none, so the messages are checked in one."""
    calls = (
        "lambda: rj.so3.log(None), lambda: rj.energy(np.ones(3), np.ones(3)),\n"
        "lambda: rj.simulate(np.ones(3), np.ones(3), None, [0.0, 1.0]),\n"
        "lambda: rj.simulate_heavy_top(rj.RigidBody(np.ones(3)), np.ones(3),\n"
        "                              [0.0, 0.0, 1.0], [0.0, 1.0])"
    )
    lines, out = _errors_without_type_checks(calls, "TypeError")
    assert lines[0] == "P must be an array (or a number), got None", out
    assert lines[1].startswith("body must be a rigidjax.RigidBody, got ndarray: wrap"), out
    assert lines[2].startswith("body must be a rigidjax.RigidBody or Gyrostat, got ndarray"), out
    assert lines[3].startswith("top must be a rigidjax.HeavyTop, got RigidBody"), out


def test_solvers_without_an_explicit_tableau():
    """`darboux(method="geometric", solver=diffrax.Euler())` named `method` and called forward
    Euler not explicit; the message now names the solver and why (in a process without the
    tests' type checks, which catch the Euler first)."""
    calls = (
        "lambda: rj.darboux(lambda t: t * np.ones(3), [0.0, 1.0], method='geometric',\n"
        "                   solver=diffrax.Euler()),\n"
        "lambda: rj.ExplicitRK(diffrax.Kvaerno3())"
    )
    lines, out = _errors_without_type_checks(calls, "ValueError")
    assert lines[0].startswith("the Runge–Kutta method (the solver, or the method of"), out
    assert lines[0].endswith("; Euler has no Butcher tableau"), out
    assert lines[1].endswith("; Kvaerno3 is implicit"), out


@pytest.mark.parametrize("A", [np.zeros((3, 3)), np.outer([1.0, 2.0, 0.0], [0.0, 1.0, 1.0])])
def test_so3_project_of_a_singular_matrix(A):
    with pytest.raises(ValueError, match=r"A has rank < 2: many rotations are equally near"):
        so3.project(A)
    with raises_in_jit("A has rank < 2"):
        jax.block_until_ready(jax.jit(so3.project)(A))


def test_so3_project_of_rank_two_is_unique():
    """Rank 2 still has one nearest rotation: SciPy's (SVD, det fixed) answer."""
    from scipy.spatial.transform import Rotation

    A = np.diag([2.0, 1.0, 0.0])
    np.testing.assert_allclose(so3.project(A), np.eye(3), atol=1e-15)
    R = Rotation.from_rotvec([0.3, -0.4, 0.5]).as_matrix()
    np.testing.assert_allclose(so3.project(R @ A), R, atol=1e-14)


def test_omega_to_rates_at_gimbal_lock():
    with pytest.raises(ValueError, match=r"gimbal lock.*seq='ZXZ'.*kinematics\.euler_atlas"):
        euler.omega_to_rates(np.zeros(3), W0)  # the default ZXZ at the identity, check=False
    with pytest.raises(ValueError, match=r"gimbal lock.*seq='XYX'"):
        euler.omega_to_rates(np.array([0.1, 0.0, 0.2]), W0, "XYX")
    # the other locks, whose sin π and cos(π/2) are no exact zero in floating point
    for seq, beta in (("ZXZ", np.pi), ("ZYX", np.pi / 2), ("xyz", -np.pi / 2)):
        with pytest.raises(ValueError, match=rf"gimbal lock.*seq='{seq}'"):
            euler.omega_to_rates(np.array([0.1, beta, 0.2]), W0, seq)
    # traced, no check (as documented): the inverse formula's 1/0
    assert not np.all(np.isfinite(jax.jit(euler.omega_to_rates)(np.zeros(3), W0)))


@pytest.mark.parametrize("guess", [[1.0, NAN, 2.0], [1.0, -2.0, 2.5]])
def test_identify_inertia_names_a_bad_guess(guess):
    ts = np.linspace(0.0, 2.0, 21)
    omega = analytic.free_rigid_body([1.0, 2.0, 2.5], [0.3, 1.0, 0.2], ts)
    with pytest.raises(ValueError, match=r"^inertia_guess (has non-finite|is not positive)"):
        rj.identify_inertia(ts, omega, inertia_guess=guess)


def test_simulate_names_batch_shapes():
    body = rj.RigidBody([1.0, 2.0, 2.5])
    q0 = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
    with pytest.raises(
        ValueError,
        match=r"batch shapes .* do not broadcast: body \(\), omega0 \(3,\), q0 \(2,\)",
    ):
        rj.simulate(body, np.ones((3, 3)), q0, TS)


def _nan_after(t_bad):
    return lambda t, w, q: jnp.where(t > t_bad, jnp.nan, 0.1) * w


def test_nonfinite_torque_is_named_adaptive():
    body = rj.RigidBody([1.0, 2.0, 2.5])
    with pytest.raises(
        rj.IntegrationError,
        match=r"between t = 0 and t = 0\.5 .*the torque returned a non-finite value \(NaN or "
        r"inf\) at t = 0 .*make torque\(t, omega, q\) finite",
    ):
        rj.simulate(body, W0, None, TS, torque=lambda t, w, q: jnp.full(3, jnp.nan))


def test_nonfinite_torque_is_named_fixed_steps():
    body = rj.RigidBody([1.0, 2.0, 2.5])
    kw = {"solver": diffrax.Tsit5(), "stepsize_controller": diffrax.ConstantStepSize()}
    with pytest.raises(
        rj.IntegrationError,
        # the first of 33 probes of [0.5, 1] past t = 0.6: 0.5 + 4/64
        match=r"between t = 0\.5 and t = 1 .*the torque returned a non-finite value .* at "
        r"t = 0\.5625 ",
    ):
        rj.simulate(body, W0, None, TS, torque=_nan_after(0.55), dt0=0.01, **kw)
    # the step's own blow-up keeps its message
    with pytest.raises(rj.IntegrationError, match="the step is too large"):
        rj.simulate(body, np.array([0.0, 400.0, 1.0]), None, TS, dt0=0.5, **kw)


@pytest.mark.parametrize("frame", ["inertial", "Space", "left"])
def test_torque_frame_typos_are_refused(frame):
    """A torque_frame other than "space" or "body" ran as "body" ("left", Zhilin's word for
    space, gave a wrong answer)."""
    tq = lambda t, w, q: jnp.array([0.0, 0.0, 1.0])  # noqa: E731
    match = f"torque_frame must be 'space' or 'body' .*got '{frame}'"
    with pytest.raises(ValueError, match=match):
        rj.simulate(rj.RigidBody([1.0, 2.0, 2.5]), W0, None, TS, torque=tq, torque_frame=frame)
    with pytest.raises(ValueError, match=match):
        rj.simulate(rj.Gyrostat([1.0, 2.0, 2.5], h=[0.0, 0.0, 0.5]), W0, None, TS,
                    torque=tq, torque_frame=frame)  # fmt: skip
    with pytest.raises(ValueError, match=match):
        rj.identify_inertia(TS, omega_obs=np.ones((3, 3)), torque=tq, torque_frame=frame)


def test_mekf_names_a_zero_q0():
    ts = np.linspace(0.0, 1.0, 3)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (3, 1))
    with pytest.raises(ValueError, match=r"q0 is a zero quaternion.*\|q0\| > 0"):
        rj.estimation.mekf(ts, np.zeros((2, 3)), q, arw=1e-3, rrw=1e-5, sigma=1e-3, q0=np.zeros(4))


def test_kepler_r0_zero():
    with pytest.raises(ValueError, match=r"r0 must be non-zero.*singular at the centre"):
        kepler.simulate_central(np.zeros(3), np.array([0.0, 1.0, 0.0]), TS, alpha=1.0)


def test_energy_of_a_body_still_works():
    body = rj.RigidBody([1.0, 2.0, 2.5])
    np.testing.assert_allclose(rj.energy(body, W0), 0.5 * np.sum(np.array([1.0, 2.0, 2.5]) * W0**2))
