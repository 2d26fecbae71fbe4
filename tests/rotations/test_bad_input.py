"""Bad input to the rotation maps is a clear error naming the argument: a ValueError with the value
and the fix on concrete input (also under an eager grad/jacfwd/jacrev, whose primal is known),
the same message from `equinox.error_if` under jit/vmap.
Valid input (identity, θ = π, 180° rotations, slightly non-orthogonal matrices) keeps finite
values and gradients, and the algebra of the integrators gains no checks."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax.rotations import andoyer, euler, gibbs, mrp, quat, so3
from tests.helpers import scalar_first as sp

# What `equinox.error_if` raises at run time (equinox 0.13, jax 0.10): EquinoxRuntimeError
# (eager, vmap, grad, equinox.filter_jit); under jax.jit, JAX's runtime error or, once the
# function is compiled and called through JAX's C++ fast path, a ValueError "INTERNAL:
# CpuCallback error" — both carrying "_EquinoxRuntimeError: <message>".
RUNTIME = eqx.EquinoxRuntimeError


def raises_in_jit(match):
    """The run-time error of a check under `jax.jit` (not a trace-time ValueError: its message
    is equinox's)."""
    return pytest.raises(
        (jax.errors.JaxRuntimeError, ValueError), match=r"EquinoxRuntimeError: " + match
    )


NAN = float("nan")
E = np.eye(3)
Q1 = np.array([1.0, 0, 0, 0])
V = np.array([0.3, -0.2, 0.5])
AXES = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 0, 1.0]])  # (m, e, n): classical ZXZ


def raises_everywhere(f, args, match):
    """`f(*args)` raises ValueError at once (concrete input), and the run-time error of the check
    under jax.jit and under vmap (in equinox.filter_jit), each matching `match` (a regex naming
    the argument)."""
    with pytest.raises(ValueError, match=match) as info:
        f(*args)
    assert "Callback" not in str(info.value)  # raised by the check itself, not at run time
    with raises_in_jit(match):
        jax.block_until_ready(jax.jit(f)(*args))
    batched = [jnp.stack([jnp.asarray(a), jnp.asarray(a)]) for a in args]
    with pytest.raises(RUNTIME, match=match):
        jax.block_until_ready(eqx.filter_jit(jax.vmap(f))(*batched))


# ------------------------------------------------------------------------- non-finite input

NONFINITE = {
    # rotation matrices
    "so3.log": (so3.log, (np.full((3, 3), NAN),), "P must be a finite rotation matrix"),
    "so3.distance": (so3.distance, (E, E + [[0, 0, np.inf]] * 3), "P2 must be a finite"),
    "so3.angular_velocity": (so3.angular_velocity, (E * NAN, E), "P must be finite"),
    "so3.angular_velocity P_dot": (so3.angular_velocity, (E, E * NAN), "P_dot must be finite"),
    "so3.project": (so3.project, (E * NAN,), "A must be finite"),
    "quat.from_matrix": (
        quat.from_matrix,
        (np.full((3, 3), np.inf),),
        "P must be a finite rotation matrix",
    ),
    "euler.from_matrix": (euler.from_matrix, (E * NAN,), "P must be a finite"),
    "euler.davenport_from_matrix": (
        lambda P: euler.davenport_from_matrix(P, AXES),
        (E * NAN,),
        "P must be a finite",
    ),
    "gibbs.from_matrix": (gibbs.from_matrix, (E * NAN,), "P must be a finite"),
    "mrp.from_matrix": (mrp.from_matrix, (E * NAN,), "P must be a finite"),
    "andoyer.to_andoyer P": (andoyer.to_andoyer, (V, E * NAN), "P must be a finite"),
    # quaternions
    "quat.normalize": (quat.normalize, ([NAN, 0, 0, 1],), r"q must be a finite quaternion"),
    "quat.to_matrix": (quat.to_matrix, ([np.inf, 0, 0, 1],), r"q must be a finite quaternion"),
    "quat.rotate": (quat.rotate, ([NAN, 0, 0, 1], V), r"q must be a finite quaternion"),
    "quat.inv": (quat.inv, ([1, NAN, 0, 0],), r"q must be a finite quaternion"),
    "quat.to_rotvec": (quat.to_rotvec, ([1, 0, np.inf, 0],), r"q must be a finite quaternion"),
    "quat.angle": (quat.angle, ([1, 0, 0, NAN],), r"q must be a finite quaternion"),
    "quat.to_cayley_klein": (quat.to_cayley_klein, ([NAN, 0, 0, 1],), "q must be a finite"),
    "quat.to_su2": (quat.to_su2, ([NAN, 0, 0, 1],), "q must be a finite"),
    "quat.from_cayley_klein": (quat.from_cayley_klein, (np.eye(2) * NAN,), "U must be finite"),
    "quat.slerp a": (quat.slerp, ([NAN, 0, 0, 1], Q1, 0.5), "a must be a finite quaternion"),
    "quat.slerp b": (quat.slerp, (Q1, [NAN, 0, 0, 1], 0.5), "b must be a finite quaternion"),
    "quat.slerp t": (quat.slerp, (Q1, Q1, NAN), "t must be finite"),
    "quat.mean q": (quat.mean, ([Q1, [NAN, 0, 0, 1]],), "q must be a finite quaternion"),
    "quat.mean weights": (quat.mean, ([Q1, Q1], [1.0, NAN]), "weights must be finite"),
    "euler.from_quat": (euler.from_quat, ([NAN, 0, 0, 1],), "q must be a finite quaternion"),
    "euler.davenport_from_quat": (
        lambda q: euler.davenport_from_quat(q, AXES),
        ([NAN, 0, 0, 1],),
        "q must be a finite quaternion",
    ),
    "gibbs.from_quat": (gibbs.from_quat, ([NAN, 0, 0, 1],), "q must be a finite quaternion"),
    "mrp.from_quat": (mrp.from_quat, ([NAN, 0, 0, 1],), "q must be a finite quaternion"),
    # rotation vectors and other vector parametrisations
    "quat.from_rotvec": (quat.from_rotvec, ([np.inf, 0, 0],), "theta must be finite"),
    "so3.compose phi": (so3.compose, ([NAN, 0, 0], V), "phi must be finite"),
    "so3.compose psi": (so3.compose, (V, [NAN, 0, 0]), "psi must be finite"),
    "gibbs.to_quat": (gibbs.to_quat, ([NAN, 0, 0],), "g must be finite"),
    "gibbs.to_matrix": (gibbs.to_matrix, ([np.inf, 0, 0],), "g must be finite"),
    "mrp.to_quat": (mrp.to_quat, ([NAN, 0, 0],), "p must be finite"),
    "mrp.to_matrix": (mrp.to_matrix, ([np.inf, 0, 0],), "p must be finite"),
    # (these named an internal quaternion q, or a half turn, or returned NaN)
    "mrp.rotate": (mrp.rotate, ([NAN, 0, 0], V), "p must be finite"),
    "mrp.compose p2": (mrp.compose, (V, [np.inf, 0, 0]), "p2 must be finite"),
    "gibbs.rotate": (gibbs.rotate, ([NAN, 0, 0], V), "g must be finite"),
    "gibbs.compose g1": (gibbs.compose, ([NAN, 0, 0], V), "g1 must be finite"),
    "andoyer.to_andoyer M_body": (andoyer.to_andoyer, ([NAN, 1, 0], E), "M_body must be finite"),
    # angles
    "euler.to_quat": (euler.to_quat, ([0.1, NAN, 0.3],), "angles must be finite"),
    "euler.to_matrix": (euler.to_matrix, ([0.1, np.inf, 0.3],), "angles must be finite"),
    "euler.davenport_to_matrix": (
        lambda a: euler.davenport_to_matrix(a, AXES),
        ([0.1, NAN, 0.3],),
        "angles must be finite",
    ),
    "euler.rates_to_omega angles": (euler.rates_to_omega, ([NAN, 1, 0], V), "angles must be"),
    "euler.rates_to_omega rates": (euler.rates_to_omega, (V, [NAN, 1, 0]), "rates must be"),
    "euler.omega_to_rates omega": (euler.omega_to_rates, (V, [NAN, 1, 0]), "omega must be"),
    "andoyer.from_andoyer l": (
        andoyer.from_andoyer,
        (0.5, 1.0, 0.2, NAN, 0.1, 0.2),
        "l must be finite",
    ),
    "andoyer.from_andoyer L": (
        andoyer.from_andoyer,
        (NAN, 1.0, 0.2, 0.3, 0.1, 0.2),
        "L must be finite",
    ),
    "andoyer.momentum": (andoyer.momentum, (0.5, np.inf, 0.3), "G must be finite"),
    "andoyer.space_momentum": (andoyer.space_momentum, (1.0, 0.5, NAN), "h must be finite"),
    "andoyer.gamma": (andoyer.gamma, (0.5, 1.0, 0.2, 0.3, NAN), "g must be finite"),
}


@pytest.mark.parametrize("case", list(NONFINITE), ids=list(NONFINITE))
def test_nonfinite_input_is_an_error_naming_the_argument(case):
    f, args, match = NONFINITE[case]
    args = tuple(np.asarray(a, float) for a in args)
    raises_everywhere(f, args, match)


def test_nonfinite_error_shows_the_value_and_where():
    q = np.array([Q1, Q1, [1.0, 0, NAN, 0]])
    with pytest.raises(ValueError, match=r"q must be a finite .*got q\[2\] = \[ ?1\., 0\., nan"):
        quat.to_rotvec(q)
    with pytest.raises(ValueError, match=r"angles must be finite, got angles\[1\] = \[.*inf"):
        euler.to_matrix(np.array([[0.0, 0, 0], [0.0, np.inf, 0]]))


# ------------------------------------------------------------------------- improper matrices

IMPROPER = {
    "reflection": np.diag([1.0, 1.0, -1.0]),
    "inversion": -E,
    "zero": np.zeros((3, 3)),
    "ones": np.ones((3, 3)),  # det 0: so3.log gave [0, 0, 0] before
    "rank 2": np.array([[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0]]),
    "left-handed noisy": Rotation.from_rotvec([0.3, -1.0, 2.0]).as_matrix() @ np.diag([1, -1, 1])
    + 1e-9,
}

TAKES_A_ROTATION = {
    "so3.log": (so3.log, "P"),
    "so3.distance P1": (lambda P: so3.distance(P, E), "P1"),
    "so3.distance P2": (lambda P: so3.distance(E, P), "P2"),
    "quat.from_matrix": (quat.from_matrix, "P"),
    "euler.from_matrix": (lambda P: euler.from_matrix(P, "zyx"), "P"),
    "euler.davenport_from_matrix": (lambda P: euler.davenport_from_matrix(P, AXES), "P"),
    "gibbs.from_matrix": (gibbs.from_matrix, "P"),
    "mrp.from_matrix": (mrp.from_matrix, "P"),
    "andoyer.to_andoyer": (lambda P: andoyer.to_andoyer(V, P), "P"),
}


@pytest.mark.parametrize("fn", list(TAKES_A_ROTATION))
def test_improper_matrix_is_an_error(fn):
    f, name = TAKES_A_ROTATION[fn]
    msg = name + r" is not a rotation matrix: non-positive determinant"
    for P in IMPROPER.values():
        with pytest.raises(ValueError, match=msg + r".*: det " + name + " = "):
            f(P)
    # traced: one representative (a compile per case would only repeat it)
    with raises_in_jit(msg + r".*negate one axis"):
        jax.block_until_ready(jax.jit(f)(IMPROPER["reflection"]))
    # the concrete error names the offending element of a batch
    batch = np.stack([E, E, IMPROPER["ones"]])
    with pytest.raises(ValueError, match=r"det " + name + r"\[2\] = 0"):
        f(batch)


def test_log_of_a_non_rotation():
    """`so3.log(ones((3, 3)))` was silently [0, 0, 0]; now an error, also under vmap and grad
    (an eager grad knows the value: the ValueError with it, at once)."""
    raises_everywhere(so3.log, (np.ones((3, 3)),), "P is not a rotation matrix")
    for d in (jax.grad(lambda P: so3.log(P).sum()), jax.jacfwd(so3.log), jax.jacrev(so3.log)):
        with pytest.raises(ValueError, match=r"P is not a rotation matrix.*: det P = 0 for P"):
            d(jnp.ones((3, 3)))
    with raises_in_jit("P is not a rotation matrix"):
        jax.block_until_ready(jax.jit(jax.grad(lambda P: so3.log(P).sum()))(jnp.ones((3, 3))))
    with pytest.raises(RUNTIME, match=r"P is not a rotation matrix"):
        jax.block_until_ready(jax.vmap(so3.log)(jnp.stack([jnp.eye(3), -jnp.eye(3)])))


def test_matrices_with_positive_determinant_are_orthogonalised_as_scipy(rng):
    """det > 0 matrices that are not orthogonal give the quaternion of their nearest rotation
    (SciPy: the polar factor U Vᵀ), from rounding-level drift to gross distortion."""
    R = Rotation.random(32, random_state=rng)
    A = rng.normal(size=(32, 3, 3))
    distort = {
        "drift 1e-9": np.eye(3) + 1e-9 * rng.normal(size=(32, 3, 3)),
        "drift 1e-5": np.eye(3) + 1e-5 * rng.normal(size=(32, 3, 3)),
        "stretched": A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(3),  # polar factor: R itself
        "distorted": np.eye(3) + 0.3 * rng.normal(size=(32, 3, 3)),
    }
    for name, D in distort.items():
        M = R.as_matrix() @ D
        M = M[np.linalg.det(M) > 0]
        want = Rotation.from_matrix(M).as_quat(canonical=True)[:, [3, 0, 1, 2]]
        np.testing.assert_allclose(quat.from_matrix(M), want, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(
            so3.log(M), Rotation.from_matrix(M).as_rotvec(), atol=1e-11, err_msg=name
        )
    for M in (2 * E, np.diag([1.0, 2.0, 3.0]), np.array([[1.0, 1, 1], [0, 1, 1], [0, 0, 1]])):
        want = Rotation.from_matrix(M).as_quat(canonical=True)[[3, 0, 1, 2]]
        np.testing.assert_allclose(quat.from_matrix(M), want, atol=1e-12)
    # exact rotations keep the exact construction (no iteration): bit-identical to before
    P = R.as_matrix()
    np.testing.assert_array_equal(quat.from_matrix(P), quat.from_matrix(P, assume_valid=True))


def test_orthogonalisation_derivative_is_consistent():
    """The derivative of `log(P)` at a rotation is that of the function that orthogonalises:
    zero along `P S` (S symmetric), and equal to central differences in any direction."""
    P = jnp.asarray(Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix())
    S = jnp.array([[0.3, 0.1, -0.2], [0.1, -0.5, 0.4], [-0.2, 0.4, 0.9]])
    D = jnp.asarray(np.random.default_rng(3).normal(size=(3, 3)))
    h = 1e-6

    @jax.jit
    def run(P):
        return (
            jax.jvp(so3.log, (P,), (P @ S,))[1],
            jax.jvp(so3.log, (P,), (D,))[1],
            (so3.log(P + h * D) - so3.log(P - h * D)) / (2 * h),
            jnp.einsum("ijk,jk->i", jax.jacrev(so3.log)(P), D),
        )

    along_sym, d, fd, rev = run(P)
    np.testing.assert_allclose(along_sym, 0, atol=1e-13)
    np.testing.assert_allclose(d, fd, atol=1e-8)
    np.testing.assert_allclose(rev, d, atol=1e-13)


# ------------------------------------------------------------------------- zero quaternions

TAKES_A_QUATERNION = {
    "quat.normalize": (quat.normalize, "q"),
    "quat.to_matrix": (quat.to_matrix, "q"),
    "quat.rotate": (lambda q: quat.rotate(q, V), "q"),
    "quat.inv": (quat.inv, "q"),
    "quat.to_rotvec": (quat.to_rotvec, "q"),
    "quat.angle": (quat.angle, "q"),
    "quat.to_cayley_klein": (quat.to_cayley_klein, "q"),
    "quat.to_su2": (quat.to_su2, "q"),
    "quat.slerp a": (lambda q: quat.slerp(q, Q1, 0.3), "a"),
    "quat.slerp b": (lambda q: quat.slerp(Q1, q, 0.3), "b"),
    "quat.mean": (lambda q: quat.mean(jnp.stack([jnp.asarray(Q1), q])), "q"),
    "euler.from_quat": (lambda q: euler.from_quat(q, "ZYX"), "q"),
    "euler.davenport_from_quat": (lambda q: euler.davenport_from_quat(q, AXES), "q"),
    "gibbs.from_quat": (gibbs.from_quat, "q"),
    "mrp.from_quat": (mrp.from_quat, "q"),
}


@pytest.mark.parametrize("fn", list(TAKES_A_QUATERNION))
def test_zero_quaternion_is_a_value_error_naming_the_argument(fn):
    """A ValueError on concrete input (these raised equinox's runtime error before, or returned
    a silent 0); the same message under jit and vmap."""
    f, name = TAKES_A_QUATERNION[fn]
    raises_everywhere(f, (np.zeros(4),), name + " is a zero quaternion, which is no rotation")
    with pytest.raises(ValueError, match=rf"{name}(\[1\])? = \[0\., 0\., 0\., 0\.\].*identity"):
        f(np.zeros(4))


@pytest.mark.parametrize("fn", [k for k in TAKES_A_QUATERNION if k != "quat.mean"])
def test_a_float32_quaternion_whose_square_norm_leaves_the_range(fn):
    """Non-zero and finite, but |q|² overflows float32 (2e19) or is subnormal (1e-20), which XLA
    flushes to 0: NaN, inf or the identity came back silently. A ValueError naming q (eagerly,
    no compile). (`quat.mean`'s case stacks a float64 key: float64, in range.)"""
    f, name = TAKES_A_QUATERNION[fn]
    q = np.array([0.8, 0.2, -0.5, 0.26], np.float32)
    for s in (2e19, 1e-20):
        with pytest.raises(ValueError, match=rf"\|{name}\|² is out of its float range"):
            f(np.float32(s) * q)


def test_non_unit_quaternions_stand_for_their_direction():
    """Non-zero quaternions of any length are the rotation q/|q| (SciPy's convention): no error."""
    q = np.array([0.3, -1.0, 2.0, 0.5])
    u = q / np.linalg.norm(q)
    np.testing.assert_allclose(quat.to_matrix(3 * q), quat.to_matrix(u), atol=1e-15)
    np.testing.assert_allclose(quat.to_rotvec(1e-3 * q), quat.to_rotvec(u), atol=1e-15)
    np.testing.assert_allclose(euler.from_quat(7 * q), euler.from_quat(u), atol=1e-14)


def test_cayley_klein_without_rotation_part():
    U = 1j * np.eye(2)  # α = δ = i: projection (λ0, λ1, λ2, λ3) = 0
    raises_everywhere(quat.from_cayley_klein, (U,), "U has no rotation part")
    with pytest.raises(ValueError, match="U has no rotation part"):
        quat.from_su2(np.zeros((2, 2)))


def test_gibbs_half_turn_names_the_argument():
    raises_everywhere(gibbs.from_quat, (np.array([0.0, 0.6, 0, -0.8]),), r"q is a rotation by χ")
    with pytest.raises(ValueError, match=r"P is a rotation by χ = π \(λ0 = 0 in .*MRP"):
        gibbs.from_matrix(np.diag([-1.0, 1.0, -1.0]))


# ------------------------------------------------------------------------- quat.mean weights


def test_mean_rejects_bad_weights_and_empty_sets():
    q = np.array([Q1, [0.9, 0.1, 0, 0], [0.9, 0, 0.1, 0]])
    raises_everywhere(quat.mean, (q, np.array([1.0, -0.5, 1.0])), "weights must be non-negative")
    raises_everywhere(quat.mean, (q, np.zeros(3)), "weights must not all be zero")
    with pytest.raises(ValueError, match=r"weights\[1\] = -0\.5"):
        quat.mean(q, np.array([1.0, -0.5, 1.0]))
    # a batch of sets: one set without weight is named
    with pytest.raises(ValueError, match=r"not all be zero in a set, got weights\[1\] = \[0"):
        quat.mean(np.stack([q, q]), np.array([[1.0, 1, 1], [0, 0, 0]]))
    # zero weights for some rotations are fine (they are left out)
    m = quat.mean(q, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(m, Q1, atol=1e-15)
    with pytest.raises(ValueError, match=r"q must hold at least one rotation.*shape \(0, 4\)"):
        quat.mean(np.zeros((0, 4)))
    with pytest.raises(ValueError, match=r"q must hold at least one rotation"):
        jax.jit(quat.mean)(jnp.zeros((3, 0, 4)))
    with pytest.raises(ValueError, match=r"weights must have shape \(\.\.\., N\) with N = 3"):
        quat.mean(q, np.ones(4))


# ------------------------------------------------------------------------- other checks


def test_angle_projection_and_gimbal_checks_are_value_errors():
    with pytest.raises(ValueError, match=r"G must be positive.*got G = 0"):
        andoyer.from_andoyer(0.0, 0.0, 0.0, 0.1, 0.2, 0.3)
    with pytest.raises(ValueError, match=r"\|L\| must not exceed G.*L = 1\.5, G = 1"):
        andoyer.from_andoyer(1.5, 1.0, 0.0, 0.1, 0.2, 0.3)
    with pytest.raises(ValueError, match=r"\|H\| must not exceed G"):
        andoyer.space_momentum(1.0, -1.5, 0.0)
    with pytest.raises(ValueError, match=r"M_body is zero: M_body\[1\] = \[0"):
        andoyer.to_andoyer(np.array([[1.0, 0, 0], [0, 0, 0]]), E)
    with raises_in_jit(r"\|H\| must not exceed G"):
        jax.block_until_ready(jax.jit(andoyer.space_momentum)(1.0, -1.5, 0.0))
    with pytest.raises(ValueError, match=r"angles are at gimbal lock.*angles = \[ ?0\.2, 0\."):
        euler.omega_to_rates(np.array([0.2, 0.0, -0.7]), V, check=True)
    with pytest.raises(ValueError, match=r"the product P\(g1\) P\(g2\) is a rotation by χ = π"):
        gibbs.compose(np.array([2.0, 0, 0]), np.array([2.0, 0, 0]))


# ------------------------------------------------------------------------- SciPy's sign at w = 0


def test_canonical_follows_scipy_at_half_turns():
    ties = np.array(
        [
            [0.0, -1, 0, 0],
            [0.0, 0, -1, 0],
            [0.0, 0, 0, -1],
            [0.0, -0.6, 0.8, 0],
            [0.0, 0.0, -0.6, 0.8],
            [-0.0, 0.6, -0.8, 0],
            [0.0, 0, 0.6, -0.8],
            [-0.5, 0.5, -0.5, 0.5],
            [0.5, -0.5, 0.5, -0.5],
        ]
    )
    want = Rotation.from_quat(ties[:, [1, 2, 3, 0]]).as_quat(canonical=True)[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(quat.canonical(ties), want, atol=1e-15)
    np.testing.assert_allclose(quat.canonical(-ties), want, atol=1e-15)


def test_from_matrix_matches_scipy_canonical_at_180_degrees(rng):
    axes = np.concatenate(
        [
            np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, -1, 0], [0, 1, -1], [1, 0, -1]]),
            np.array([[-1.0, 1, 1], [1, -1, 1], [1, 1, -1], [-1, -1, 1]]),
            rng.normal(size=(32, 3)),
        ]
    )
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    exact = 2 * axes[:, :, None] * axes[:, None, :] - np.eye(3)  # symmetric: λ0 = 0 exactly
    for P in (exact, Rotation.from_rotvec(np.pi * axes).as_matrix()):
        want = Rotation.from_matrix(P).as_quat(canonical=True)[:, [3, 0, 1, 2]]
        q = np.asarray(quat.from_matrix(P))
        np.testing.assert_allclose(q, want, atol=1e-15)
        # the rotation vector at |θ| = π follows the same rule: first non-zero component > 0
        np.testing.assert_allclose(so3.log(P), np.pi * want[:, 1:], atol=1e-14)
        np.testing.assert_allclose(mrp.from_matrix(P), want[:, 1:], atol=1e-15)
    assert np.all(np.asarray(quat.from_matrix(exact))[:, 0] == 0)
    # and away from the ties, the same quaternion as SciPy
    P = Rotation.random(64, random_state=rng).as_matrix()
    want = Rotation.from_matrix(P).as_quat(canonical=True)[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(quat.from_matrix(P), want, atol=1e-15)


# ------------------------------------------------------------------------- valid input stays smooth

SPECIAL = np.array(
    [
        Rotation.identity().as_matrix(),
        Rotation.from_rotvec([np.pi, 0, 0]).as_matrix(),
        Rotation.from_rotvec(np.pi * np.array([0.6, 0, -0.8])).as_matrix(),
        Rotation.from_rotvec(np.pi * np.array([2.0, -3, 6]) / 7).as_matrix(),
        Rotation.from_rotvec([1e-9, 0, 0]).as_matrix(),
    ]
)


@pytest.mark.parametrize(
    "f",
    [
        so3.log,
        quat.from_matrix,
        lambda P: so3.distance(P, jnp.eye(3)),
        lambda P: euler.from_matrix(P, "ZXZ"),
        lambda P: euler.davenport_from_matrix(P, AXES),
        mrp.from_matrix,
        lambda P: andoyer.to_andoyer(jnp.array([0.3, 0.4, 1.0]), P).as_array(),
    ],
    ids=["log", "from_matrix", "distance", "euler", "davenport", "mrp", "andoyer"],
)
def test_checked_conversions_keep_finite_gradients_at_identity_and_pi(f):
    jr, jf = jax.jit(lambda P: (jax.vmap(jax.jacrev(f))(P), jax.vmap(jax.jacfwd(f))(P)))(
        jnp.asarray(SPECIAL)
    )
    assert np.all(np.isfinite(jr)) and np.all(np.isfinite(jf))
    np.testing.assert_allclose(jr, jf, rtol=1e-10, atol=1e-10)


def test_checked_quaternion_maps_keep_finite_gradients():
    qs = jnp.asarray(sp(Rotation.from_matrix(SPECIAL)))
    for f in (quat.to_rotvec, quat.angle, mrp.from_quat, quat.to_cayley_klein):
        J = jax.jit(jax.vmap(jax.jacrev(lambda q, f=f: jnp.real(f(q)))))(qs)
        assert np.all(np.isfinite(J))
    g = jax.grad(lambda t: quat.to_rotvec(quat.from_rotvec(t)).sum())(jnp.zeros(3))
    np.testing.assert_allclose(g, np.ones(3), atol=1e-15)
    g = jax.grad(lambda w: quat.mean(jnp.asarray([Q1, [0.0, 1, 0, 0]]), w)[0])(
        jnp.array([0.7, 0.3])
    )
    assert np.all(np.isfinite(g))


def test_float32_checks_and_orthogonalisation(rng):
    P = Rotation.random(8, random_state=rng).as_matrix()
    M = (P @ (np.eye(3) + 1e-3 * rng.normal(size=(8, 3, 3)))).astype(np.float32)
    want = Rotation.from_matrix(M.astype(np.float64)).as_rotvec()
    got = jax.jit(so3.log)(M)
    assert got.dtype == jnp.float32
    np.testing.assert_allclose(got, want, atol=5e-6)
    with pytest.raises(ValueError, match="non-positive determinant"):
        so3.log(np.diag([1.0, 1.0, -1.0]).astype(np.float32))
    with pytest.raises(ValueError, match="zero quaternion"):
        quat.to_rotvec(np.zeros(4, np.float32))


# ------------------------------------------------------------------------- hot path: no new checks


def _conds(f, *args):
    """Number of run-time checks (`lax.cond` of `equinox.error_if`) in the program of `f`."""
    return str(jax.make_jaxpr(f)(*args)).count(" cond[")


def test_integrator_algebra_gains_no_checks():
    q, v, P = jnp.asarray(Q1), jnp.asarray(V), jnp.eye(3)
    for f, args in [
        (quat.mul, (q, q)),
        (quat.conj, (q,)),
        (quat.canonical, (q,)),
        (so3.hat, (v,)),
        (so3.exp, (v,)),
        (so3.Z, (v,)),
        (so3.Z_inv, (v,)),
        (so3.shadow, (v,)),
        (euler.jacobian, (v,)),
        (lambda P: quat.from_matrix(P, assume_valid=True), (P,)),
        (lambda a, b: quat.retract(a, b), (q, v)),
    ]:
        assert _conds(f, *args) == 0, f
    # the one check each had (|q| > 0), now also of finiteness, is still one
    for f, args in [
        (quat.rotate, (q, v)),
        (quat.normalize, (q,)),
        (quat.to_matrix, (q,)),
        (quat.inv, (q,)),
        (so3.log, (P,)),
        (quat.from_matrix, (P,)),
        (euler.from_quat, (q,)),
    ]:
        assert _conds(f, *args) == 1, f


# ------------------------------------------------------------ batches that do not broadcast

A2, B3 = np.full((2, 3), 0.1), np.full((3, 3), 0.2)
QA2, QB3 = np.asarray(quat.from_rotvec(A2)), np.asarray(quat.from_rotvec(B3))
PA2, PB3 = np.asarray(so3.exp(A2)), np.asarray(so3.exp(B3))
MISMATCHED = {
    "so3.compose": (so3.compose, (A2, B3), r"phi \(2,\), psi \(3,\)"),
    "so3.rotate": (so3.rotate, (A2, B3), r"theta \(2,\), a \(3,\)"),
    "so3.distance": (so3.distance, (PA2, PB3), r"P1 \(2,\), P2 \(3,\)"),
    "so3.angular_velocity": (so3.angular_velocity, (PA2, PB3), r"P \(2,\), P_dot \(3,\)"),
    "quat.mul": (quat.mul, (QA2, QB3), r"a \(2,\), b \(3,\)"),
    "quat.rotate": (quat.rotate, (QA2, B3), r"q \(2,\), v \(3,\)"),
    "quat.slerp": (quat.slerp, (QA2, QA2, np.zeros(3)), r"a \(2,\), b \(2,\), t \(3,\)"),
    "euler.rates_to_omega": (euler.rates_to_omega, (A2, B3), r"angles \(2,\), rates \(3,\)"),
    "euler.omega_to_rates": (euler.omega_to_rates, (A2, B3), r"angles \(2,\), omega \(3,\)"),
}


@pytest.mark.parametrize("case", MISMATCHED, ids=list(MISMATCHED))
def test_batches_that_do_not_broadcast_are_named(case):
    """Two arguments whose leading dimensions do not broadcast: a ValueError naming both and
    their batch shapes (it was JAX's own message about `mul`, `matmul` or an einsum label)."""
    f, args, names = MISMATCHED[case]
    with pytest.raises(ValueError, match=r"do not broadcast: " + names):
        f(*args)
    # broadcasting batches still broadcast: (2, 1) against (3,) gives (2, 3)
    wide = [np.asarray(args[0])[:, None], *args[1:]]
    if case == "quat.slerp":
        wide[1] = QB3[0]  # (a (2, 1), b (), t (3,))
    out = f(*wide)
    assert out.shape[:2] == (2, 3)


def test_random_takes_an_int_shape_as_scipy():
    key = jax.random.key(0)
    np.testing.assert_array_equal(quat.random(key, 3), quat.random(key, (3,)))
    assert so3.random(key, 5).shape == (5, 3, 3)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(tol=-1.0), r"tol must be a finite number >= 0.*got -1.0"),
        (dict(tol=float("nan")), r"tol must be a finite number >= 0.*got nan"),
        (dict(max_iter=0), r"max_iter must be a positive integer, got 0"),
    ],
)
def test_rotation_spline_options_are_checked(kw, match):
    from rigidjax import RotationSpline

    with pytest.raises(ValueError, match=match):
        RotationSpline(np.arange(3.0), np.asarray(quat.from_rotvec(B3)), **kw)
