"""`run`: a model of ONE design point evaluated at every point of a design, compiled once,
in fixed-size chunks split over the local devices and shared among processes, stored as it
goes and resumable."""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import numbers
import sys
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from . import _layout, _store
from .design import RESERVED, Design

__all__ = ["STATUS", "run"]

STATUS = {
    0: "ok",
    1: "nonfinite_observable",
    2: "integration_failed",
    3: "model_error",
}
"""The codes of the `status` variable (also in its attrs, as CF flags)."""

Model = Callable[[dict[str, jax.Array]], Mapping[str, jax.Array]]


def _check_design(design: Design) -> Design:
    if not isinstance(design, Design):
        raise TypeError(
            f"design must be a sweep Design (from sweep.grid or sweep.sample), got {design!r}"
        )
    return design  # its points were checked when it was made (`Design.__post_init__`)


def _point_struct(design: Design) -> dict[str, jax.ShapeDtypeStruct]:
    """One point's factors, in the default float dtype; a value finite only in float64 (the
    design's) is a ValueError here."""
    dtype = jnp.asarray(0.0).dtype  # float64 with jax_enable_x64, else float32
    for name, v in design.points.items():
        with np.errstate(over="ignore"):
            bad = ~np.isfinite(v.astype(dtype))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"design factor {name!r} overflows {np.dtype(dtype).name}, the points' dtype: "
                f"point {k} has {v[k]}; rescale the factor, or enable float64 "
                '(jax.config.update("jax_enable_x64", True))'
            )
    return {name: jax.ShapeDtypeStruct((), dtype) for name in design.points}


def _outputs(model: Model, design: Design) -> dict[str, jax.ShapeDtypeStruct]:
    """The observables' shapes and dtypes (`jax.eval_shape` of one point: nothing computed);
    a model that is not a pure JAX function of the point is a ValueError here."""
    try:
        out = jax.eval_shape(model, _point_struct(design))
    except jax.errors.ConcretizationTypeError as e:
        raise ValueError(
            "model must be a pure JAX function of the point: its outputs (and their shapes) may "
            "not depend on the point's values through Python control flow (use jnp.where / "
            f"lax.cond): {e}"
        ) from e
    if not isinstance(out, Mapping) or not out:
        raise ValueError(
            f"model(point) must return a non-empty dict of arrays (the observables), got {out!r}"
        )
    shapes = {}
    for name, s in out.items():
        if name == "result":
            continue
        if not isinstance(name, str) or not hasattr(s, "shape"):
            raise ValueError(f"model output {name!r} must be an array, got {s!r}")
        if name in design.points or name in design.dims or name in RESERVED or name[:1] == "_":
            raise ValueError(
                f"model output {name!r} clashes with a factor, a dimension of the design or a "
                f"reserved name ({', '.join(RESERVED)}, or a leading '_'): rename it"
            )
        shapes[name] = jax.ShapeDtypeStruct(tuple(s.shape), s.dtype)
    return shapes


def _evaluate(model: Model) -> Callable:
    """One point → (observables, status): 0 all finite, 1 an observable is not finite, 2 the
    model returned a failed `result` (e.g. `traj.result` of a solve with `throw=False`)."""

    def one(point):
        out = dict(model(point))
        result = out.pop("result", None)
        finite = jnp.array(True)
        for v in out.values():
            if jnp.issubdtype(v.dtype, jnp.inexact):
                finite = finite & jnp.all(jnp.isfinite(v))
        status = jnp.where(finite, 0, 1)
        if result is not None:
            if isinstance(result, type(diffrax.RESULTS.successful)):
                failed = result != diffrax.RESULTS.successful
            else:
                failed = jnp.asarray(result) != 0
            status = jnp.where(failed, 2, status)
        return out, status.astype(jnp.int8)

    return one


@functools.lru_cache(maxsize=8)
def _compiled(
    model: Model, n_pad: int, factors: tuple[str, ...], dtype: str, devices: tuple
) -> tuple[Callable, NamedSharding]:
    """`jit(vmap(model))` for `n_pad` points, sharded over `devices` (one Mesh axis "point"),
    compiled ahead of time: once per sweep, and kept for the next call with the same model and
    shapes (e.g. resuming). Returns the program and its input sharding."""
    mesh = Mesh(np.array(devices), ("point",))
    sharding = NamedSharding(mesh, PartitionSpec("point"))
    fn = jax.jit(jax.vmap(_evaluate(model)), in_shardings=sharding, out_shardings=sharding)
    batch = {k: jax.ShapeDtypeStruct((n_pad,), dtype, sharding=sharding) for k in factors}
    return fn.lower(batch).compile(), sharding


def _chunk_points(design: Design, idx: np.ndarray, n_pad: int, dtype) -> dict[str, np.ndarray]:
    take = np.concatenate([idx, np.full(n_pad - idx.size, idx[-1])])  # pad: repeat the last
    return {name: v[take].astype(dtype) for name, v in design.points.items()}


@contextlib.contextmanager
def _quiet_callbacks():
    """Silence JAX's log of a failing host callback (an `eqx.error_if` inside the model) while
    the sweep records the error itself."""
    log = logging.getLogger("jax._src.callback")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        log.setLevel(level)


def _error_message(e: Exception) -> str:
    """The message of an error raised inside a compiled model (an `eqx.error_if` message is
    wrapped in the runtime's callback traceback)."""
    text = str(e)
    key = "RuntimeError: "
    if "EquinoxRuntimeError" in text and key in text:
        return text[text.rindex(key) + len(key) :].strip().splitlines()[0]
    return f"{type(e).__name__}: {text.strip().splitlines()[0] if text.strip() else ''}"


def _one_by_one(single, design: Design, idx: np.ndarray, outputs, errors: list[str]):
    """A chunk that raised, evaluated point by point: the points that raise get status 3 and
    fill values (their errors are listed once per distinct message), the others their values."""
    outs = {
        n: np.full((idx.size, *s.shape), _store.fill_value(np.dtype(s.dtype)), s.dtype)
        for n, s in outputs.items()
    }
    status = np.full(idx.size, 3, np.int8)
    for j, i in enumerate(idx):
        point = {name: v[i] for name, v in design.points.items()}
        try:
            out, st = jax.device_get(single(point))
        except Exception as e:  # noqa: BLE001 - recorded as this point's failure
            message = _error_message(e)
            if message not in errors:
                errors.append(message)
            continue
        for n, v in out.items():
            outs[n][j] = v
        status[j] = st
    return outs, status


def _barrier(name: str) -> None:
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(f"rigidjax.sweep: {name}")


def run(
    model: Model,
    design: Design,
    *,
    store: str | Path | None = None,
    chunk_size: int | np.integer | None = None,
    progress: bool = True,
) -> xr.Dataset:
    """Evaluate `model(point) -> dict[str, array]` (a pure JAX function of ONE point, `point` a
    dict of scalars named by the factors) at every point of `design`.

    Returns an `xarray.Dataset`: the design's dimensions with the factor values as coordinates,
    one variable per observable (its own dimensions appended), `status` (int8; `STATUS`: 0 ok,
    1 an observable not finite, 2 the model's `result` output failed, 3 the model raised on the
    chunk) and provenance attrs. A model may return `result=traj.result` (a solve with
    `throw=False`) so that failed integrations are recorded per point.

    The model is `vmap`-ped and compiled once for chunks of a fixed size (`chunk_size` points,
    default from the memory per point; the last chunk padded), each chunk split over all local
    devices. With `store` (a directory), results go to a Zarr v3 store as each chunk finishes,
    a chunk is marked done only after its data are written, and calling `run` again with the
    same design and store computes only the missing chunks; the Dataset returned then reads
    its values from the store when they are used (`.load()` brings them into memory), so a
    sweep larger than memory stays bounded by the chunk. After `jax.distributed.initialize`,
    every process runs the same call and takes every `num_processes`-th chunk; each returns the
    complete Dataset (a store is required then)."""
    t0 = time.perf_counter()
    design = _check_design(design)
    if chunk_size is not None and not (
        isinstance(chunk_size, numbers.Integral)
        and not isinstance(chunk_size, bool)
        and chunk_size > 0
    ):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    path = None if store is None else Path(store)
    if path is not None:
        _store.check_writable(path)
    n_proc, pid = jax.process_count(), jax.process_index()
    if n_proc > 1 and path is None:
        raise ValueError("a multi-process sweep needs store=... (the processes share it)")
    outputs = _outputs(model, design)
    point = _point_struct(design)
    meta = {
        "fingerprint": design.fingerprint(),
        "outputs": {k: [list(s.shape), np.dtype(s.dtype).name] for k, s in outputs.items()},
    }
    requested = None if chunk_size is None else _layout.block_shape(design.shape, int(chunk_size))

    def new_chunk() -> tuple[int, ...]:
        default = _layout.default_chunk_size(outputs, point, design.size)
        return requested or _layout.block_shape(design.shape, default)

    group = None
    if path is not None:
        if pid == 0 and _store.open_existing(path, meta, requested) is None:
            chunk = new_chunk()
            blocks = _layout.blocks(design.shape, chunk)
            _store.create(path, design, outputs, chunk, len(blocks), {**meta, "chunk": list(chunk)})
        _barrier("store ready")
        opened = _store.open_existing(path, meta, requested)
        assert opened is not None
        group, chunk = opened  # every process (and a resumed call) uses the stored chunks
        blocks = _layout.blocks(design.shape, chunk)
        done = np.asarray(_store.array(group, _store.DONE)[:]).astype(bool)
        arrays = None
    else:
        chunk = new_chunk()
        blocks = _layout.blocks(design.shape, chunk)
        done = np.zeros(len(blocks), bool)
        arrays: dict[str, np.ndarray] | None = {
            name: np.full(design.shape + s.shape, _store.fill_value(np.dtype(s.dtype)), s.dtype)
            for name, s in outputs.items()
        }
        arrays["status"] = np.full(design.shape, -1, np.int8)

    todo = [k for k in range(pid, len(blocks), n_proc) if not done[k]]
    n_pad = _layout.padded_size(chunk, jax.local_device_count())
    failures = {code: 0 for code in STATUS if code}
    errors: list[str] = []
    compile_s = 0.0
    if todo:
        if progress:  # tqdm.auto: a widget in notebooks (it warns there without ipywidgets)
            from tqdm.auto import tqdm
        else:
            from tqdm import tqdm

        dtype = next(iter(point.values())).dtype
        t_compile = time.perf_counter()
        fn, sharding = _compiled(
            model, n_pad, tuple(point), np.dtype(dtype).name, tuple(jax.local_devices())
        )
        compile_s = time.perf_counter() - t_compile  # ~0 when this call found it compiled
        single = None  # point by point, compiled only if a chunk raises
        bar = tqdm(
            total=sum(math.prod(s.stop - s.start for s in blocks[k]) for k in todo),
            unit="pt",
            desc="sweep",
            disable=not progress,
            file=sys.stderr,
        )
        for k in todo:
            block = blocks[k]
            idx = _layout.flat_indices(design.shape, block)
            pts = jax.device_put(_chunk_points(design, idx, n_pad, dtype), sharding)
            bshape = tuple(s.stop - s.start for s in block)
            with _quiet_callbacks():
                try:
                    out, status = jax.device_get(fn(pts))
                except Exception:  # noqa: BLE001 - a failing point must not stop the sweep
                    single = single or jax.jit(_evaluate(model))
                    out, status = _one_by_one(single, design, idx, outputs, errors)
            values = {
                n: np.asarray(v)[: idx.size].reshape(bshape + v.shape[1:]) for n, v in out.items()
            }
            values["status"] = np.asarray(status)[: idx.size].reshape(bshape)
            if group is not None:
                _store.write_chunk(group, k, block, values)
            else:
                assert arrays is not None
                for n, v in values.items():
                    arrays[n][block] = v
            for code in failures:
                failures[code] += int(np.sum(values["status"] == code))
            bar.update(idx.size)
            bar.set_postfix(failed=sum(failures.values()))
        bar.close()

    _barrier("chunks written")
    status_attrs = {"flag_values": list(STATUS), "flag_meanings": " ".join(STATUS.values())}
    if group is not None:
        import zarr

        if pid == 0:
            status = np.asarray(_store.array(group, "status")[...])
            wall = time.perf_counter() - t0
            attrs = _provenance(design, chunk, status, errors, wall, compile_s)
            group.attrs.update(attrs)
            group["status"].attrs.update(status_attrs)
            with warnings.catch_warnings():  # xarray reads consolidated v3 metadata fine
                warnings.filterwarnings("ignore", "Consolidated metadata", UserWarning)
                zarr.consolidate_metadata(str(path))
        _barrier("store closed")
        ds = xr.open_zarr(str(path), chunks=None)  # read from the store on access
    else:
        assert arrays is not None
        ds = _dataset(design, outputs, arrays)
        ds["status"].attrs.update(status_attrs)
        wall = time.perf_counter() - t0
        ds.attrs.update(_provenance(design, chunk, arrays["status"], errors, wall, compile_s))
    if progress and pid == 0:
        failed = ", ".join(f"{n}: {c}" for n, c in ds.attrs["failures"].items() if c) or "none"
        print(
            f"sweep: {design.size} points in {ds.attrs['wall_time_s']:.3g} s; failed: {failed}",
            file=sys.stderr,
        )
    return ds


def _provenance(
    design: Design,
    chunk: tuple[int, ...],
    status: np.ndarray,
    errors: list[str],
    wall: float,
    compile_s: float,
) -> dict:
    """The attrs of a sweep's results: versions, devices, processes, time, failures by cause."""
    from .. import __version__

    attrs = {
        "rigidjax_version": __version__,
        "jax_version": jax.__version__,
        "num_devices": jax.device_count(),
        "num_processes": jax.process_count(),
        "wall_time_s": wall,
        "compile_time_s": compile_s,
        "design": design.method,
        "chunk": list(chunk),
        "failures": {STATUS[c]: int(np.sum(status == c)) for c in STATUS if c},
    }
    if errors:
        attrs["errors"] = errors
    return attrs


def _dataset(design: Design, outputs, arrays: dict[str, np.ndarray]) -> xr.Dataset:
    data = {
        name: (design.dims + _store.trailing_dims(name, tuple(s.shape)), arrays[name])
        for name, s in outputs.items()
    }
    data["status"] = (design.dims, arrays["status"])
    return xr.Dataset(data, coords=dict(design.coords))
