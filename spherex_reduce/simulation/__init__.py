"""The noise simulator: the paper's Table 2 model on the readout schedule.

`simulate` turns a scene (YAML or dict) into raw ramps or a slope image;
`expected_slope_variance` predicts the slope noise without simulating, and
`slope_covariance` its covariance between samples of a frame.
"""

from ..core.lazy_names import attach

_OWN = {
    "engine": ["NoiseEngine"],
    "scene": ["Scene", "load_scene"],
    "simulator": ["SpherexSimulator", "simulate", "simulate_to_fits"],
}
#: Names shown here from the layer below (`lazy_loader.attach` attaches this
#: package's own modules only), each with its module, imported when first used.
_BELOW = dict.fromkeys(["NoiseComponent", "expected_slope_variance", "load_noise_table",
                        "ls_weights", "noise_components", "slope_covariance"],
                       "spherex_reduce.noise")
__getattr__, __dir__, __all__ = attach(__name__, _OWN, _BELOW)
