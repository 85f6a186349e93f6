"""Reduction steps as plain functions (each also runs as a pipeline step)."""

from .clip import pair_difference, sigma_clip
from .dark import combine_darks, subtract_dark
from .fit_ramp import fit_ramp
from .phantom import subtract_phantom
from .reference import correct_reference
from .unchop import rechop, unchop

__all__ = [
    "combine_darks",
    "correct_reference",
    "fit_ramp",
    "pair_difference",
    "rechop",
    "sigma_clip",
    "subtract_dark",
    "subtract_phantom",
    "unchop",
]
