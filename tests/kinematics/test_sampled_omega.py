"""darboux with sampled angular velocity (gyro data): interpolated inside the samples, never
extrapolated; bad samples are clear errors naming the argument."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicHermiteSpline

from rigidjax import darboux

T_S = np.linspace(0.0, 2.0, 21)
W_S = np.stack([0.3 + 0.1 * T_S, -0.2 * np.ones_like(T_S), 0.5 * np.cos(T_S)], -1)


@pytest.mark.parametrize(("lo", "hi"), [(0.0, 2.5), (-0.1, 2.0)])
def test_times_beyond_the_samples(lo, hi):
    with pytest.raises(ValueError, match=r"ts must lie within the times of the omega samples"):
        darboux((T_S, W_S), jnp.linspace(lo, hi, 4))


def test_non_finite_samples():
    bad = W_S.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"omega samples must be finite: omega samples\[7, 1\]"):
        darboux((T_S, bad), jnp.linspace(0.0, 2.0, 4))
    with pytest.raises(ValueError, match=r"omega t_samples must be strictly increasing"):
        darboux((T_S[::-1], W_S), jnp.linspace(0.0, 2.0, 4))


def test_the_sampled_interval_itself_is_fine():
    P = darboux((T_S, W_S), jnp.linspace(0.0, 2.0, 4))
    assert P.shape == (4, 3, 3) and np.all(np.isfinite(P))


def test_steps_end_at_the_samples():
    """The interpolant's second derivative jumps at the knots: the default tolerance is reached
    only when steps end there (2.3e-7 off at rtol = 1e-10 stepping across them). Reference:
    SciPy's DOP853 restarted at every knot on the same C¹ Hermite spline, and the body-frame
    Poisson equation Ṗ = P Ω×."""
    t_s = np.linspace(0.0, 6.0, 61)
    w_s = np.stack([1.3 + 0 * t_s, 0.7 * np.sin(1.3 * t_s), 0.7 * np.cos(1.3 * t_s)], -1)
    slopes = np.diff(w_s, axis=0) / np.diff(t_s)[:, None]  # backward differences, as Diffrax's
    spline = CubicHermiteSpline(t_s, w_s, np.concatenate([slopes[:1], slopes]))

    def field(t, p):
        x, y, z = spline(t)
        return (p.reshape(3, 3) @ np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])).ravel()

    p, ref = np.eye(3).ravel(), [np.eye(3)]
    for a, b in zip(t_s[:-1], t_s[1:], strict=True):
        p = solve_ivp(field, (a, b), p, method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
        ref.append(p.reshape(3, 3))
    ts = jnp.linspace(0.0, 6.0, 7)
    P = darboux((t_s, w_s), ts, frame="body", method="quat")
    np.testing.assert_allclose(P, np.array(ref)[::10], atol=2e-9)


def _sorts_in_loops(jaxpr, in_loop=False) -> int:
    """The `sort` equations of `jaxpr` inside a `while` or `scan`, nested jaxprs included."""
    count = 0
    for eqn in jaxpr.eqns:
        count += in_loop and eqn.primitive.name == "sort"
        loop = in_loop or eqn.primitive.name in ("while", "scan")
        for value in eqn.params.values():
            for sub in value if isinstance(value, tuple | list) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    count += _sorts_in_loops(inner, loop)
    return count


def test_the_sample_times_are_sorted_once():
    """Diffrax's ClipStepSizeController sorts its `step_ts` in every `diffeqsolve`, and darboux
    makes one per output interval: with an output at each sample the time was quadratic in the
    samples (1.2e4: 9 s a call, 0.75 s now). The knots are sorted once, outside the loops."""
    P = jax.make_jaxpr(lambda t, w: darboux((t, w), t, frame="body", method="quat"))
    assert _sorts_in_loops(P(jnp.asarray(T_S), jnp.asarray(W_S)).jaxpr) == 0
    # and the steps still end at the samples: the same values as the outputs every 10th sample
    every = darboux((T_S, W_S), T_S, frame="body", method="quat")
    few = darboux((T_S, W_S), T_S[::10], frame="body", method="quat")
    np.testing.assert_allclose(every[::10], few, atol=1e-12)
