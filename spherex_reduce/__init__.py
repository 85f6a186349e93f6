"""spherex_reduce: simulate, reduce and measure H2RG readout noise.

Implements Heaton et al., *Noise Reduction Methods for Large-Scale Intensity
Mapping Measurements with Infrared Detector Arrays*: the readout schedule
(row chopping, reference and phantom reads), the reduction pipeline and the
spatial power-spectrum analysis.
"""

import logging

import lazy_loader as lazy

#: The public names and the module of each, imported when first used (SPEC 1,
#: `lazy_loader`): ``import spherex_reduce`` loads none of them, so a command pays
#: only for the modules it uses.
_EXPORTS = {
    "_version": ["__version__"],
    "core": ["dq"],
    "core.errors": ["ConfigError", "FormatError", "PluginError", "SpherexReduceError",
                    "StepSkipped"],
    "core.exposure": ["Exposure", "ReferenceReads"],
    "core.geometry": ["DetectorGeometry", "RefBorder"],
    "core.readout.schedule": ["ReadoutSchedule"],
    "io": ["read", "write"],
    "noise": ["expected_slope_variance"],
    "reduce.integrations": ["reduce_integrations"],
    "reduce.pipeline": ["Pipeline"],
    "reduce.step": ["Simulator", "Step", "Strategy"],
    "reduce.steps": ["combine_darks", "correct_reference", "detect_jumps", "fit_ramp",
                     "pair_difference", "rechop", "sigma_clip", "subtract_dark",
                     "subtract_phantom", "unchop"],
    "simulation": ["simulate"],
}

__getattr__, __dir__ = lazy.attach(
    __name__,
    submodules=["analysis", "cli", "core", "io", "noise", "plugin", "reduce", "simulation"],
    submod_attrs=_EXPORTS,
)[:2]
__all__ = sorted(name for names in _EXPORTS.values() for name in names)

logging.getLogger("spherex_reduce").addHandler(logging.NullHandler())
