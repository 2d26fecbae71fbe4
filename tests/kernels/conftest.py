"""Fixtures of the kernels' tests."""

import pytest


@pytest.fixture
def triton_modules(monkeypatch):
    """The list into which the text of each Triton module that Pallas builds goes (a private
    JAX function wrapped: skipped where this JAX lays it out otherwise)."""
    try:
        from jax._src.pallas.triton import lowering
    except ImportError as e:
        pytest.skip(f"this JAX has no Pallas Triton lowering where expected: {e}")
    modules = []
    lower = lowering.lower_jaxpr_to_triton_module

    def lower_and_keep(*args, **kwargs):
        result = lower(*args, **kwargs)
        modules.append(result.module.operation.get_asm())
        return result

    monkeypatch.setattr(lowering, "lower_jaxpr_to_triton_module", lower_and_keep)
    return modules
