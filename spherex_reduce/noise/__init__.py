"""The readout noise model as data: components, their PSDs and the analytic slope statistics.

Below the steps and the simulator (the io layer): the simulator synthesises
these PSDs, and reduction strategies that need the noise model (the
``wiener`` reference strategy) read them from here.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "components": ["BUILTIN_TABLES", "NoiseComponent", "load_noise_table", "noise_components"],
    "variance": ["expected_slope_variance", "ls_weights", "slope_covariance"],
})
