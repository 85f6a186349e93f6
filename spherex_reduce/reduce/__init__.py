"""Reduction: the Step protocol, the executor, the pipeline, plugins and the steps.

Its modules are attached lazily (``lazy_loader``): ``spherex_reduce.reduce.pipeline``
works after ``import spherex_reduce.reduce`` and imports the module then.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submodules=[
    "batch", "executor", "hookspecs", "integrations", "options", "passes", "pipeline", "plugins",
    "provenance", "scheduler", "step", "steps"])
