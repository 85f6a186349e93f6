"""What a plugin author uses, in one place (pluggy style).

A plugin is a module registered under the entry-point group ``spherex_reduce``
whose functions, marked with `hookimpl`, return the classes it adds: steps
(`Step` subclasses, optionally with a `Kernel` or a `Consumer` so they stream
in bands of rows), reference strategies (`Strategy` subclasses, returning
`ReferenceOffsets`) and simulators (`Simulator`).  A step declares what it does
to the noise with a `NoiseEffect` (a reference strategy with a
`ReferenceEffect`; clipping thresholds bounded by `AtLeast`, e.g.
`MEASURED_SIGMA`), so that the noise forecast can propagate it.  Parameters
are declared as `Parameter` tuples; kernels see `Block` and `Context` objects
and report `Record` objects; a reference strategy reads the reference pixels of
a side block with `reference_pixels` (``ALL``: every column parity).  The
plugin guide (``docs/plugins.rst``) shows a whole plugin.

Examples
--------
>>> from spherex_reduce.plugin import Parameter, Step, hookimpl
>>> class Scale(Step):
...     name = "scale"
...     keyword = "S_SCALE"
...     parameters = (Parameter("factor", 1.0, (float,), "multiply by this"),)
...     def run(self, exposure, factor):
...         return exposure.replace(data=exposure.data.data * factor)
>>> @hookimpl
... def register_steps():
...     return [Scale]
>>> Scale.name
'scale'
"""

from .core.block import Block, Context
from .core.parameters import Parameter
from .reduce.hookspecs import hookimpl
from .reduce.noise_effect import MEASURED_SIGMA, AtLeast, NoiseEffect, ReferenceEffect
from .reduce.step import Consumer, Kernel, Record, Simulator, Step, Strategy
from .reduce.steps.reference.strategies import ALL, ReferenceOffsets, reference_pixels

__all__ = [
    "ALL",
    "MEASURED_SIGMA",
    "AtLeast",
    "Block",
    "Consumer",
    "Context",
    "Kernel",
    "NoiseEffect",
    "Parameter",
    "Record",
    "ReferenceEffect",
    "ReferenceOffsets",
    "Simulator",
    "Step",
    "Strategy",
    "hookimpl",
    "reference_pixels",
]
