"""quat.align_vectors against SciPy's Rotation.align_vectors: random problems, one vector pair
(parallel, antipodal, near-antipodal), infinite and zero weights, collinear sets, SciPy's errors;
gradients against central finite differences, also at a perfect fit with orthonormal vectors
(where an SVD's derivative is 0/0)."""

import warnings
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidjax import quat
from tests.helpers import fd_jacobian
from tests.rotations.test_bad_input import raises_in_jit

N = 6
# one compiled program per shape, shared by the tests (weights traced: both paths, selected)
ALIGN = jax.jit(partial(quat.align_vectors, return_sensitivity=True))
ALIGN_PAIR = jax.jit(quat.align_vectors)


def flat(a, b, w):
    q, rssd, _ = ALIGN(a, b, w)
    return jnp.concatenate([q, rssd[None]])


JAC = jax.jit(jax.jacfwd(flat, argnums=(0, 1)))


def same_rotation(q, r: Rotation, atol=1e-12):
    ref = r.as_quat(scalar_first=True)
    q = np.asarray(q)
    err = min(np.abs(q - ref).max(), np.abs(q + ref).max())
    assert err <= atol, (q, ref, err)


def scipy_align(a, b, w=None, sens=False):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "not uniquely or poorly defined"
        return Rotation.align_vectors(a, b, w, return_sensitivity=sens)


def problem(seed, noise=0.1):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(N, 3))
    b = Rotation.random(rng=rng).apply(a) + noise * rng.normal(size=(N, 3))
    return a, b, rng.uniform(0.1, 2.0, N)


def test_random_problems_match_scipy():
    for seed in range(4):
        a, b, w = problem(seed)
        q, rssd, sens = ALIGN(a, b, w)
        r, rssd_ref, sens_ref = scipy_align(a, b, w, sens=True)
        same_rotation(q, r)
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-14
        np.testing.assert_allclose(rssd, rssd_ref, rtol=1e-12)
        np.testing.assert_allclose(sens, sens_ref, rtol=1e-10, atol=1e-13)
        # it maps b onto a: the rotation applied to b is a's best fit
        np.testing.assert_allclose(quat.rotate(q, b), r.apply(b), atol=1e-12)


def test_scipy_docstring_examples():
    a = [[0, 1, 0], [0, 1, 1], [0, 1, 1]]
    b = [[1, 0, 0], [1, 1.1, 0], [1, 0.9, 0]]
    pad = [[0.0, 0, 0]] * 3  # padded to N pairs with zero weights: the compiled ALIGN

    def align(a, b, w):  # arrays, not lists: lists are pytrees to jax.jit (another program)
        return ALIGN(np.array(a, float), np.array(b, float), np.array(w, float))

    q, rssd, sens = align(a + pad, b + pad, [1.0, 1, 1, 0, 0, 0])
    np.testing.assert_allclose(quat.to_matrix(q), [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(rssd, 0.141421356237308, rtol=1e-12)
    np.testing.assert_allclose(2 * sens, [[0.2, 0, 0], [0, 1.5, 1], [0, 1, 1]], atol=1e-12)
    q, _, _ = align(
        [[0, 1, 0], [0, 1, 1], *pad, [0, 0, 1]],
        [[1, 0, 0], [1, 2, 0], *pad, [1, 1, 1]],
        [np.inf, 1, 0, 0, 0, 0],
    )
    np.testing.assert_allclose(quat.to_matrix(q), [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)


PAIRS = [
    ([1, 0, 0], [0, 1, 0]),
    ([1, 0, 0], [-1, 0, 0]),  # antipodal: SciPy's half-turn axis
    ([0, 0, 2], [0, 0, -1]),
    ([0.3, -0.5, 0.8], [-0.3, 0.5, -0.8]),
    ([0.3, 0.2, -1], [-0.3, -0.2, 1 + 1e-7]),  # near-antipodal
    ([1, 2, 3], [1, 2, 3]),  # parallel
    ([1, 2, 3], [2, 4, 6.000001]),
    ([1, 2, 3], [-3, 0.5, 2]),
    ([1, 2, 3], [-1, -2, 3]),
]


def test_one_vector_pair():
    for a, b in PAIRS:
        q, rssd = ALIGN_PAIR(np.asarray(a, float), np.asarray(b, float))
        r, rssd_ref = scipy_align(a, b)
        same_rotation(q, r, atol=1e-9)
        np.testing.assert_allclose(rssd, rssd_ref, atol=1e-12)
        ua, ub = np.asarray(a) / np.linalg.norm(a), np.asarray(b) / np.linalg.norm(b)
        np.testing.assert_allclose(quat.rotate(q, ub), ua, atol=1e-12)
    # antipodal primary (infinite weight, the others weight 0): finite derivatives
    a = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1]])
    w = np.array([np.inf, 0, 0, 0, 0, 0])
    Ja, Jb = JAC(a, -a, w)
    assert np.all(np.isfinite(Ja)) and np.all(np.isfinite(Jb))
    same_rotation(ALIGN(a, -a, w)[0], scipy_align(a[0], -a[0])[0])


def test_infinite_and_zero_weights():
    a, b, w = problem(7, noise=0.2)
    for k in (0, 3):
        wk = w.copy()
        wk[k] = np.inf
        wk[(k + 1) % N] = 0.0
        q, rssd, sens = ALIGN(a, b, wk)
        assert np.all(np.isnan(sens))
        r, rssd_ref = scipy_align(a, b, wk)
        same_rotation(q, r, atol=1e-12)
        np.testing.assert_allclose(rssd, rssd_ref, rtol=1e-12)
        # the primary pair is aligned exactly
        ua, ub = a[k] / np.linalg.norm(a[k]), b[k] / np.linalg.norm(b[k])
        np.testing.assert_allclose(quat.rotate(q, ub), ua, atol=1e-13)
    # a zero weight leaves its pair out; an inf weight with only zero weights: no turn
    wz = w.copy()
    wz[2] = 0.0
    q, rssd, _ = ALIGN(a, b, wz)
    r, rssd_ref = scipy_align(np.delete(a, 2, 0), np.delete(b, 2, 0), np.delete(wz, 2))
    same_rotation(q, r)
    np.testing.assert_allclose(rssd, rssd_ref, rtol=1e-12)
    wi = np.zeros(N)
    wi[1] = np.inf
    q, rssd, _ = ALIGN(a, b, wi)
    same_rotation(q, scipy_align(a, b, wi)[0], atol=1e-12)
    assert rssd == 0.0


def test_degenerate_sets():
    """Collinear vectors and all-zero weights: no unique optimum; the optimal rotation closest
    to the identity (SciPy's SVD picks one arbitrarily: rssd compared), finite gradients."""
    a = np.array([[1.0, 0, 0], [2, 0, 0], [-0.5, 0, 0], [3, 0, 0], [1, 0, 0], [-1, 0, 0]])
    b = np.array([[0.0, 1, 0], [0, 3, 0], [0, -1, 0], [0, 1, 0], [0, 2, 0], [0, -1, 0]])
    w = np.ones(N)
    q, rssd, _ = ALIGN(a, b, w)
    np.testing.assert_allclose(rssd, scipy_align(a, b)[1], rtol=1e-12)
    q_pair, _ = ALIGN_PAIR(np.array([1.0, 0, 0]), np.array([0.0, 1, 0]))  # the minimal y → x
    np.testing.assert_allclose(q, q_pair, atol=1e-12)
    Ja, Jb = JAC(a, b, w)
    assert np.all(np.isfinite(Ja)) and np.all(np.isfinite(Jb))
    q0, rssd0, _ = ALIGN(a, b, np.zeros(N))
    np.testing.assert_array_equal(q0, [1, 0, 0, 0])
    same_rotation(q0, scipy_align(a, b, np.zeros(N))[0])
    assert rssd0 == 0.0
    # b = a: the identity, exactly fitted
    a = problem(2)[0]
    q1, rssd1, _ = ALIGN(a, a, w)
    np.testing.assert_allclose(q1, [1, 0, 0, 0], atol=1e-15)
    assert rssd1 == 0.0


def test_gradients_match_finite_differences():
    """q (4) and rssd with respect to a and b: noisy, exact fit with orthonormal vectors (B = 2R,
    three equal singular values: the q-method's gap is still 4), an infinite weight."""
    for case in ("noisy", "exact_orthonormal", "inf_weight"):
        a, b, w = problem(11)
        if case == "exact_orthonormal":
            a = np.concatenate([np.eye(3), np.eye(3)])
            b = Rotation.from_rotvec([0.3, -0.2, 0.5]).inv().apply(a)
            w = np.ones(N)
        if case == "inf_weight":
            w[2] = np.inf
        J_a, J_b = JAC(a, b, w)
        fd_a = fd_jacobian(lambda x, b=b, w=w: flat(x, b, w), a)
        fd_b = fd_jacobian(lambda x, a=a, w=w: flat(a, x, w), b)
        np.testing.assert_allclose(J_a.reshape(5, 3 * N), fd_a, atol=2e-7, err_msg=case)
        np.testing.assert_allclose(J_b.reshape(5, 3 * N), fd_b, atol=2e-7, err_msg=case)


@pytest.mark.slow
def test_reverse_mode_and_weight_gradients():
    a, b, w = problem(12)
    J_a = JAC(a, b, w)[0]
    np.testing.assert_allclose(jax.jit(jax.jacrev(flat))(a, b, w), J_a, atol=1e-12)
    g = jax.jit(jax.jacfwd(flat, argnums=2))(a, b, w)
    np.testing.assert_allclose(g, fd_jacobian(lambda w: flat(a, b, w), w), atol=2e-7)
    # eager (concrete weights) equals compiled
    J = jax.jacfwd(lambda x: quat.align_vectors(x, b, w)[0])(jnp.asarray(a))
    np.testing.assert_allclose(J, J_a[:4], atol=1e-12)


@pytest.mark.slow
def test_concrete_weights_and_pairs():
    """Concrete weights choose one path in Python: the same results as the compiled ALIGN."""
    a, b, w = problem(4)
    for wk in (w, np.where(np.arange(N) == 1, np.inf, w)):
        q, rssd = quat.align_vectors(a, b, wk)
        q_ref, rssd_ref, _ = ALIGN(a, b, wk)
        np.testing.assert_allclose(q, q_ref, atol=1e-14)
        np.testing.assert_allclose(rssd, rssd_ref, atol=1e-14)
    q1, rssd1 = quat.align_vectors(a, b)
    r1, rssd1_ref = scipy_align(a, b)
    same_rotation(q1, r1)
    np.testing.assert_allclose(rssd1, rssd1_ref, rtol=1e-12)
    for x, y in PAIRS:  # (1, 3) arrays and a weight: the weight in the rssd (SciPy's)
        q2, rssd2 = quat.align_vectors([x], [y], [2.0])
        # atol: a component ~1e-10 of a nearly antiparallel pair differs by rounding between
        # the compiled and the eager (quick-compiled) program (measured 4e-10)
        q2_ref = ALIGN_PAIR(np.asarray(x, float), np.asarray(y, float))[0]
        np.testing.assert_allclose(q2, q2_ref, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(rssd2, scipy_align([x], [y], [2.0])[1], atol=1e-12)
    J = jax.jacfwd(lambda x: quat.align_vectors(x, -x)[0])(jnp.array([1.0, 0, 0]))
    assert np.all(np.isfinite(J))


@pytest.mark.slow
def test_vmap_over_problems():
    a, b, w = problem(3)
    A = np.stack([a, 2 * a, -a])
    B = np.stack([b, b, b])
    q, rssd = jax.vmap(quat.align_vectors, in_axes=(0, 0, None))(A, B, w)
    for k in range(3):
        qk, rk = quat.align_vectors(A[k], B[k], w)
        np.testing.assert_allclose(q[k], qk, atol=1e-14)
        np.testing.assert_allclose(rssd[k], rk, atol=1e-14)


def _dominant_problem(seed, near):
    """Two pairs, weights (1e10, 1), the primary vectors `near` from antiparallel."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(2, 3))
    a[0] /= np.linalg.norm(a[0])
    b = rng.normal(size=(2, 3))
    b[0] = -a[0] + near * rng.normal(size=3)
    return a, b, np.array([1e10, 1.0])


def test_dominant_weight_matches_scipy():
    """Weights (1e10, 1), primary vectors nearly antiparallel (issue 26: the q-method was off by
    2.7e-6 from SciPy): SciPy's own numbers, concrete and traced weights, though SciPy's SVD of
    B loses the light pair at eps * 1e10 (measured here up to 4e-6 rad from the optimum)."""
    for seed, near in enumerate((1e-1, 1e-3, 1e-5, 1e-7, 0.0)):
        a, b, w = _dominant_problem(seed, near)
        for align in (quat.align_vectors, ALIGN_PAIR):
            same_rotation(align(a, b, w)[0], scipy_align(a, b, w)[0], atol=1e-9)
    # the sensitivity from the singular values, as SciPy's (from λ_max, (λ_max² − |B|²)/2
    # cancelled: 6e-7 to 2e-6 relative at weights (1e10, 1, 1), measured); a third pair
    for seed in range(4):
        a, b, w = _dominant_problem(seed, 1e-3)
        a, b, w = np.vstack([a, a[1:] + 1]), np.vstack([b, b[1:] - 1]), np.append(w, 1.0)
        sens = quat.align_vectors(a, b, w, return_sensitivity=True)[2]
        ref = scipy_align(a, b, w, sens=True)[2]
        np.testing.assert_allclose(sens, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_dominant_weight_refined_matches_exact_references():
    """`refine=True` at weights (1e10, 1): the optimum itself. References: (i) data fitted
    exactly by a known rotation (half-turn minus `near` about an axis ⟂ b_0, SciPy's
    from_rotvec), whose optimum is that rotation at any weights; (ii) noisy data: SciPy with the
    weight 1e10 made infinite (exact, Magner's constrained solution), which moves the optimum by
    about w_2/w_1 = 1e-10."""
    refined = jax.jit(partial(quat.align_vectors, refine=True))
    for seed, near in enumerate((1e-1, 1e-3, 1e-5, 1e-7, 0.0)):
        a, b, w = _dominant_problem(seed, near)
        axis = np.cross(b[0], [0.3, -0.5, 0.8])
        truth = Rotation.from_rotvec((np.pi - near) * axis / np.linalg.norm(axis))
        exact = truth.apply(b)
        for align in (partial(quat.align_vectors, refine=True), refined):  # concrete, traced w
            same_rotation(align(exact, b, w)[0], truth, atol=1e-12)
            same_rotation(align(a, b, w)[0], scipy_align(a, b, [np.inf, 1.0])[0], atol=1e-9)
        # without refine: SciPy's rounding, measured larger than 1e-9 in some of these cases
        assert same_angle(quat.align_vectors(exact, b, w)[0], truth) < 1e-5


def same_angle(q, r: Rotation) -> float:
    ref = r.as_quat(scalar_first=True)
    return 2 * float(np.arcsin(min(1.0, np.linalg.norm(quat.mul(quat.conj(ref), q)[1:]))))


@pytest.mark.slow  # ~15 s
def test_dominant_weight_gradient_matches_finite_differences():
    """The optimum's derivative, with and without `refine` (SciPy's value is rounding noise at
    eps * 1e10 around the optimum: no finite differences of it)."""
    a, b, w = _dominant_problem(7, 1e-3)
    J = {
        refine: np.asarray(
            jax.jit(jax.jacfwd(lambda a, r=refine: quat.align_vectors(a, b, w, refine=r)[0]))(a)
        ).reshape(4, 6)
        for refine in (False, True)
    }
    assert np.all(np.isfinite(J[True]))
    fd = fd_jacobian(lambda x: quat.align_vectors(x, b, w, refine=True)[0], a)
    np.testing.assert_allclose(J[True], fd, atol=1e-6)
    np.testing.assert_allclose(J[False], J[True], atol=1e-14)


def test_float32():
    a, b, w = problem(5)
    q, rssd = quat.align_vectors(np.float32(a), np.float32(b), np.float32(w))
    assert q.dtype == jnp.float32 and rssd.dtype == jnp.float32
    same_rotation(q, scipy_align(a, b, w)[0], atol=1e-5)


def test_errors_are_scipys():
    a, b, _ = problem(1)
    cases = [
        ((a[:, :2], b), "Expected input `a` to have shape"),
        ((a, b[:, :2]), "Expected input `b` to have shape"),
        ((a, b[:3]), "Expected inputs `a` and `b` to have same shapes"),
        ((a[None], b[None]), "Expected input `a` to have shape"),
        ((a, b, np.ones((N, 1))), "Expected `weights` to be 1 dimensional"),
        ((a, b, np.ones(N + 1)), "Expected `weights` to have number of values"),
        ((a, b, -np.ones(N)), r"`weights` may not contain negative values, got weights\[0\]"),
        ((a, b, [np.inf, np.inf, 1, 1, 1, 1]), "Only one infinite weight is allowed"),
        (([[0, 0, 0], [1, 0, 0]], [[1, 0, 0], [0, 1, 0]], [np.inf, 1]), "zero length primary"),
        (([0, 0, 0], [1, 0, 0]), "Cannot align zero length primary vectors"),
        ((a, np.where(b == b[0, 0], np.nan, b)), r"b must be finite, got b\[0\]"),
    ]
    for args, match in cases:
        with pytest.raises(ValueError, match=match):
            quat.align_vectors(*args)
    with pytest.raises(ValueError, match="Cannot return sensitivity matrix"):
        quat.align_vectors(a[0], b[0], return_sensitivity=True)
    with pytest.raises(ValueError, match="Cannot return sensitivity matrix"):
        quat.align_vectors(a, b, [np.inf, 1, 1, 1, 1, 1], return_sensitivity=True)
    with raises_in_jit("Only one infinite weight is allowed"):
        ALIGN(a, b, jnp.array([np.inf, np.inf, 1, 1, 1, 1]))
    with raises_in_jit("`weights` may not contain negative values"):
        ALIGN(a, b, -jnp.ones(N))
