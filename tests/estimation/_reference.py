"""The NumPy MEKF of `benchmarks/reference/mekf_numpy.py`, loaded by path (the benchmarks are not
a package)."""

import importlib.util
from pathlib import Path

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "reference" / "mekf_numpy.py"
_spec = importlib.util.spec_from_file_location("mekf_numpy", _PATH)
assert _spec is not None and _spec.loader is not None
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)
mekf_numpy = _module.mekf_numpy
