"""Rotation maps: rotation tensor and vector (`so3`), quaternions (`quat`), Euler and Davenport
angles (`euler`), the Gibbs vector (`gibbs`), modified Rodrigues parameters (`mrp`) and
Andoyer–Deprit variables (`andoyer`). Pure functions with leading batch dimensions."""

from . import andoyer, euler, gibbs, mrp, quat, so3

__all__ = ["andoyer", "euler", "gibbs", "mrp", "quat", "so3"]
