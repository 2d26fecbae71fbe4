"""How the per-body solves of a batch join into the batch's outcome."""

from __future__ import annotations

import math
from typing import Any

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._checks import is_concrete


@jax.jit
def first_failure(stats: dict[str, Array], results) -> tuple[dict[str, Array], Any]:
    """Per-body solves' `stats` (`(B,)` each) with `num_valid` the batch's (the fewest valid
    output times) and `failed_body` the index of the body that failed first in time (for the
    error message: popped before the stats reach a trajectory), and the batch's result: that
    body's failure (`results (B,)`; successful if none failed). One compiled program."""
    valid = stats["num_valid"]
    failed = results != diffrax.RESULTS.successful
    i = jnp.argmin(jnp.where(failed, valid, jnp.iinfo(valid.dtype).max))
    result = jax.tree.map(lambda r: r[i], results)
    return {**stats, "num_valid": jnp.min(valid), "failed_body": i}, result


def failed_body(
    batch: tuple[int, ...], first: Array | None, states: Array | None = None
) -> str | None:
    """Which body of a batch of concrete solves failed, in words ("body 7 of 100", "body
    (1, 2) of the batch of shape (2, 3)"): the body that failed first (`first`,
    `first_failure`'s `failed_body`, for per-body solves), else the first body whose state at
    the failed output time (`states (B, ...)`) is non-finite; None for one body, traced values,
    or a batch that failed as one (a lockstep solve out of steps)."""
    if first is None and states is not None and is_concrete(states):
        bad = ~jnp.all(jnp.isfinite(states.reshape(states.shape[0], -1)), axis=-1)
        first = jnp.argmax(bad) if bool(jnp.any(bad)) else None
    if math.prod(batch) < 2 or first is None or not is_concrete(first):
        return None
    if len(batch) == 1:
        return f"body {int(first)} of {batch[0]}"
    where = tuple(int(i) for i in np.unravel_index(int(first), batch))
    return f"body {where} of the batch of shape {batch}"
