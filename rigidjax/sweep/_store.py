"""The Zarr (v3) store of a sweep: one array per observable and `status` over the design's
dimensions, chunked like the sweep; the factors as coordinates; and a group `_sweep` holding
the design's fingerprint and one done-flag per chunk, written only after the chunk's data."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import jax
import numpy as np
import zarr

from .._folders import write_problem
from .design import Design

DONE = "_sweep/done"


def check_writable(path: Path) -> None:
    """A ValueError, before any computation, if a store cannot be made and written at `path`
    (`rigidjax._folders.write_problem`: nothing is left behind)."""
    problem = write_problem(path)
    if problem is not None:
        raise ValueError(
            f"store {str(path)!r} cannot be written: {problem}; give a writable directory for "
            "the Zarr store"
        )


def refuse_foreign(path: Path) -> None:
    """A ValueError if `path` is a folder with files and no Zarr store: creating the store
    there would erase them."""
    if path.is_dir() and not (path / "zarr.json").exists() and any(path.iterdir()):
        raise ValueError(
            f"store {str(path)!r} is a folder with files and no Zarr store in it; give a new "
            "path or an empty folder (a sweep's store replaces what a folder holds)"
        )


def trailing_dims(name: str, shape: tuple[int, ...]) -> tuple[str, ...]:
    """Names of an observable's own dimensions (after the design's)."""
    return tuple(f"{name}_dim_{i}" for i in range(len(shape)))


def fill_value(dtype: np.dtype):
    return np.nan if np.issubdtype(dtype, np.inexact) else 0


def create(
    path: Path,
    design: Design,
    outputs: Mapping[str, jax.ShapeDtypeStruct],
    chunk: tuple[int, ...],
    num_chunks: int,
    meta: dict,
) -> None:
    """Lay out an empty store (every chunk missing, nothing done)."""
    g = zarr.open_group(str(path), mode="w", zarr_format=3)
    non_dim = [c for c in design.coords if c not in design.dims]
    coordinates = {"coordinates": " ".join(non_dim)} if non_dim else {}
    for name, (dims, values) in design.coords.items():
        a = g.create_array(name, shape=values.shape, dtype=values.dtype, dimension_names=dims)
        a[...] = values
    for name, s in outputs.items():
        dtype = np.dtype(s.dtype)
        a = g.create_array(
            name,
            shape=design.shape + tuple(s.shape),
            chunks=chunk + tuple(s.shape),
            dtype=dtype,
            fill_value=fill_value(dtype),
            dimension_names=design.dims + trailing_dims(name, tuple(s.shape)),
        )
        a.attrs.update(coordinates)
    status = g.create_array(
        "status",
        shape=design.shape,
        chunks=chunk,
        dtype="int8",
        fill_value=-1,
        dimension_names=design.dims,
    )
    status.attrs.update(coordinates)
    sweep = g.create_group("_sweep")
    sweep.attrs.update(meta)
    sweep.create_array("done", shape=(num_chunks,), chunks=(1,), dtype="int8", fill_value=0)


def open_existing(
    path: Path, meta: dict, chunk: tuple[int, ...] | None
) -> tuple[zarr.Group, tuple[int, ...]] | None:
    """The store at `path` and its chunk shape, if it holds a sweep with the same fingerprint
    and outputs and (when `chunk` is given) the same chunks; a ValueError if it holds another
    one, or if `path` is a folder with files and no Zarr store (which creating the store would
    erase); None if there is no store yet. Without `chunk`, the stored chunking is adopted (a
    resumed or multi-process sweep with the default chunk size uses the first call's)."""
    if not (path / "zarr.json").exists():
        refuse_foreign(path)
        return None
    g = zarr.open_group(str(path), mode="r+")
    if "_sweep" not in g:
        raise ValueError(f"store {str(path)!r} exists and is not a rigidjax sweep; give a new path")
    old = dict(g["_sweep"].attrs)
    wanted = {**meta, "chunk": old.get("chunk") if chunk is None else list(chunk)}
    for key, what in (
        ("fingerprint", "another design"),
        ("outputs", "a model with other observables"),
        ("chunk", "another chunk_size"),
    ):
        if old.get(key) != wanted[key]:
            raise ValueError(
                f"store {str(path)!r} was written for {what} ({key}: {old.get(key)} here vs "
                f"{wanted[key]}); give a new store path, or delete the old store to start over"
            )
    stored = old["chunk"]
    assert isinstance(stored, list)
    return g, tuple(int(c) for c in stored)  # type: ignore[arg-type]


def array(g: zarr.Group, name: str) -> zarr.Array:
    """The array `name` of the store's group."""
    a = g[name]
    if not isinstance(a, zarr.Array):
        raise ValueError(f"the store's {name!r} is not an array: the store is damaged")
    return a


def write_chunk(
    g: zarr.Group, k: int, block: tuple[slice, ...], values: Mapping[str, np.ndarray]
) -> None:
    """Write chunk `k` (its observables and status), then mark it done."""
    for name, v in values.items():
        array(g, name)[block] = v
    array(g, DONE)[k] = 1
