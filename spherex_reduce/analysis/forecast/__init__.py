"""The noise forecast: the expected power spectrum of a reduced slope image, no random numbers.

The entry points are `forecast` (P(k), total and per noise component),
`band_power_forecast` (the band power from the band's cells alone) and
`forecast_fft_magnitude` (the expected 2-D FFT near the origin, paper Fig. 7).
Inside: ``engine`` (the entry points), ``rows`` (E|FFT|² cell by cell),
``functionals`` (what each read's samples contribute), ``wiener`` (the drift
estimate of the ``wiener`` reference strategy), ``layout`` (the readout frame's
Fourier plane to the stored image's), ``steps`` (what a pipeline does to the
noise, built from what each step declares) and ``sweep`` (a sweep's grid
forecast).
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "engine": ["band_power_forecast", "forecast"],
    "fft": ["forecast_fft_magnitude"],
})
