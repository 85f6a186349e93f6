"""Reduction: the Step protocol, the executor, the pipeline, plugins and the steps.

Each module is imported when first used (``spherex_reduce.reduce.pipeline``
after ``import spherex_reduce.reduce``), as in every package of `spherex_reduce`.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submodules=[
    "batch", "executor", "hookspecs", "integrations", "pipeline", "plugins", "provenance",
    "scheduler", "step", "steps"])
