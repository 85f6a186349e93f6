"""Reduction steps: one module per step, with its function, `Step` class and hook.

Each module registers its step with the plugin system (it is a built-in plugin,
see `spherex_reduce.reduce.plugins.BUILTIN_PLUGINS`); the functions here run the step
alone, with its provenance recorded.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "clipping": ["sigma_clip"],
    "dark": ["combine_darks", "subtract_dark"],
    "fit_ramp.step": ["fit_ramp"],
    "jumps.step": ["detect_jumps"],
    "pairs": ["pair_difference"],
    "phantom": ["subtract_phantom"],
    "reference.step": ["correct_reference"],
    "unchop": ["rechop", "unchop"],
})
