"""The noise simulator: the paper's Table 2 model on the readout schedule.

`simulate` turns a scene (YAML or dict) into raw ramps or a slope image;
`expected_slope_variance` predicts the slope noise without simulating, and
`slope_covariance` its covariance between samples of a frame.
"""

from ..noise import (
    NoiseComponent,
    expected_slope_variance,
    load_noise_table,
    ls_weights,
    noise_components,
    slope_covariance,
)
from .engine import NoiseEngine
from .scene import Scene, load_scene
from .simulator import SpherexSimulator, simulate, simulate_to_fits

__all__ = [
    "NoiseComponent",
    "NoiseEngine",
    "Scene",
    "SpherexSimulator",
    "expected_slope_variance",
    "load_noise_table",
    "load_scene",
    "ls_weights",
    "noise_components",
    "simulate",
    "simulate_to_fits",
    "slope_covariance",
]
