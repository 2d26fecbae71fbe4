"""Models and backends: a `Model` is one body's ODE written once in JAX; `solve_model` runs it
on the CPU kernel written from it, or through Diffrax, with the same steps and numbers."""

from .model import Field, Model
from .solve import solve_model

__all__ = ["Field", "Model", "solve_model"]
