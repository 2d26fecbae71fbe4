"""Batched sweeps: a model of one design point evaluated over a design (`grid`, `sample`) by
`run`, compiled once, chunked over devices and processes, stored in Zarr and resumable."""

from .design import Design, grid, sample
from .run import STATUS, run

__all__ = ["STATUS", "Design", "grid", "run", "sample"]
