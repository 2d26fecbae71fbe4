"""Sampled-data attitude control: example laws `controller(t_k, Ω_k, q_k, params) -> command`
for `simulate(gyrostat, ..., controller=..., control_period=...)` (zero-order hold)."""

from .laws import BDot, QuaternionPD, bdot, quaternion_pd

__all__ = ["BDot", "QuaternionPD", "bdot", "quaternion_pd"]
