"""The steps of a pipeline called one after another, each on the whole exposure in memory.

The reference the pipeline's passes (several steps over bands of a file or of
memory) are compared with: each step's own ``__call__``, as a user calling the
functions by hand would run them.
"""

from spherex_reduce import Exposure, Pipeline, read


def one_by_one(config, exposure):
    """``config`` (a mapping or a `Pipeline`) run step by step on ``exposure`` (or a path)."""
    pipe = config if isinstance(config, Pipeline) else Pipeline(config)
    current = exposure if isinstance(exposure, Exposure) else read(exposure)
    for name, params in pipe.steps:
        current = pipe.registry.step(name)(pipe.registry)(current, **params)
    return current
