"""The `rigidjax` console command."""

from .main import main

__all__ = ["main"]
