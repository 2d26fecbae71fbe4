"""rigidjax: JAX-accelerated, differentiable rigid-body rotation maps, kinematics and dynamics."""

from . import quat, so3

__all__ = ["quat", "so3"]
__version__ = "0.1.0"
