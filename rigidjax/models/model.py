"""A model: one body's ODE `ẏ = f(t, y, p)` on a flat state, written once in JAX and run by
every backend (`rigidjax.models.solve`)."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

Field = Callable[[Array, Array, Array], Array]


class Model(eqx.Module):
    """One body's vector field `field(t, y (size,), p (params,)) -> ẏ (size,)`, with the state's
    unit-norm groups `unit` (`(start, length)`: a quaternion, renormalised after every step), a
    step-end map `end` (`y, changed ← end(y)` after every step and its normalisation: a shadow
    or chart switch; `changed` says where it changed the state) and `name` for messages. The
    parameters `p` are per body (moments, masses); constants the field closes over (torque
    gains) are the field's own and reach `jax.grad` as well."""

    field: Field  # a PyTree where it holds arrays (a bound method of a module)
    size: int = eqx.field(static=True)
    params: int = eqx.field(static=True)
    unit: tuple[tuple[int, int], ...] = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="model")
    jump: Field | None = None  # `y ← jump(t, y, p)` at flagged interval starts (a sample)
    record: tuple[int, int] = eqx.field(static=True, default=(0, 0))  # recorded after a jump
    end: Callable[[Array], tuple[Array, Array]] | None = None  # after every step


class TreeModel(eqx.Module):
    """A model whose state and parameters are PyTrees (`(Ω, γ, q)`, a `RigidState`, ...) for one
    body, flattened for the backends: `vf(t, y, args)` on the trees, `unit` the indices of the
    state's leaves that are unit quaternions."""

    vf: Callable  # a PyTree (its arrays, if any, are leaves)
    y_def: Any = eqx.field(static=True)  # a PyTreeDef
    y_shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    p_def: Any = eqx.field(static=True)
    p_shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    unit: tuple[int, ...] = eqx.field(static=True)
    name: str = eqx.field(static=True)
    jump_vf: Callable | None = None  # `jump(t, y, args) -> y` on the trees
    record: int | None = eqx.field(static=True, default=None)  # the leaf recorded after jumps
    end_vf: Callable | None = None  # `end(y) -> (y, changed)` on the trees, after every step

    def model(self) -> Model:
        """The flat `Model` (one per tree model: see `flat`)."""
        sizes = [math.prod(s) for s in self.y_shapes]
        starts = np.cumsum([0, *sizes])
        unit = tuple((int(starts[i]), sizes[i]) for i in self.unit)
        size, params = int(starts[-1]), sum(math.prod(s) for s in self.p_shapes)
        jump = None if self.jump_vf is None else self.jump
        record = (0, 0) if self.record is None else (int(starts[self.record]), sizes[self.record])
        # the step-end map of a copy without the field: the field may hold the tracers of a
        # transformation (traced constants, lifted for the kernels), which a map used in
        # another trace (`_modes`' forward mode) must not carry along
        bare = dataclasses.replace(self, vf=_no_field, jump_vf=None)
        end = None if self.end_vf is None else bare.end
        return Model(self.field, size, params, unit, self.name, jump, record, end)

    def unravel(self, flat: Array, which: str) -> Any:
        """The tree of a flat state (`which="y"`, last axis) or parameters (`"p"`)."""
        tree_def, shapes = (
            (self.y_def, self.y_shapes) if which == "y" else (self.p_def, self.p_shapes)
        )
        lead, out, start = flat.shape[:-1], [], 0
        for s in shapes:
            n = math.prod(s)
            out.append(flat[..., start : start + n].reshape(*lead, *s))
            start += n
        return jax.tree_util.tree_unflatten(tree_def, out)

    def field(self, t, y, p):
        return self._on_trees(self.vf, t, y, p)

    def jump(self, t, y, p):
        assert self.jump_vf is not None
        return self._on_trees(self.jump_vf, t, y, p)

    def end(self, y):
        assert self.end_vf is not None
        out, changed = self.end_vf(self.unravel(y, "y"))
        return _joined(out, y.dtype), changed

    def _on_trees(self, fn: Callable, t, y, p):
        return _joined(fn(t, self.unravel(y, "y"), self.unravel(p, "p")), y.dtype)


def _no_field(t, y, args):
    raise AssertionError("the step-end map's copy of a tree model has no field")


def _joined(tree: Any, dtype) -> Array:
    return jnp.concatenate(leaves(tree, dtype))


def leaves(tree: Any, dtype) -> list[Array]:
    """The leaves of one body's `tree`, each flattened: `[(n_i,), ...]`."""
    return [jnp.ravel(jnp.asarray(a)).astype(dtype) for a in jax.tree_util.tree_leaves(tree)]


def ravel(tree: Any, dtype) -> Array:
    """The leaves of one body's `tree`, flattened and joined: `(N,)`."""
    return jnp.concatenate([*leaves(tree, dtype), jnp.zeros((0,), dtype)])


def flat(tm: TreeModel) -> Model:
    """The flat `Model` of `tm`, kept per field and tree structure (so that the field is traced
    once, as `jax.jit` traces a function once)."""
    try:
        return _flat(tm)
    except TypeError:  # an unhashable field
        return tm.model()


@functools.lru_cache(maxsize=64)
def _flat(tm: TreeModel) -> Model:
    return tm.model()
