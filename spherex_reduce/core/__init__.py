"""The data model below everything: geometry, schedule, exposure, flags, errors.

Its modules are attached lazily (``lazy_loader``): ``spherex_reduce.core.dq``
works after ``import spherex_reduce.core`` and imports the module then.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submodules=[
    "block", "dq", "errors", "exposure", "fields", "geometry", "lazy_names", "limits",
    "parameters", "readout", "source_mask", "window"])
