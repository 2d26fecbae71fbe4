"""How the per-body solves of a batch join into the batch's outcome."""

from __future__ import annotations

from typing import Any

import diffrax
import jax
import jax.numpy as jnp
from jaxtyping import Array


def first_failure(stats: dict[str, Array], results) -> tuple[dict[str, Array], Any]:
    """Per-body solves' `stats` (`(B,)` each) with `num_valid` the batch's (the fewest valid
    output times), and the batch's result: the failure of the body that failed first in time
    (`results (B,)`; successful if none did)."""
    valid = stats["num_valid"]
    failed = results != diffrax.RESULTS.successful
    i = jnp.argmin(jnp.where(failed, valid, jnp.iinfo(valid.dtype).max))
    return {**stats, "num_valid": jnp.min(valid)}, jax.tree.map(lambda r: r[i], results)
