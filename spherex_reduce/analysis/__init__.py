"""Measure noise: spatial power spectra, band power, temporal PSD fits.

Spatial (`spherex_reduce.analysis.spectrum`): `power_spectrum` (P(k), k in
rad/pixel, k = 2π · pixel scale / θ), `band_power` (θ = 5–20′ by default; `band_label`),
`fft_magnitude` (paper Fig. 7), `photon_noise_power` (the Zodiacal-light line
of Fig. 13) and `source_mask` (photutils segmentation).

Temporal (`spherex_reduce.analysis.temporal`): `temporal_psd` (Welch),
`fit_noise_model` (α + β/f + γ/f^1.3 with uncertainties, paper eq. 1 and
Table 2), and the reference-pixel and phantom streams of a raw exposure in time
order (`reference_timestream`, `phantom_timestream`, `fit_raw_noise`).
"""

from .spectrum import (
    BAND_KMAX,
    BAND_KMIN,
    SPHEREX_PIXEL_SCALE,
    FFTImage,
    band_label,
    band_power,
    fft_magnitude,
    k_from_theta,
    photon_noise_label,
    photon_noise_power,
    power_spectrum,
    slope_variance_factor,
    source_mask,
    theta_from_k,
)
from .temporal import (
    NoiseModelFit,
    Timestream,
    aliased_basis,
    fit_noise_model,
    fit_raw_noise,
    model_basis,
    phantom_timestream,
    reference_timestream,
    temporal_psd,
)

__all__ = [
    "BAND_KMAX",
    "BAND_KMIN",
    "SPHEREX_PIXEL_SCALE",
    "FFTImage",
    "NoiseModelFit",
    "Timestream",
    "aliased_basis",
    "band_label",
    "band_power",
    "fft_magnitude",
    "fit_noise_model",
    "fit_raw_noise",
    "k_from_theta",
    "model_basis",
    "phantom_timestream",
    "photon_noise_label",
    "photon_noise_power",
    "power_spectrum",
    "reference_timestream",
    "slope_variance_factor",
    "source_mask",
    "temporal_psd",
    "theta_from_k",
]
