"""Reduction steps as plain functions (each also runs as a pipeline step)."""

from .unchop import rechop, unchop

__all__ = ["rechop", "unchop"]
