"""Attitude determination: the multiplicative EKF of attitude and gyro bias (`mekf`), its
one-step core (`propagate`, `update`), and the estimator in the loop of a sampled-data
controller (`estimated`)."""

from .loop import Estimated, LoopLog, control_error, estimated, knowledge_error, loop_log
from .mekf import MEKF, FilterState, mekf, propagate, update

__all__ = [
    "MEKF",
    "Estimated",
    "FilterState",
    "LoopLog",
    "control_error",
    "estimated",
    "knowledge_error",
    "loop_log",
    "mekf",
    "propagate",
    "update",
]
