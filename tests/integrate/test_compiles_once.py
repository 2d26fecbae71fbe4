"""An eager solve called again with the same problem reuses its compiled program: the field's
closure conversion (for the rules of `_modes.both_modes`) made a new static argument on every
call, and every eager solve on the Diffrax path was lowered and compiled again (3-8 s a call)."""

import dataclasses

import jax
import jax.numpy as jnp
import pytest

import rigidjax as rj

_LOWERED: list[str] = []
_COUNTING = [False]


def _listen(name: str, duration: float, **kwargs) -> None:
    if _COUNTING[0] and name == "/jax/core/compile/jaxpr_to_mlir_module_duration":
        _LOWERED.append(name)


jax.monitoring.register_event_duration_secs_listener(_listen)
TS = jnp.linspace(0.0, 2.0, 3)


def _omega(t):
    return jnp.array([1.0, 0.5 * jnp.sin(t), 0.2])


CALLS = {"darboux geometric": lambda: rj.darboux(_omega, TS, method="geometric")}


@pytest.mark.parametrize("call", list(CALLS))
def test_a_second_eager_call_lowers_nothing(call):
    first = jax.block_until_ready(CALLS[call]())
    _LOWERED.clear()
    _COUNTING[0] = True
    try:
        again = jax.block_until_ready(CALLS[call]())
    finally:
        _COUNTING[0] = False
    assert not _LOWERED, f"{len(_LOWERED)} program(s) lowered again"
    assert jnp.array_equal(first, again)


@dataclasses.dataclass
class _Unhashable:  # (`eq` without `hash`: no static argument of a compiled solve)
    a: float

    def __call__(self, t):
        return jnp.array([self.a, 0.5 * jnp.sin(t), 0.2])


def test_an_unhashable_callable_still_solves():
    """Converted as before (compiled for each call): the values of the same ω as a function."""
    got = rj.darboux(_Unhashable(1.0), TS, method="geometric")
    assert jnp.allclose(got, jax.block_until_ready(CALLS["darboux geometric"]()), atol=1e-14)
