"""The pixel populations in a forecast (hot pixels, a dark-current spread, telegraph pixels):
their white power against numpy draws and against the package's simulator, reduced with and
without the shipped pipeline's 5-sigma clip."""

import warnings

import numpy as np
import pytest
from _forecast_scenes import BINS, ROIC, tiny
from astropy import units as u
from astropy.utils.exceptions import AstropyUserWarning

from spherex_reduce.analysis import forecast, power_spectrum
from spherex_reduce.analysis.forecast.engine import band_power_forecast
from spherex_reduce.analysis.forecast.populations import population_variances
from spherex_reduce.analysis.light import light_sensitive_image
from spherex_reduce.reduce.pipeline import as_pipeline
from spherex_reduce.simulation import load_scene, simulate

TELEGRAPH = {"fraction": 0.1, "amplitude": 400.0, "rate": 0.5, "amplitude_spread": 100.0,
             "rate_spread": 0.3}


def _gamma(rng, mean, spread, n):
    return rng.gamma((mean / spread) ** 2, spread ** 2 / mean, n)


def test_a_telegraph_pixels_slope_variance_is_that_of_numpy_chains():
    """Two-state chains drawn here (a flip from one frame to the next with the chance
    (1 - exp(-2 r T)) / 2, gamma steps and rates), their least-squares slopes' variance."""
    sc = load_scene({"geometry": {"nrows": 16, "ncols": 16, "nchannels": 1},
                     "readout": {"nframes": 12, "phantom_reads": 0},
                     "scene": {"rtn": {**TELEGRAPH, "fraction": 1.0}}})
    got = population_variances(sc)[0]["telegraph"]
    s = sc.schedule
    frame = s.frame_samples / s.geometry.pixel_rate
    t = np.arange(12) * frame
    w = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    rng = np.random.default_rng(4)
    n = 400_000
    amp, rate = _gamma(rng, 400.0, 100.0, n), _gamma(rng, 0.5, 0.3, n)
    state = rng.random(n) < 0.5
    slope = w[0] * amp * state
    for k in range(1, 12):
        state ^= rng.random(n) < -np.expm1(-2 * rate * frame) / 2
        slope += w[k] * amp * state
    dev = (slope - slope.mean()) ** 2
    assert abs(got - dev.mean()) < 4 * dev.std() / np.sqrt(n), (got, dev.mean())


def _monte_carlo(scene, pipeline, runs):
    p = None if pipeline is None else as_pipeline(pipeline)
    power = []
    for i in range(runs):
        image = simulate(scene, seed=i)
        power.append(power_spectrum(light_sensitive_image(image if p is None else p.run(image)),
                                    bins=BINS)["power"].value)
    power = np.array(power)
    return power.mean(axis=0), power.std(axis=0, ddof=1) / np.sqrt(runs)


@pytest.mark.parametrize("pipeline, terms, runs", [
    # no clip: every population's variance in every bin (telegraph ~20x the readout's)
    (None, {"dark_current_spread": 2.0, "hot_pixel_fraction": 0.03, "hot_pixel_current": 30.0,
            "hot_pixel_current_spread": 10.0, "rtn": TELEGRAPH}, 300),
    # the shipped pipeline's 5-sigma clip masks the steps of most telegraph pixels and
    # every hot pixel of 2000 e/s, keeps those of 30 e/s
    ("spherex-default", {"dark_current_spread": 2.0, "hot_pixel_fraction": 0.005,
                         "hot_pixel_current": 2000.0, "hot_pixel_current_spread": 100.0,
                         "rtn": TELEGRAPH}, 400),
    ("spherex-default", {"hot_pixel_fraction": 0.03, "hot_pixel_current": 30.0,
                         "hot_pixel_current_spread": 10.0}, 400),
])
def test_monte_carlo_of_the_populations_within_three_standard_errors(pipeline, terms, runs):
    """Slope images of the package's simulator (each seed another detector) reduced by the
    pipeline and measured as `spherex-reduce spectrum` measures them, against the forecast
    in every bin; and the band power of the band's cells alone is the forecast's."""
    scene = tiny([ROIC], terms={"dark_current": 5.0, **terms})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AstropyUserWarning)  # (reference pixels' telegraph)
        table = forecast(scene, pipeline, {"bins": BINS})
        band = band_power_forecast(scene, pipeline, 0.3, 1.2)
        full = forecast(scene, pipeline, {"kmin": 0.3, "kmax": 1.2, "bins": BINS})
    expect = u.Quantity(table["power"]).value
    mean, se = _monte_carlo(scene, pipeline, runs)
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se
    assert abs(band / full.meta["band_power"] - 1) < 1e-9
    parts = [c for c in table.colnames if c.startswith("power_") and c != "power_err"]
    np.testing.assert_allclose(sum(table[c].value for c in parts), expect, rtol=1e-9)


def test_without_the_clip_the_telegraph_would_be_forecast_twentyfold():
    """The clip matters: the unclipped telegraph power is ~20x what the clipped pipeline
    measures (the test above), so the clip's mixture is what the agreement rests on."""
    scene = tiny([ROIC], terms={"dark_current": 5.0, "rtn": TELEGRAPH})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AstropyUserWarning)
        clipped = forecast(scene, "spherex-default", {"bins": BINS})["power_telegraph"]
        free = forecast(scene, None, {"bins": BINS})["power_telegraph"]
    assert free[0] > 1000 * clipped[0] > 0


def test_reference_pixels_telegraph_is_left_out_with_one_warning():
    scene = tiny([ROIC], terms={"rtn": {**TELEGRAPH, "pixels": "reference"}})
    with pytest.warns(AstropyUserWarning, match="reference pixels .* left out"):
        table = forecast(scene, "spherex-default", {"bins": BINS})
    assert "power_telegraph" not in table.colnames
