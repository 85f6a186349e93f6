"""The noise simulator: the paper's Table 2 model on the readout schedule.

`simulate` turns a scene (YAML or dict) into raw ramps or a slope image;
`expected_slope_variance` predicts the slope noise without simulating, and
`slope_covariance` its covariance between samples of a frame.
"""

import importlib

import lazy_loader as lazy

_own_getattr, _, _own_all = lazy.attach(__name__, submod_attrs={
    "engine": ["NoiseEngine"],
    "scene": ["Scene", "load_scene"],
    "simulator": ["SpherexSimulator", "simulate", "simulate_to_fits"],
})
#: Names shown here from the layer below (`lazy_loader.attach` attaches this
#: package's own modules only), each with its module, imported when first used.
_BELOW = dict.fromkeys(["NoiseComponent", "expected_slope_variance", "load_noise_table",
                        "ls_weights", "noise_components", "slope_covariance"],
                       "spherex_reduce.noise")
__all__ = sorted([*_own_all, *_BELOW])


def __getattr__(name):
    if name in _BELOW:
        return getattr(importlib.import_module(_BELOW[name]), name)
    return _own_getattr(name)


def __dir__():
    return __all__.copy()
