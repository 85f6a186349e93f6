"""Fourier-filter reference correction: an example ``spherex_reduce`` plugin."""

from .plugin import FourierReference, fourier_filter

__all__ = ["FourierReference", "fourier_filter"]
__version__ = "0.1.0"
