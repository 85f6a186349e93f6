"""Reduction steps: each with its function, `Step` class and hook, and their helpers.

Steps: ``unchop`` (`unchop`, `rechop`), ``phantom`` (`subtract_phantom`),
``clipping`` (`sigma_clip`), ``dark`` (`subtract_dark`, and `combine_darks`
to make the master dark) and ``pairs`` (`pair_difference`) are one module
each.  A step with helpers of its own is a subpackage whose ``step`` module is
the step and whose other modules are its helpers: ``reference/``
(`correct_reference` and its strategies), ``fit_ramp/`` (`fit_ramp`) and
``jumps/`` (`detect_jumps`).  ``pixel_maps`` is a helper, not a step: the
per-pixel read noise, gain and dark current shared by ``fit_ramp`` and
``detect_jumps``.

Each step's module registers it with the plugin system (it is a built-in plugin,
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
