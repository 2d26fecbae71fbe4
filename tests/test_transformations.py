"""Every public rotation map under every JAX transformation (issue 34): a matrix generated from
the modules' `__all__`, so that a new public function is covered without anyone adding it here.

For each function the inputs are built from `ARGS` (by argument name; per module and per
function overrides first). A function whose required argument has no entry fails
`test_every_public_function_is_covered` (and each of its cases) until it gets one, or a reason
in `EXCLUDED` (only for functions that do not map arrays to arrays). Each case must give the
eager value: to rounding in float64 (`jit` on arguments, `jit` and `equinox.filter_jit` of a
function that captures the arrays as constants, `vmap`, nested `vmap`, a `lax.scan` body using
captured arrays); `grad`, `jacfwd` and `jacrev` of a scalar reduction agree with each other and
with eager central differences along a tangent of the inputs' manifold (unit quaternions,
rotation matrices); float32 inputs give float32 within 1e-5 of the float64 value.
"""

from __future__ import annotations

import functools
import inspect
import types
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigidjax.rotations as rotations

# The vmap, scan and derivative cases are compiled with XLA:CPU's classic emitters at LLVM's
# lowest level (rigidjax._compile.SMALL_PROGRAM): 2-5x faster to compile these small programs,
# the same trace. `jit_captured` is the plain `jax.jit` of the issue.
quick_jit = functools.partial(
    jax.jit,
    compiler_options={"xla_cpu_use_fusion_emitters": False, "xla_backend_optimization_level": 0},
)

# The modules whose public functions are maps of arrays: every rotation module of
# `rigidjax.rotations.__all__` (so a new module there is covered too).
MODULES: dict[str, types.ModuleType] = {
    name: getattr(rotations, name)
    for name in rotations.__all__
    if isinstance(getattr(rotations, name), types.ModuleType)
}

# Public names that are not maps of arrays to arrays, with the reason.
EXCLUDED: dict[str, str] = {
    "interop.from_scipy": "takes a SciPy Rotation object",
    "interop.to_scipy": "returns a SciPy Rotation object",
    "interop.from_jaxlie": "takes a jaxlie SO3 object",
    "interop.to_jaxlie": "returns a jaxlie SO3 object",
    "quat.identity": "no array argument (a shape and a dtype)",
    "groups.rotation_group": "no array argument (a group name and an axis)",
    "cayley_klein.pauli": "no array argument (a dtype)",
    "euler.gimbal_tol": "maps a dtype to a Python float",
    "andoyer.AndoyerVariables": "a NamedTuple of the six variables: no computation",
}

# Classes are called through a function of arrays.
CALLS: dict[str, Callable[..., Any]] = {
    "slerp.Slerp": lambda ts, q, t: rotations.Slerp(ts, q)(t),
    "spline.RotationSpline": lambda ts, q, t: rotations.RotationSpline(ts, q)(t),
}


# ---------------------------------------------------------------------------------------------
# Inputs: a kind of argument draws a valid value and moves it along its manifold.


def _normalize(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _exp(v):
    """Rodrigues' formula in NumPy (float64)."""
    a = np.linalg.norm(v)
    K = _hat(v)
    if a < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(a) / a * K + (1 - np.cos(a)) / a**2 * K @ K


def _su2(q):
    w, x, y, z = q
    return np.array([[w - 1j * z, -y - 1j * x], [y - 1j * x, w + 1j * z]])


@dataclass(frozen=True)
class Kind:
    """How to draw an argument; `real` ones are differentiated (a tangent `d` at `x`, and the
    curve `x(eps)` through `x` with that tangent, for central differences)."""

    sample: Callable[[np.random.Generator], Any]
    role: str = "real"  # "real" | "complex" | "key" | "static"
    curve: Callable[[np.ndarray, np.ndarray, float], np.ndarray] = lambda x, d, e: x + e * d
    tangent: Callable[[np.ndarray, np.ndarray], np.ndarray] = lambda x, d: d
    direction: Callable[[np.random.Generator, np.ndarray], np.ndarray] = lambda rng, x: rng.normal(
        size=np.shape(x)
    )


def real(sample):
    return Kind(sample)


def _rotvec(rng):
    return _normalize(rng.normal(size=3)) * rng.uniform(0.3, 2.5)


UNIT = dict(
    curve=lambda x, d, e: _normalize(x + e * d),
    tangent=lambda x, d: d - x * np.sum(x * d, axis=-1, keepdims=True),
)
ROTVEC = real(_rotvec)
VEC = real(lambda rng: rng.normal(size=3))
SMALL_VEC = real(lambda rng: 0.4 * rng.normal(size=3) / np.sqrt(3))
QUAT = Kind(lambda rng: _normalize(rng.normal(size=4)), **UNIT)
QUATS = Kind(lambda rng: _normalize(rng.normal(size=(3, 4))), **UNIT)
ROTMAT = Kind(
    lambda rng: _exp(_rotvec(rng)),
    curve=lambda x, d, e: x @ _exp(e * d),
    tangent=lambda x, d: x @ _hat(d),
    direction=lambda rng, x: rng.normal(size=3),
)
MAT = real(lambda rng: rng.normal(size=(3, 3)))
NEAR_ROTMAT = real(lambda rng: _exp(_rotvec(rng)) + 0.05 * rng.normal(size=(3, 3)))
SYM4 = Kind(
    lambda rng: (lambda Q: Q @ np.diag([1.0, 2.0, 3.5, 5.0]) @ Q.T)(
        np.linalg.qr(rng.normal(size=(4, 4)))[0]
    ),
    direction=lambda rng, x: (lambda a: a + a.T)(rng.normal(size=(4, 4))),
)
ANGLES = real(lambda rng: np.array([rng.uniform(-3, 3), rng.uniform(0.5, 2.5), rng.uniform(-3, 3)]))
ANGLE = real(lambda rng: np.asarray(rng.uniform(-3, 3)))
FRACTION = real(lambda rng: np.asarray(rng.uniform(0.1, 0.9)))
TIMES = real(lambda rng: np.concatenate([[0.0], np.cumsum(rng.uniform(0.8, 1.2, size=2))]))
VECS = real(lambda rng: rng.normal(size=(3, 3)))
MOMENTS = real(lambda rng: np.array([1.0, 2.0, 2.5]) + rng.uniform(0, 0.2, size=3))
PROJECTION = real(lambda rng: np.asarray(rng.uniform(-0.8, 0.8)))  # |L|, |H| < G
SU2 = Kind(lambda rng: _su2(_normalize(rng.normal(size=4))), role="complex")
SIGMA = Kind(lambda rng: np.einsum("i,ijk->ijk", rng.normal(size=3), _PAULI).sum(0), "complex")
KEY = Kind(lambda rng: jax.random.key(int(rng.integers(2**31))), role="key")
_PAULI = np.array([[[0, 1], [1, 0]], [[0, -1j], [1j, 0]], [[1, 0], [0, -1]]])


def _andoyer6(rng):
    return np.array(
        [
            rng.uniform(-0.8, 0.8),
            rng.uniform(1.2, 1.6),
            rng.uniform(-0.8, 0.8),
            *rng.uniform(-3, 3, size=3),
        ]
    )


ARGS: dict[str, Kind] = {
    "theta": ROTVEC,
    "phi": ROTVEC,
    "psi": ROTVEC,
    "delta": SMALL_VEC,
    "v": VEC,
    "r": VEC,
    "rates": VEC,
    "omega": VEC,
    "M_body": VEC,
    "q": QUAT,
    "q_ref": QUAT,
    "a": QUAT,
    "b": QUAT,
    "P": ROTMAT,
    "P1": ROTMAT,
    "P2": ROTMAT,
    "A": MAT,
    "P_dot": MAT,
    "T": MAT,
    "angles": ANGLES,
    "g": SMALL_VEC,
    "g1": SMALL_VEC,
    "g2": SMALL_VEC,
    "p": SMALL_VEC,
    "p1": SMALL_VEC,
    "p2": SMALL_VEC,
    "t": FRACTION,
    "U": SU2,
    "S": SIGMA,
    "key": KEY,
    "inertia": MOMENTS,
    "av": real(_andoyer6),
    "L": PROJECTION,
    "G": real(lambda rng: np.asarray(rng.uniform(1.2, 1.6))),
    "H": PROJECTION,
    "l": ANGLE,
    "h": ANGLE,
}
MODULE_ARGS: dict[str, dict[str, Kind]] = {
    "andoyer": {"g": ANGLE},
    "davenport": {"axes": Kind(lambda rng: np.eye(3)[[2, 0, 2]], role="static")},
}
FUNCTION_ARGS: dict[str, dict[str, Kind]] = {
    "so3.rotate": {"a": VEC},
    "so3.project": {"A": NEAR_ROTMAT},
    "quat.continuous": {"q": QUATS},
    "average.mean": {"q": QUATS},
    "average.top_eigvec": {"M": SYM4},
    "align.align_vectors": {"a": VECS, "b": VECS},
    "powers.power": {"p": real(lambda rng: np.asarray(rng.uniform(0.3, 1.7)))},
    "slerp.key_frames": {"ts": TIMES, "q": QUATS},
    "slerp.Slerp": {"ts": TIMES, "q": QUATS, "t": real(lambda rng: np.asarray(1.3))},
    "spline.RotationSpline": {"ts": TIMES, "q": QUATS, "t": real(lambda rng: np.asarray(1.3))},
}


def _public_functions() -> dict[str, Any]:
    """`module.name` -> the object, once per object (named by the module that defines it)."""
    found: dict[int, tuple[str, Any]] = {}
    for modname, mod in MODULES.items():
        for name in mod.__all__:
            obj = getattr(mod, name)
            if isinstance(obj, types.ModuleType) or not callable(obj):
                continue  # constants, type aliases
            if isinstance(obj, type) and f"{modname}.{name}" not in CALLS:
                if getattr(obj, "__module__", None) != mod.__name__:
                    continue  # a class imported for annotations
            defining = getattr(obj, "__module__", None) == mod.__name__
            if id(obj) not in found or defining:
                found[id(obj)] = (f"{modname}.{name}", obj)
    return dict(sorted(found.values(), key=lambda kv: kv[0]))


FUNCTIONS = _public_functions()
TESTED = [name for name in FUNCTIONS if name not in EXCLUDED]


@dataclass
class Case:
    """A function of its array arguments (static ones bound) and its samples."""

    fn: Callable[..., Any]
    kinds: list[Kind]
    samples: list[list[Any]]  # 4 samples, each the list of array arguments

    @property
    def x(self):
        return self.samples[0]

    def stacked(self, n):
        return [jnp.stack(xs) for xs in zip(*self.samples[:n], strict=True)]

    @property
    def real_args(self):
        return [i for i, k in enumerate(self.kinds) if k.role == "real"]


@functools.cache
def case_of(name: str) -> Case:
    obj = FUNCTIONS[name]
    modname = name.split(".")[0]
    fn = CALLS.get(name, obj)
    table = {**ARGS, **MODULE_ARGS.get(modname, {}), **FUNCTION_ARGS.get(name, {})}
    array_names, kinds, static = [], [], {}
    for p in inspect.signature(fn).parameters.values():
        if p.default is not inspect.Parameter.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue  # optional arguments keep their defaults
        if p.name not in table:
            raise LookupError(
                f"{name}: no input for its argument {p.name!r}: add one to ARGS, MODULE_ARGS or "
                "FUNCTION_ARGS of tests/test_transformations.py (or a reason to EXCLUDED if "
                f"{name} does not map arrays to arrays)"
            )
        kind = table[p.name]
        if kind.role == "static":
            static[p.name] = kind.sample(np.random.default_rng(0))
        else:
            array_names.append(p.name)
            kinds.append(kind)
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    samples = [
        [k.sample(rng) if k.role == "key" else jnp.asarray(k.sample(rng)) for k in kinds]
        for _ in range(4)
    ]

    def bound(*arrays):
        return fn(**dict(zip(array_names, arrays, strict=True)), **static)

    return Case(bound, kinds, samples)


@functools.cache
def eager(name: str, sample: int = 0):
    case = case_of(name)
    return case.fn(*case.samples[sample])


# ---------------------------------------------------------------------------------------------
# Comparisons


def assert_close(actual, expected, rtol=1e-10, atol=1e-12, what=""):
    a_leaves, a_tree = jax.tree.flatten(actual)
    e_leaves, e_tree = jax.tree.flatten(expected)
    assert a_tree == e_tree, f"{what}: structure {a_tree} != {e_tree}"
    for a, e in zip(a_leaves, e_leaves, strict=True):
        a, e = np.asarray(a), np.asarray(e)
        assert a.shape == e.shape, f"{what}: shape {a.shape} != {e.shape}"
        if np.issubdtype(e.dtype, np.inexact):
            scale = max(1.0, float(np.max(np.abs(e), initial=0.0)))
            np.testing.assert_allclose(a, e, rtol=rtol, atol=atol * scale, err_msg=what)
        else:
            np.testing.assert_array_equal(a, e, err_msg=what)


def stack_eager(name, indices, shape):
    outs = [eager(name, i) for i in indices]
    return jax.tree.map(lambda *xs: jnp.stack(xs).reshape(*shape, *xs[0].shape), *outs)


# ---------------------------------------------------------------------------------------------
# Derivatives of a scalar reduction of the outputs


def _float_leaves(out):
    return [x for x in jax.tree.leaves(out) if jnp.issubdtype(jnp.result_type(x), jnp.inexact)]


class Reduction:
    """`s(real args)`: the float outputs weighted by fixed random numbers and summed (real and
    imaginary parts), the other arguments held at their first sample. `applies` is False where
    nothing is differentiable (no real float argument, or no float output)."""

    def __init__(self, name):
        self.name = name
        self.case = case_of(name)
        self.idx = self.case.real_args
        leaves = _float_leaves(eager(name))
        self.applies = bool(self.idx and leaves)
        rng = np.random.default_rng(zlib.crc32(name.encode()) + 1)
        self.weights = [
            (rng.normal(size=np.shape(x)), rng.normal(size=np.shape(x))) for x in leaves
        ]

    def _args(self, reals):
        args = list(self.case.x)
        for i, r in zip(self.idx, reals, strict=True):
            args[i] = r
        return args

    def __call__(self, *reals):
        total = 0.0
        leaves = _float_leaves(self.case.fn(*self._args(reals)))
        for x, (wr, wi) in zip(leaves, self.weights, strict=True):
            total = total + jnp.sum(wr * jnp.real(x)) + jnp.sum(wi * jnp.imag(x))
        return total

    def eager_numpy(self, *reals):
        """The same sum of an eager call, in NumPy."""
        leaves = [np.asarray(x) for x in _float_leaves(self.case.fn(*self._args(reals)))]
        return sum(
            float(np.sum(wr * x.real) + np.sum(wi * x.imag))
            for x, (wr, wi) in zip(leaves, self.weights, strict=True)
        )

    @property
    def reals(self):
        return [self.case.x[i] for i in self.idx]

    def central_difference(self):
        """The directional derivative along a tangent `t` of every real argument at once, by
        central differences of eager calls along the curve through the inputs; and `t`."""
        rng = np.random.default_rng(zlib.crc32(self.name.encode()) + 2)
        xs = [np.asarray(x) for x in self.reals]
        kinds = [self.case.kinds[i] for i in self.idx]
        ds = [k.direction(rng, x) for k, x in zip(kinds, xs, strict=True)]
        h = 1e-5

        def at(eps):
            moved = [k.curve(x, d, eps) for k, x, d in zip(kinds, xs, ds, strict=True)]
            return self.eager_numpy(*[jnp.asarray(x) for x in moved])

        tangents = [k.tangent(x, d) for k, x, d in zip(kinds, xs, ds, strict=True)]
        return (at(h) - at(-h)) / (2 * h), tangents


# ---------------------------------------------------------------------------------------------
# The cases. Those under a trace (`jit` on arguments, `vmap`, nested `vmap`, a `scan` body and
# the derivatives) are compiled as one program per function (where that fails, case by case, to
# name the failing ones); `jit` on captured constants, `filter_jit` and float32 run on their own.


def traced_cases(name) -> dict[str, tuple[Callable[..., Any], Any, Callable[[Any], None]]]:
    """label -> (program, its inputs, the check of its output)."""
    case = case_of(name)
    x0 = case.x
    two, four = case.stacked(2), case.stacked(4)
    four = [x.reshape(2, 2, *x.shape[1:]) for x in four]

    def scan(_):
        def body(carry, _):
            return carry, case.fn(*x0)  # arrays captured from outside the body

        return jax.lax.scan(body, 0, None, length=2)[1]

    def check_scan(out):
        assert_close(out, stack_eager(name, [0, 0], (2,)), what="captured arguments")

    cases = {
        "jit": (lambda x: case.fn(*x), x0, lambda out: assert_close(out, eager(name))),
        "vmap": (
            lambda x: jax.vmap(case.fn)(*x),
            two,
            lambda out: assert_close(out, stack_eager(name, [0, 1], (2,))),
        ),
        "vmap_nested": (
            lambda x: jax.vmap(jax.vmap(case.fn))(*x),
            four,
            lambda out: assert_close(out, stack_eager(name, [0, 1, 2, 3], (2, 2))),
        ),
        "scan": (scan, (), check_scan),
    }
    s = Reduction(name)
    if s.applies:
        fd: list[Any] = []
        results: dict[str, Any] = {}

        def check_derivative(mode):
            def check(out):
                if not fd:
                    fd.extend(s.central_difference())
                value, tangents = fd
                along = sum(
                    float(np.sum(np.asarray(g) * t)) for g, t in zip(out, tangents, strict=True)
                )
                scale = max(1.0, abs(value), *(float(np.max(np.abs(g))) for g in out))
                assert abs(along - value) <= 1e-6 * scale, (
                    f"along a tangent {along!r}, central differences {value!r}"
                )
                for other, theirs in results.items():
                    assert_close(out, theirs, rtol=1e-8, atol=1e-10, what=f"{mode} vs {other}")
                results[mode] = out

            return check

        argnums = tuple(range(len(s.idx)))
        for mode, transform in (("grad", jax.grad), ("jacfwd", jax.jacfwd), ("jacrev", jax.jacrev)):
            program = functools.partial(lambda t, x: t(s, argnums=argnums)(*x), transform)
            cases[mode] = (program, s.reals, check_derivative(mode))
    return cases


def run_traced(name, failures):
    cases = traced_cases(name)
    try:
        outs = quick_jit(lambda inputs: {k: cases[k][0](x) for k, x in inputs.items()})(
            {k: c[1] for k, c in cases.items()}
        )
    except Exception:  # find the failing ones
        outs = {}
        for label, (program, inputs, _) in cases.items():
            try:
                outs[label] = quick_jit(program)(inputs)
            except Exception as e:
                failures.append(_failure(name, label, e))
    for label, out in outs.items():
        try:
            cases[label][2](out)
        except Exception as e:
            failures.append(_failure(name, label, e))


def _failure(name, label, e):
    return f"{name} [{label}]: {type(e).__name__}: {str(e).strip()[:600]}"


def case_eager(name):
    out = eager(name)
    for leaf in _float_leaves(out):
        assert np.all(np.isfinite(np.asarray(leaf))), "non-finite eager value"


def case_jit_captured(name):
    case = case_of(name)
    x = case.x
    assert_close(jax.jit(lambda: case.fn(*x))(), eager(name))


def case_filter_jit(name):
    """`equinox.filter_jit` of a function that captures the arrays (the issue's pattern; with
    traced arguments it is `jit`'s trace)."""
    case = case_of(name)
    x = case.x
    assert_close(eqx.filter_jit(lambda: case.fn(*x))(), eager(name))


def case_float32(name):
    case = case_of(name)
    low = {"real": jnp.float32, "complex": jnp.complex64}
    x32 = [
        x.astype(low[k.role]) if k.role in low else x
        for k, x in zip(case.kinds, case.x, strict=True)
    ]
    out32 = case.fn(*x32)
    for leaf in _float_leaves(out32):
        assert leaf.dtype in (jnp.float32, jnp.complex64), f"float32 in, {leaf.dtype} out"
    assert_close(out32, eager(name), rtol=1e-5, atol=1e-5)


CASES: dict[str, Callable[[str], None]] = {
    "jit_captured": case_jit_captured,
    "filter_jit": case_filter_jit,
    "float32": case_float32,
}


def test_every_public_function_is_covered():
    """Each public function of the rotation modules builds its inputs or has a reason in
    EXCLUDED; no stale entries in the tables."""
    missing = []
    for name in TESTED:
        try:
            case_of(name)
        except LookupError as e:
            missing.append(str(e))
    assert not missing, "\n".join(missing)
    assert not set(EXCLUDED) - set(FUNCTIONS), "stale EXCLUDED entries"
    assert not set(CALLS) - set(FUNCTIONS), "stale CALLS entries"
    assert not set(FUNCTION_ARGS) - set(FUNCTIONS), "stale FUNCTION_ARGS entries"
    assert len(TESTED) > 50  # the generator found the rotation maps


# the classes and Wahba's problem compile the most (10-15 s each): with the slow tests
SLOW = {"spline.RotationSpline", "align.align_vectors", "slerp.Slerp"}


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in TESTED]
)
def test_transformations(name):
    """Every case of `name`, all run (one test per function: the inputs, the eager values and
    the derivatives' references are shared), the failures reported together."""
    case = case_of(name)
    failures = []

    def run(label, check, *args):
        try:
            check(*args)
        except Exception as e:  # report every failing case, then fail
            failures.append(_failure(name, label, e))

    run("eager", case_eager, name)
    if failures:  # no reference value
        pytest.fail(failures[0])
    for label, check in CASES.items():
        if label == "float32" and not case.real_args:
            continue  # (keys only: nothing to lower)
        run(label, check, name)
    run_traced(name, failures)
    assert not failures, f"{len(failures)} case(s) failed:\n" + "\n".join(failures)
