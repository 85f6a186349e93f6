"""spherex_reduce: simulate, reduce and measure H2RG readout noise.

Implements Heaton et al., *Noise Reduction Methods for Large-Scale Intensity
Mapping Measurements with Infrared Detector Arrays*: the readout schedule
(row chopping, reference and phantom reads), the reduction pipeline and the
spatial power-spectrum analysis.
"""

import logging

from ._version import __version__
from .core import dq
from .core.errors import ConfigError, FormatError, PluginError, SpherexReduceError, StepSkipped
from .core.exposure import Exposure, ReferenceReads
from .core.geometry import DetectorGeometry, RefBorder
from .core.schedule import ReadoutSchedule
from .io import read, write
from .reduce.integrations import reduce_integrations
from .reduce.pipeline import Pipeline
from .reduce.step import Simulator, Step, Strategy
from .reduce.steps import (
    combine_darks,
    correct_reference,
    fit_ramp,
    pair_difference,
    rechop,
    sigma_clip,
    subtract_dark,
    subtract_phantom,
    unchop,
)

logging.getLogger("spherex_reduce").addHandler(logging.NullHandler())

__all__ = [
    "ConfigError",
    "DetectorGeometry",
    "Exposure",
    "FormatError",
    "Pipeline",
    "PluginError",
    "ReadoutSchedule",
    "RefBorder",
    "ReferenceReads",
    "Simulator",
    "SpherexReduceError",
    "Step",
    "StepSkipped",
    "Strategy",
    "__version__",
    "combine_darks",
    "correct_reference",
    "dq",
    "expected_slope_variance",
    "fit_ramp",
    "pair_difference",
    "read",
    "rechop",
    "reduce_integrations",
    "sigma_clip",
    "simulate",
    "subtract_dark",
    "subtract_phantom",
    "unchop",
    "write",
]


def __getattr__(name):
    # The simulator (scipy.signal, its engine) costs ~0.4 s to import; load it only
    # when asked for, so that reducing a file does not pay for it.
    if name in ("simulate", "expected_slope_variance"):
        from . import simulation

        return getattr(simulation, name)
    raise AttributeError(f"module 'spherex_reduce' has no attribute {name!r}")
