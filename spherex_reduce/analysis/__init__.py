"""Measure noise: spatial power spectra, band power, temporal PSD fits.

Spatial (`spherex_reduce.analysis.spectrum`): `power_spectrum` (P(k), k in
rad/pixel, k = 2π · pixel scale / θ), `band_power` (θ = 5–20′ by default;
named by `band_label`, its exact θ by `band_theta`), `fft_magnitude` (paper
Fig. 7); `source_mask` (photutils segmentation, `spherex_reduce.core.source_mask`).
Photon noise (`spherex_reduce.analysis.photon_noise`): `photon_noise_power`
(the Zodiacal-light line of Fig. 13).

Temporal (`spherex_reduce.analysis.temporal`): `temporal_psd` (Welch),
`fit_noise_model` (α + β/f + γ/f^1.3 with uncertainties, paper eq. 1 and
Table 2).  Streams of a raw exposure (`spherex_reduce.analysis.timestreams`):
the reference-pixel and phantom streams in time order (`reference_timestream`,
`phantom_timestream`, `fit_raw_noise`).  A fitted noise model of a detector
from its darks, as a scene: `characterize` (`spherex_reduce.analysis.characterize`).

Expected spectra without random numbers (`spherex_reduce.analysis.forecast.engine`):
`forecast` (P(k) of a slope image reduced by linear steps, total and per noise
component), `band_power_forecast` (its band power from the band's cells alone).

Simulate, reduce and measure one case: `run_case` (`spherex_reduce.analysis.case`),
used by the demo, the figures and the sweeps.  Judge correction strategies on
the same noise and an injected sky (`sky_field`, `inject_sky`):
`compare_strategies` (`spherex_reduce.analysis.compare`), with the white floor
of the noise model (`white_floor`) and the cross-spectrum (`cross_spectrum`).
"""

from ..core.lazy_names import attach

_OWN = {
    "case": ["CaseResult", "SpectrumMeasure", "run_case"],
    "characterize": ["Characterization", "characterize"],
    "compare": ["CompareResult", "Comparison", "compare_strategies", "load_comparison",
                "measure_against_sky", "white_floor"],
    "photon_noise": ["photon_noise_label", "photon_noise_power", "slope_variance_factor"],
    "light": ["light_sensitive", "light_sensitive_image"],
    "forecast": ["band_power_forecast", "forecast"],
    "sky": ["inject_sky", "sky_field"],
    "spectrum": ["BAND_KMAX", "BAND_KMIN", "SPHEREX_PIXEL_SCALE", "EmptyBandError", "FFTImage",
                 "band_label", "band_power", "band_theta", "cross_spectrum", "fft_magnitude",
                 "k_from_theta", "power_spectrum", "theta_from_k"],
    "temporal": ["NoiseModelFit", "aliased_basis", "fit_noise_model", "model_basis",
                 "temporal_psd", "welch_terms"],
    "timestreams": ["Timestream", "detrend_frames", "fit_raw_noise", "phantom_timestream",
                    "reference_timestream"],
}
#: Names shown here from the layers below (`lazy_loader.attach` attaches this
#: package's own modules only), each with its module, imported when first used.
_BELOW = {"source_mask": "spherex_reduce.core.source_mask",
          "as_pipeline": "spherex_reduce.reduce.pipeline"}
__getattr__, __dir__, __all__ = attach(__name__, _OWN, _BELOW)
