"""Inertia tensors (rigidjax.inertia) against textbook formulas, point clouds and 004's facts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rigidjax import inertia as ri
from rigidjax import so3


def _rotations(rng, n):
    """`n` random proper rotations (QR of Gaussian matrices, det fixed to +1)."""
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=-2, axis2=-1))[:, None, :]
    q[:, :, 2] *= np.sign(np.linalg.det(q))[:, None]
    return q


def _rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


# ------------------------------------------------------------------ primitives: textbook values


def test_primitives_textbook_values():
    m = np.array([1.0, 2.5, 0.3])
    r = np.array([0.5, 1.0, 2.0])
    h = np.array([2.0, 0.1, 3.0])
    size = np.array([[1.0, 2.0, 3.0], [0.2, 0.2, 5.0], [4.0, 1.0, 0.5]])

    def diag(a, b, c):
        return np.stack([np.diag([x, y, z]) for x, y, z in zip(a, b, c, strict=True)])

    expected = {
        "solid_sphere": (ri.solid_sphere(m, r), diag(*[2 / 5 * m * r**2] * 3)),
        "spherical_shell": (ri.spherical_shell(m, r), diag(*[2 / 3 * m * r**2] * 3)),
        "box": (
            ri.box(m, size),
            diag(
                m / 12 * (size[:, 1] ** 2 + size[:, 2] ** 2),
                m / 12 * (size[:, 0] ** 2 + size[:, 2] ** 2),
                m / 12 * (size[:, 0] ** 2 + size[:, 1] ** 2),
            ),
        ),
        "solid_cylinder": (
            ri.solid_cylinder(m, r, h),
            diag(m * (3 * r**2 + h**2) / 12, m * (3 * r**2 + h**2) / 12, m * r**2 / 2),
        ),
        "rod": (ri.rod(m, h), diag(m * h**2 / 12, m * h**2 / 12, 0 * m)),
        "ellipsoid": (
            ri.ellipsoid(m, size),
            diag(
                m / 5 * (size[:, 1] ** 2 + size[:, 2] ** 2),
                m / 5 * (size[:, 0] ** 2 + size[:, 2] ** 2),
                m / 5 * (size[:, 0] ** 2 + size[:, 1] ** 2),
            ),
        ),
        "solid_cone": (
            ri.solid_cone(m, r, h),
            diag(
                3 / 20 * m * r**2 + 3 / 80 * m * h**2,
                3 / 20 * m * r**2 + 3 / 80 * m * h**2,
                3 / 10 * m * r**2,
            ),
        ),
    }
    for name, (got, want) in expected.items():
        assert got.shape == (3, 3, 3), name
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=0, err_msg=name)
    # one concrete number by hand: box 1 kg, 1×2×3 m: I_xx = (4 + 9)/12
    assert float(ri.box(1.0, [1.0, 2.0, 3.0])[0, 0]) == pytest.approx(13 / 12, rel=1e-15)


def test_scalar_broadcasting_and_dtype():
    assert ri.solid_sphere(1.0, 1.0).shape == (3, 3)
    assert ri.solid_cylinder(np.ones(4), 1.0, np.ones((2, 1))).shape == (2, 4, 3, 3)
    f32 = ri.box(np.float32(2.0), np.array([1.0, 2.0, 3.0], np.float32))
    assert f32.dtype == jnp.float32
    assert ri.solid_cone(np.float32(1.0), 0.5, 2.0).dtype == jnp.float32
    assert ri.solid_sphere(1, 2).dtype == jnp.float64  # integers promoted
    with pytest.raises(ValueError, match=r"size must have shape \(\.\.\., 3\)"):
        ri.box(1.0, [1.0, 2.0])


# ------------------------------------------------------------------ point clouds


def _mid(n):
    return (np.arange(n) + 0.5) / n


def _disc(ns, nphi):
    """Equal-area points of the unit disc (midpoints in r² and φ)."""
    rr, ph = np.meshgrid(np.sqrt(_mid(ns)), 2 * np.pi * _mid(nphi), indexing="ij")
    return (rr * np.cos(ph)).ravel(), (rr * np.sin(ph)).ravel()


def _cloud_box(size, n=(40, 46, 52)):
    axes = [(_mid(k) - 0.5) * s for k, s in zip(n, size, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def _cloud_cylinder(r, h, n=(30, 60, 50)):
    x, y = _disc(n[0], n[1])
    z = (_mid(n[2]) - 0.5) * h
    shape = (x.size, z.size)
    return np.stack(
        [np.broadcast_to(r * x[:, None], shape), np.broadcast_to(r * y[:, None], shape),
         np.broadcast_to(z, shape)], -1,
    ).reshape(-1, 3)  # fmt: skip


def _cloud_cone(r, h, n=(10, 24, 400)):
    """Equal-mass points of a cone with its base at z = 0 and apex at z = h: slices of equal
    volume (distance from the apex u h with u³ uniform), each an equal-area disc."""
    x, y = _disc(n[0], n[1])
    u = _mid(n[2]) ** (1 / 3)
    X, Y = r * x[:, None] * u, r * y[:, None] * u
    return np.stack([X, Y, np.broadcast_to(h * (1 - u), X.shape)], -1).reshape(-1, 3)


def _cloud_ellipsoid(semi, n=(40, 40, 60)):
    """Equal-mass points of the unit ball (r³, cos ϑ, φ uniform) scaled by the semi-axes."""
    r, c, ph = np.meshgrid(_mid(n[0]) ** (1 / 3), 1 - 2 * _mid(n[1]), 2 * np.pi * _mid(n[2]),
                           indexing="ij")  # fmt: skip
    s = np.sqrt(1 - c**2)
    ball = np.stack([r * s * np.cos(ph), r * s * np.sin(ph), r * c], -1).reshape(-1, 3)
    return ball * np.asarray(semi)


def test_point_clouds_approximate_primitives():
    """A uniform (equal-mass, ~10⁵ points) cloud filling each body reproduces its formula."""
    m = 2.0
    size, r, h, semi = np.array([1.0, 2.0, 3.0]), 0.7, 2.0, np.array([1.0, 2.0, 3.0])
    cases = {
        "box": (_cloud_box(size), ri.box(m, size)),
        "cylinder": (_cloud_cylinder(r, h), ri.solid_cylinder(m, r, h)),
        "ellipsoid": (_cloud_ellipsoid(semi), ri.ellipsoid(m, semi)),
    }
    for name, (pts, want) in cases.items():
        assert 5e4 < len(pts) < 1.2e5
        np.testing.assert_allclose(ri.center_of_mass(1.0, pts), 0, atol=1e-12, err_msg=name)
        got = ri.point_masses(m / len(pts), pts)
        assert _rel(got, want) < 1e-3, name
    # rotated clouds give the rotated tensor, I' = P I Pᵀ
    P = _rotations(np.random.default_rng(1), 1)[0]
    pts = _cloud_box(size)
    cloud = ri.point_masses(m / len(pts), pts @ P.T)
    assert _rel(cloud, so3.rotate_tensor(P, ri.box(m, size))) < 1e-3


def test_cone_center_of_mass_and_inertia_from_point_cloud():
    m, r, h = 3.0, 0.8, 2.5
    pts = _cloud_cone(r, h)  # base at z = 0
    com = np.asarray(ri.center_of_mass(1.0, pts))
    np.testing.assert_allclose(com[:2], 0, atol=1e-12)
    assert com[2] == pytest.approx(h / 4, rel=1e-3)  # centre of mass at h/4 from the base
    assert abs(com[2] - h / 3) > 0.1  # (not the centroid of the side triangle)
    got = ri.point_masses(m / len(pts), pts - com)
    want = ri.solid_cone(m, r, h)
    assert _rel(got, want) < 1e-3
    # about the base centre: Steiner with a = h/4 along the axis
    about_base = ri.parallel_axis(want, m, [0.0, 0.0, h / 4])
    assert _rel(ri.point_masses(m / len(pts), pts), about_base) < 1e-3


# ------------------------------------------------------------------ Steiner, rotate, combine


def test_parallel_axis_against_point_masses_and_back(rng):
    masses = rng.uniform(0.1, 2.0, size=(4, 50))
    x = rng.normal(size=(4, 50, 3))
    com = np.asarray(ri.center_of_mass(masses, x))
    I_com = ri.point_masses(masses, x - com[:, None, :])
    a = rng.normal(size=(4, 3))
    M = masses.sum(-1)
    shifted = ri.parallel_axis(I_com, M, a)
    np.testing.assert_allclose(
        shifted, ri.point_masses(masses, x - com[:, None, :] - a[:, None, :]), rtol=1e-12
    )
    np.testing.assert_allclose(ri.parallel_axis(shifted, M, a, to_com=True), I_com, atol=1e-12)
    # the explicit formula Ĩ = I + m (a² E − a a), and (11.34) Ĩ_zz = I_zz + M a² for a ⊥ z
    want = np.asarray(I_com) + M[:, None, None] * (
        np.einsum("bi,bi->b", a, a)[:, None, None] * np.eye(3) - a[:, :, None] * a[:, None, :]
    )
    np.testing.assert_allclose(shifted, want, rtol=1e-12)
    a_perp = np.array([0.3, -1.2, 0.0])
    Izz = ri.parallel_axis(I_com[0], M[0], a_perp)[2, 2]
    assert float(Izz) == pytest.approx(float(I_com[0, 2, 2]) + M[0] * 1.53, rel=1e-13)


def test_combine_two_boxes_is_one_box():
    size = np.array([1.0, 2.0, 3.0])
    parts = jnp.stack([ri.box(1.5, size), ri.box(1.5, size)])
    coms = np.array([[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]]) + np.array([1.0, -2.0, 0.5])
    I, M, R = ri.combine(parts, np.array([1.5, 1.5]), coms)
    assert float(M) == 3.0
    np.testing.assert_allclose(R, [1.0, -2.0, 0.5], atol=1e-15)
    np.testing.assert_allclose(I, ri.box(3.0, [2.0, 2.0, 3.0]), rtol=1e-14)
    # unequal halves along z: 1×1×1 (mass 1) on top of 1×1×3 (mass 3) = 1×1×4 box of mass 4
    I, M, R = ri.combine(
        jnp.stack([ri.box(1.0, [1, 1, 1]), ri.box(3.0, [1, 1, 3])]),
        np.array([1.0, 3.0]),
        np.array([[0, 0, 1.5], [0, 0, -0.5]]),
    )
    np.testing.assert_allclose(R, 0, atol=1e-15)
    np.testing.assert_allclose(I, ri.box(4.0, [1.0, 1.0, 4.0]), rtol=1e-14)


def test_combine_point_parts_equals_point_masses(rng):
    masses = rng.uniform(0.5, 1.5, size=(3, 7))
    x = rng.normal(size=(3, 7, 3))
    I, M, R = ri.combine(np.zeros((3, 7, 3, 3)), masses, x)
    np.testing.assert_allclose(M, masses.sum(-1))
    np.testing.assert_allclose(R, ri.center_of_mass(masses, x))
    np.testing.assert_allclose(I, ri.point_masses(masses, x - np.asarray(R)[:, None]), rtol=1e-12)


# ------------------------------------------------------------------ principal axes


def test_principal_axes_recover_rotated_diagonal(rng):
    P = _rotations(rng, 16)
    moments = np.sort(rng.uniform(1.0, 2.0, size=(16, 3)), -1)
    I = so3.rotate_tensor(P, ri.as_tensor(moments))
    w, A = ri.principal_axes(I)
    np.testing.assert_allclose(w, moments, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.det(A), 1.0, atol=1e-12)
    # each column is ± the corresponding column of P
    cos = np.abs(np.einsum("bik,bik->bk", np.asarray(A), P))
    np.testing.assert_allclose(cos, 1.0, atol=1e-10)
    np.testing.assert_allclose(ri.from_moments_and_axes(w, A), I, atol=1e-12)
    np.testing.assert_allclose(ri.principal_moments(I), moments, rtol=1e-12)
    # some raw eigh bases were left-handed, so the det = +1 above is not luck
    assert np.any(np.linalg.det(np.asarray(jnp.linalg.eigh(I)[1])) < 0)


def test_as_tensor_shapes():
    np.testing.assert_array_equal(ri.as_tensor([1.0, 2.0, 3.0]), np.diag([1.0, 2.0, 3.0]))
    T = np.arange(9.0).reshape(3, 3)
    np.testing.assert_array_equal(ri.as_tensor(T), T)
    assert ri.as_tensor(np.ones((5, 3))).shape == (5, 3, 3)
    for bad in (np.ones(2), np.ones((3, 2)), 1.0):
        with pytest.raises(ValueError, match=r"\(\.\.\., 3\) or a tensor"):
            ri.as_tensor(bad)
    with pytest.raises(ValueError, match="positions must have shape"):
        ri.point_masses(np.ones(4), np.ones((4, 2)))


# ------------------------------------------------------------------ 004's facts


def test_triangle_inequality_for_primitives_and_clouds(rng):
    n = 32
    m = rng.uniform(0.1, 5.0, n)
    d = rng.uniform(0.01, 3.0, size=(n, 3))
    tensors = [
        ri.solid_sphere(m, d[:, 0]),
        ri.spherical_shell(m, d[:, 0]),
        ri.box(m, d),
        ri.solid_cylinder(m, d[:, 0], d[:, 1]),
        ri.rod(m, d[:, 0]),
        ri.ellipsoid(m, d),
        ri.solid_cone(m, d[:, 0], d[:, 1]),
        ri.point_masses(rng.uniform(0.1, 1.0, (n, 20)), rng.normal(size=(n, 20, 3)) * d[:, None]),
    ]
    w = np.asarray(ri.principal_moments(jnp.stack(tensors)))
    assert np.all(w[..., 2] <= (w[..., 0] + w[..., 1]) * (1 + 1e-12))
    assert np.all(w[..., 0] >= -1e-12 * w[..., 2])
    # all of them but the rod are valid for dynamics
    for k, T in enumerate(tensors):
        if k != 4:
            ri.check_inertia(T)


def test_planar_body_has_I3_equal_I1_plus_I2(rng):
    x = rng.normal(size=(10, 30, 3)) * np.array([1.0, 2.0, 0.0])
    P = _rotations(rng, 10)
    I = ri.point_masses(rng.uniform(0.1, 1.0, (10, 30)), x)
    np.testing.assert_allclose(I[:, 2, 2], I[:, 0, 0] + I[:, 1, 1], rtol=1e-15)
    w = np.asarray(ri.principal_moments(so3.rotate_tensor(P, I)))  # in general axes
    np.testing.assert_allclose(w[:, 2], w[:, 0] + w[:, 1], rtol=1e-13)
    ri.check_inertia(so3.rotate_tensor(P, I))  # equality is physical and accepted
    jax.jit(ri.check_inertia)(I).block_until_ready()


def test_collinear_body_is_a_rotator(rng):
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    t = rng.normal(size=(12,))
    masses = rng.uniform(0.1, 1.0, 12)
    I = ri.point_masses(masses, t[:, None] * n)
    w = np.asarray(ri.principal_moments(I))
    S = np.sum(masses * t**2)
    np.testing.assert_allclose(w, [0.0, S, S], atol=1e-13 * S)
    np.testing.assert_allclose(np.asarray(I) @ n, 0, atol=1e-13 * S)  # zero moment along the line
    with pytest.raises(ValueError, match="not positive definite.*rotator"):
        ri.check_inertia(I)


# ------------------------------------------------------------------ builders' own checks

_UNPHYSICAL = [
    (lambda: ri.solid_sphere(-1.0, 1.0), r"mass must be positive and finite, got -1.0"),
    (lambda: ri.spherical_shell(0.0, 1.0), r"mass must be positive and finite, got 0.0"),
    (lambda: ri.solid_sphere(1.0, -1.0), r"radius must be non-negative .*a length.*, got -1.0"),
    (lambda: ri.box(1.0, [1.0, -2.0, 3.0]), r"size must be non-negative .*got min -2.0"),
    (lambda: ri.ellipsoid(1.0, [1.0, np.nan, 3.0]), r"semi_axes must be non-negative"),
    (lambda: ri.solid_cylinder(1.0, 1.0, -0.5), r"height must be non-negative"),
    (lambda: ri.rod(-2.0, 1.0), r"mass must be positive"),
    (lambda: ri.solid_cone(1.0, -1.0, 1.0), r"radius must be non-negative"),
    (lambda: ri.point_masses([1.0, -1.0], np.ones((2, 3))), r"masses must be non-negative"),
]


@pytest.mark.parametrize("case", range(len(_UNPHYSICAL)))
def test_builders_refuse_unphysical_masses_and_lengths(case):
    """A negative mass gave a negative tensor and a negative length a valid-looking one
    (r² > 0), without a word; now a ValueError naming the argument (`equinox.error_if` under
    `jax.jit`)."""
    build, match = _UNPHYSICAL[case]
    with pytest.raises(ValueError, match=match):
        build()


def test_builders_check_traced_values_and_keep_degenerate_bodies():
    with pytest.raises(Exception, match="mass must be positive"):
        jax.block_until_ready(jax.jit(ri.solid_cylinder)(-1.0, 1.0, 1.0))
    # zero lengths are bodies still (a disc, a massless point among others)
    np.testing.assert_allclose(ri.solid_cylinder(2.0, 1.0, 0.0), np.diag([0.5, 0.5, 1.0]))
    ri.point_masses([0.0, 1.0], np.eye(3)[:2])


# ------------------------------------------------------------------ check_inertia

_ASYM = np.array([[2.0, 0.1, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]])
_TRI = np.diag([1.0, 1.0, 3.0])
_CASES = [
    (_ASYM, r"not symmetric: max\|I - I\^T\| = 0\.1", r"not symmetric .*\(I \+ I\^T\)/2"),
    (np.asarray(ri.rod(2.0, 1.0)), r"not positive definite: smallest principal moment 0 ",
     r"not positive definite"),
    (_TRI, r"triangle inequality: largest principal moment I3 = 3 exceeds I1 \+ I2 = 2 by 1",
     "triangle inequality"),
    # (the traced message said "symmetrize it" for NaN)
    (np.diag([1.0, 1.0, np.nan]), "non-finite entries; give finite moments",
     "non-finite entries \\(NaN or inf\\); give finite moments"),
]  # fmt: skip


@pytest.mark.parametrize(("I", "eager", "traced"), _CASES)
def test_check_inertia_rejects(I, eager, traced):
    with pytest.raises(ValueError, match=eager):
        ri.check_inertia(I)
    with pytest.raises(Exception, match=traced):
        jax.jit(ri.check_inertia)(I).block_until_ready()


def test_check_inertia_messages():
    with pytest.raises(ValueError, match=r"^body .*\(I \+ I\^T\)/2"):
        ri.check_inertia(_ASYM, name="body")
    # a negative moment breaks both positive definiteness and the triangle inequality
    with pytest.raises(ValueError, match="positive definite.*; and inertia violates the triangle"):
        ri.check_inertia(np.diag([-1.0, 1.0, 1.0]))
    batch = np.stack([np.eye(3), np.eye(3), _TRI, _TRI])
    with pytest.raises(ValueError, match=r"2 of 4 in the batch; first at \(2,\)"):
        ri.check_inertia(batch)
    with pytest.raises(Exception, match="triangle inequality"):
        jax.jit(jax.vmap(ri.check_inertia))(batch).block_until_ready()
    # tolerance: a relative excess of 1e-6 passes with rtol=1e-5 only
    near = np.diag([1.0, 1.0, 2.0 + 2e-6])
    ri.check_inertia(near, rtol=1e-5)
    with pytest.raises(ValueError, match="triangle"):
        ri.check_inertia(near)


def test_check_inertia_accepts_valid_and_returns_input(rng):
    P = _rotations(rng, 5)
    I = so3.rotate_tensor(P, ri.box(np.arange(1.0, 6.0), rng.uniform(0.1, 2.0, (5, 3))))
    np.testing.assert_array_equal(ri.check_inertia(I), I)
    np.testing.assert_allclose(jax.jit(ri.check_inertia)(I), I)
    np.testing.assert_allclose(jax.vmap(ri.check_inertia)(I), I)
    # float32: rounding asymmetry of P I Pᵀ is within the float32 default tolerance
    I32 = so3.rotate_tensor(P.astype(np.float32), np.asarray(I, np.float32))
    assert ri.check_inertia(I32).dtype == jnp.float32
    jax.jit(ri.check_inertia)(I32).block_until_ready()
    ri.check_inertia(ri.spherical_shell(1.0, 1.0))


# ------------------------------------------------------------------ transformations of JAX


def test_vmap_over_masses_matches_broadcasting():
    ms = jnp.linspace(0.5, 3.0, 7)
    got = jax.jit(jax.vmap(lambda m: ri.solid_cone(m, 0.4, 1.2)))(ms)
    np.testing.assert_allclose(got, ri.solid_cone(ms, 0.4, 1.2), rtol=1e-15)
    tot = jax.jit(jax.vmap(
        lambda m: ri.combine(jnp.stack([ri.box(m, [1, 1, 1]), ri.box(1.0, [1, 1, 1])]),
                             jnp.stack([m, 1.0]), jnp.array([[0.0, 0, 1], [0, 0, -1]]))[0]
    ))(ms)  # fmt: skip
    assert tot.shape == (7, 3, 3)
    # mass-weighted COM z = (m − 1)/(m + 1); about it I_xx = (m+1)/6 + 4 m/(m+1)
    np.testing.assert_allclose(tot[:, 0, 0], (ms + 1) / 6 + 4 * ms / (ms + 1), rtol=1e-14)


def test_gradients_of_moments(rng):
    def cone_moments(p):
        return ri.principal_moments(ri.solid_cone(p[0], p[1], p[2]))

    p = jnp.array([2.0, 0.5, 1.5])
    J = jax.jit(jax.jacfwd(cone_moments))(p)
    m, r, h = p
    # sorted moments: I_zz = 3/10 m r² = 0.15 < I_xx = I_yy = 3/20 m r² + 3/80 m h²
    Jz = [0.3 * r**2, 0.6 * m * r, 0.0]
    Jx = [0.15 * r**2 + 0.0375 * h**2, 0.3 * m * r, 0.075 * m * h]
    np.testing.assert_allclose(J, np.array([Jz, Jx, Jx]), rtol=1e-12)
    np.testing.assert_allclose(jax.jit(jax.jacrev(cone_moments))(p), J, rtol=1e-12)

    # repeated moments (spherical top): the moments' gradient through principal_axes is finite
    g = jax.jit(jax.grad(lambda r: ri.principal_axes(ri.solid_sphere(2.0, r))[0].sum()))(0.7)
    assert float(g) == pytest.approx(3 * 0.8 * 2.0 * 0.7, rel=1e-13)

    # w.r.t. point positions: finite and matching central differences
    masses = rng.uniform(0.5, 1.0, 6)
    x = rng.normal(size=(6, 3))

    @jax.jit
    def f(x):
        return jnp.sum(ri.principal_moments(ri.point_masses(masses, x)) ** 2)

    G = np.asarray(jax.grad(f)(x))
    assert np.all(np.isfinite(G))
    eps, k = 1e-6, (2, 1)
    dx = np.zeros_like(x)
    dx[k] = eps
    assert G[k] == pytest.approx(float(f(x + dx) - f(x - dx)) / (2 * eps), rel=1e-6)

    # Steiner and combine are differentiable in the offsets
    def steiner_xx(a):
        return ri.parallel_axis(ri.box(1.0, [1, 2, 3]), 2.0, a)[0, 0]

    gc = jax.jit(jax.grad(steiner_xx))(jnp.array([0.1, 0.2, 0.3]))
    np.testing.assert_allclose(gc, [0.0, 0.8, 1.2], rtol=1e-14)


def test_the_moments_gradient_of_a_principal_axes_body_has_no_scatter():
    """A body given by its moments keeps them as a diagonal tensor; their gradient comes back
    through slices (a pad), not `jnp.diagonal`'s scatter, which on the CPU took 2.7 ms against
    1.0 ms for 1e5 bodies."""
    from rigidjax import RigidBody

    def f(I):
        m, m_inv = RigidBody(I).operator()
        return jnp.sum(m * jnp.arange(1.0, 4.0)) + jnp.sum(m_inv)

    I = jnp.array([[1.0, 2.0, 2.5], [1.5, 2.0, 3.0]])
    program = str(jax.make_jaxpr(jax.grad(f))(I))
    assert "gather" not in program  # jnp.diagonal: a gather, transposed to a scatter
    np.testing.assert_allclose(jax.grad(f)(I), jnp.arange(1.0, 4.0) - 1 / I**2, rtol=1e-15)
