"""The gradient part of bench_identify.py: the cost of ``jax.grad`` through ``simulate`` over
its forward run, for simulate's adjoints and a hand-written RK4 in ``lax.scan``; loss
``c·Ω(T) + (q(T)·q_c)²`` of RK4 at T/N. The caller enables float64 first."""

from __future__ import annotations

import math

from _harness import Timing, interleaved, maxrss_mib, memory_analysis

GRAD_T = 10.0
SIM_DEFAULT_MAX_STEPS = 100_000  # simulate's default
SIM_CONFIGS = ["default", "tight", "store_all"]


def default_checkpoints(max_steps: int) -> int:
    """Checkpoints used by RecursiveCheckpointAdjoint(checkpoints=None) (equinox's rule:
    ~sqrt(2 max_steps), the fewest for which the recomputation stays O(n log n))."""
    if max_steps == 1:
        return 1
    return min(math.floor(-1.5 + math.sqrt(2 * max_steps + 0.25)) + 1, max_steps)


def make_loss(N: int, config: str):
    import diffrax
    import jax.numpy as jnp

    from rigidjax import RK4, RigidBody, simulate

    if config == "default":
        kw = {}
    elif config == "tight":
        kw = dict(max_steps=N)
    elif config == "store_all":
        kw = dict(max_steps=N, adjoint=diffrax.RecursiveCheckpointAdjoint(checkpoints=N))
    elif not config.startswith("lean_scan"):  # pragma: no cover
        raise ValueError(config)
    c = jnp.array([0.3, -0.2, 0.5])
    qc = jnp.array([0.5, 0.5, -0.5, 0.5])
    if config in ("lean_scan", "lean_scan_remat"):
        return _lean_loss(N, config == "lean_scan_remat", c, qc)

    def loss(I, w0):
        traj = simulate(
            RigidBody(I, check=False),
            w0,
            None,
            jnp.array([0.0, GRAD_T]),
            solver=RK4(),
            stepsize_controller=diffrax.ConstantStepSize(),
            dt0=GRAD_T / N,
            **kw,
        )
        return c @ traj.omega[-1] + (traj.quat[-1] @ qc) ** 2

    return loss


def _lean_loss(N: int, remat: bool, c, qc):
    """The same loss with a hand-written RK4 in ``lax.scan`` (quaternion renormalised after each
    step, as simulate does); ``remat``: ``jax.checkpoint`` on the step (stores only the state
    per step and recomputes the stages in the backward pass)."""
    import jax
    import jax.numpy as jnp

    h = GRAD_T / N

    def rhs(y, I, Iinv):
        w, q = y[:3], y[3:]
        dw = Iinv @ (-jnp.cross(w, I @ w))
        dq = 0.5 * jnp.concatenate([-(q[1:] @ w)[None], q[0] * w + jnp.cross(q[1:], w)])
        return jnp.concatenate([dw, dq])

    def loss(I, w0):
        Iinv = jnp.linalg.inv(I)

        def step(y, _):
            k1 = rhs(y, I, Iinv)
            k2 = rhs(y + h / 2 * k1, I, Iinv)
            k3 = rhs(y + h / 2 * k2, I, Iinv)
            k4 = rhs(y + h * k3, I, Iinv)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            return y.at[3:].set(y[3:] / jnp.linalg.norm(y[3:])), None

        y0 = jnp.concatenate([w0, jnp.array([1.0, 0.0, 0.0, 0.0], w0.dtype)])
        y, _ = jax.lax.scan(jax.checkpoint(step) if remat else step, y0, None, length=N)
        return c @ y[:3] + (y[3:] @ qc) ** 2

    return loss


def grad_worker(N: int, configs: list[str], repeats: int, I, w0) -> dict:
    """Forward and gradient of each config's loss at (I, w0), N steps, in this process."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    rss = dict(after_import=maxrss_mib())
    I, w0 = jnp.asarray(I), jnp.asarray(w0)
    out = {}
    timings = {}  # config -> (forward, gradient), compiled ahead of time
    for cfg in configs:
        loss = make_loss(N, cfg)
        f, g = timings[cfg] = Timing(loss, I, w0), Timing(jax.grad(loss, argnums=(0, 1)), I, w0)
        ms = {"default": SIM_DEFAULT_MAX_STEPS, "tight": N, "store_all": N}.get(cfg)
        out[cfg] = dict(
            max_steps=ms,
            checkpoints=(
                N
                if cfg in ("store_all", "lean_scan", "lean_scan_remat")
                else default_checkpoints(ms)
            ),
            forward_trace_lower_s=round(f.trace_lower_s, 3),
            forward_compile_s=round(f.compile_s, 3),
            grad_trace_lower_s=round(g.trace_lower_s, 3),
            grad_compile_s=round(g.compile_s, 3),
            forward_memory=memory_analysis(f.fn),
            grad_memory=memory_analysis(g.fn),
        )
    rss["after_compile"] = maxrss_mib()
    for f, g in timings.values():
        f.warm_up()
        g.warm_up()
    rss["after_first_runs"] = maxrss_mib()
    interleaved([t for pair in timings.values() for t in pair], repeats)
    rss["after_timing"] = maxrss_mib()
    for cfg, (f, g) in timings.items():
        out[cfg].update(
            forward_s=f.best,
            forward_s_median=f.median,
            grad_s=g.best,
            grad_s_median=g.median,
            grad_over_forward=g.best / f.best,
            grad_over_forward_median=g.median / f.median,
            forward_cpu_s=f.cpu_best,
            grad_cpu_s=g.cpu_best,
            grad_over_forward_cpu=g.cpu_best / f.cpu_best,
            forward_us_per_step=f.best / N * 1e6,
        )
    # gradient check: central finite differences of the forward program (default config)
    f, g = (t.fn for t in timings[configs[0]])
    gI, gw = g(I, w0)
    h = 1e-6
    fd_w = np.array([(f(I, w0.at[i].add(h)) - f(I, w0.at[i].add(-h))) / (2 * h) for i in range(3)])
    fd_I = np.array(
        [
            (f(I.at[i, j].add(h), w0) - f(I.at[i, j].add(-h), w0)) / (2 * h)
            for i in range(3)
            for j in range(3)
        ]
    ).reshape(3, 3)
    ad = np.concatenate([np.asarray(gI).ravel(), np.asarray(gw)])
    fd = np.concatenate([fd_I.ravel(), fd_w])
    grad_check = float(np.abs(ad - fd).max() / np.abs(fd).max())
    return dict(
        N=N,
        T=GRAD_T,
        dt=GRAD_T / N,
        configs=out,
        grad_check_max_abs_diff_vs_central_fd_rel=grad_check,
        grad_consistency_across_configs=float(
            max(
                np.abs(
                    np.concatenate([np.asarray(x).ravel() for x in timings[c][1].fn(I, w0)]) - ad
                ).max()
                for c in configs
            )
        ),
        maxrss_mib=rss,
    )
