"""The readout noise model as data: components, their PSDs and the analytic slope statistics.

Below the steps and the simulator (the io layer): the simulator synthesises
these PSDs, and reduction strategies that need the noise model (the
``wiener`` reference strategy) read them from here.
"""

from .components import BUILTIN_TABLES, NoiseComponent, load_noise_table, noise_components
from .variance import expected_slope_variance, ls_weights, slope_covariance

__all__ = [
    "BUILTIN_TABLES",
    "NoiseComponent",
    "expected_slope_variance",
    "load_noise_table",
    "ls_weights",
    "noise_components",
    "slope_covariance",
]
