"""Sampled-data attitude control: example laws `controller(t_k, Ω_k, q_k, params) -> command`
for `simulate(gyrostat, ..., controller=..., control_period=...)` (zero-order hold), and the
base of controllers with memory (`StatefulController`: a filter in the loop)."""

from .laws import BDot, QuaternionPD, bdot, quaternion_pd
from .stateful import StatefulController

__all__ = ["BDot", "QuaternionPD", "StatefulController", "bdot", "quaternion_pd"]
