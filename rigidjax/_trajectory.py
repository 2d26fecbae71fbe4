"""The base class of every trajectory an integrator returns."""

import diffrax
import equinox as eqx
from jaxtyping import Array, Float, Int


class AbstractTrajectory(eqx.Module):
    """States at the output times `ts (T,)` of one integration, with what the solver reports:
    `stats` (`num_steps`, `num_accepted_steps`, `num_rejected_steps`, summed over the output
    intervals) and `result` (`diffrax.RESULTS.successful`, or the first failure of the solve
    when it ran with `SolveOptions(throw=False)`; the states after a failure are not valid).
    Subclasses add the states (`Trajectory.omega`, `HeavyTopTrajectory.gamma`, ...) as their
    positional fields; these three are keyword-only."""

    ts: Float[Array, " T"] = eqx.field(kw_only=True)
    stats: dict[str, Int[Array, "..."]] = eqx.field(kw_only=True)
    result: diffrax.RESULTS = eqx.field(
        kw_only=True, default_factory=lambda: diffrax.RESULTS.successful
    )

    @property
    def successful(self) -> bool:
        """Whether the solve succeeded (concrete trajectories only; under `jit` compare
        `result == diffrax.RESULTS.successful`)."""
        return bool(self.result == diffrax.RESULTS.successful)
