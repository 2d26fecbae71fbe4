"""The fit's memory grows like residuals × parameters, not residuals²: 10⁴ samples of gyro and
attitude data (6·10⁴ residuals) once asked for a (residuals, residuals) buffer of 28.8 GB (the
U of the rank check's SVD, allocated by JAX's LAPACK call even without `compute_uv`)."""

import re

import jax
import jax.numpy as jnp

from rigidjax import identify_inertia


def test_fit_memory_is_linear_in_the_residuals():
    """Compiled only (abstract data, nothing runs): 500 samples of both kinds, 3000 residuals
    for 12 parameters. No array of the program has two dimensions of the residuals' length,
    and XLA's scratch memory stays far below the 72 MB of one (3000, 3000) matrix."""
    T = 500
    n_res, n_par = 6 * T, 12
    args = [jax.ShapeDtypeStruct(s, jnp.float64) for s in ((T,), (T, 3), (T, 4))]
    lowered = jax.jit(lambda t, w, q: identify_inertia(t, omega_obs=w, quat_obs=q)).lower(*args)
    shapes = {
        tuple(int(d) for d in m.rstrip("x").split("x"))
        for m in re.findall(r"tensor<((?:\d+x)+)f64>", lowered.as_text())
    }
    square = [s for s in shapes if sum(d >= n_res for d in s) >= 2]
    assert not square, f"(residuals × residuals)-sized arrays in the fit: {square}"
    temp = lowered.compile().memory_analysis().temp_size_in_bytes
    # about 2 MB measured (660 bytes a residual); 4.6 MB bound, the old program took 72 MB
    assert temp < 16 * n_res * n_par * 8, f"{temp} bytes of scratch memory for {n_res} residuals"
