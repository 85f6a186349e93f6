"""Example spherex_reduce plugin: the ``destripe`` step."""

from .plugin import DestripeStep, destripe

__all__ = ["DestripeStep", "destripe"]
