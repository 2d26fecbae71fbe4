"""How a design is cut into chunks: blocks of the design's grid that are also the Zarr chunks of
the results, so each chunk is computed, written and marked done as one unit."""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Mapping

import jax
import numpy as np

Block = tuple[slice, ...]


def block_shape(shape: tuple[int, ...], target: int) -> tuple[int, ...]:
    """The largest C-contiguous block of `shape` with at most `target` points: whole trailing
    dimensions while they fit, then part of the next one, ones before it."""
    c = [1] * len(shape)
    room = max(int(target), 1)
    for i in reversed(range(len(shape))):
        if shape[i] <= room:
            c[i] = shape[i]
            room //= shape[i]
        else:
            c[i] = room
            break
    return tuple(c)


def blocks(shape: tuple[int, ...], chunk: tuple[int, ...]) -> list[Block]:
    """Every block of the chunk grid, in C order (chunk k is `blocks(...)[k]`); edge blocks are
    cut at the design's boundary."""
    starts = itertools.product(*(range(0, n, c) for n, c in zip(shape, chunk, strict=True)))
    return [
        tuple(slice(s, min(s + c, n)) for s, c, n in zip(start, chunk, shape, strict=True))
        for start in starts
    ]


def flat_indices(shape: tuple[int, ...], block: Block) -> np.ndarray:
    """The flattened (C-order) indices of the points of `block`, in C order within it."""
    ranges = [np.arange(s.start, s.stop) for s in block]
    return np.ravel_multi_index(np.meshgrid(*ranges, indexing="ij"), shape).reshape(-1)


def padded_size(chunk: tuple[int, ...], num_devices: int) -> int:
    """The points the compiled program takes per chunk: the block rounded up to a multiple of
    the local devices (padding repeats the block's last point)."""
    return -(-math.prod(chunk) // num_devices) * num_devices


def available_memory() -> int:
    """Bytes of physical memory available now (Linux/macOS `sysconf`), 1 GiB if unknown."""
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 1 << 30


def _nbytes(structs: Mapping[str, jax.ShapeDtypeStruct]) -> int:
    return sum(math.prod(s.shape) * np.dtype(s.dtype).itemsize for s in structs.values())


def default_chunk_size(
    outputs: Mapping[str, jax.ShapeDtypeStruct],
    point: Mapping[str, jax.ShapeDtypeStruct],
    size: int,
) -> int:
    """Points per chunk from the memory per point: the model's outputs and inputs (their shapes
    from `jax.eval_shape`) times 64 for the intermediates of its integration, within a tenth of
    the available memory, at most 2¹⁶ and at most the design."""
    per_point = _nbytes(outputs) + _nbytes(point)
    budget = available_memory() // 10
    return int(max(1, min(size, 1 << 16, budget // (64 * max(per_point, 8)))))
