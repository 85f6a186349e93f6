"""The data model below everything: geometry, schedule, exposure, flags, errors.

Each module is imported when first used (``spherex_reduce.core.dq`` after
``import spherex_reduce.core``), as in every package of `spherex_reduce`.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submodules=[
    "block", "dq", "errors", "exposure", "fields", "geometry", "limits", "parameters",
    "schedule", "source_mask"])
