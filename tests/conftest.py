"""Tests run in float64 (set here, never on import of rigidjax).

Hypothesis runs derandomized by default (profile "deterministic": the examples depend only on
the test, so every run and every pytest-xdist worker checks the same cases); set
HYPOTHESIS_PROFILE=explore for fresh random examples."""

import os

import jax
import numpy as np
import pytest
from hypothesis import settings

jax.config.update("jax_enable_x64", True)

settings.register_profile("deterministic", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)
