"""Reduction steps: one module per step, with its function, `Step` class and hook.

Each module registers its step with the plugin system (it is a built-in plugin,
see `spherex_reduce.reduce.plugins.BUILTIN_PLUGINS`); the functions here run the step
alone, with its provenance recorded.
"""

from .clipping import sigma_clip
from .dark import combine_darks, subtract_dark
from .fit_ramp import fit_ramp
from .pairs import pair_difference
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
