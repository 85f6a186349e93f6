"""What a plugin author uses, in one place (pluggy style).

A plugin is a module registered under the entry-point group ``spherex_reduce``
whose functions, marked with `hookimpl`, return the classes it adds: steps
(`Step` subclasses, optionally with a `Kernel` or a `Consumer` so they stream
in bands of rows), reference strategies (`Strategy` subclasses, returning
`ReferenceOffsets`) and simulators (`Simulator`).  Parameters are declared as
`Parameter` tuples; kernels see `Block` and `Context` objects and report
`Record` objects.  The plugin guide (``docs/plugins.rst``) shows a whole plugin.

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
from .reduce.step import Consumer, Kernel, Record, Simulator, Step, Strategy
from .reduce.steps.reference.strategies import ReferenceOffsets

__all__ = [
    "Block",
    "Consumer",
    "Context",
    "Kernel",
    "Parameter",
    "Record",
    "ReferenceOffsets",
    "Simulator",
    "Step",
    "Strategy",
    "hookimpl",
]
