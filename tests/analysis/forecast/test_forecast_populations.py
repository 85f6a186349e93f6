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
from spherex_reduce.analysis.forecast.populations import POPULATIONS, population_variances
from spherex_reduce.analysis.light import light_sensitive_image
from spherex_reduce.core.errors import ConfigError
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


def _forecast(scene, pipeline):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AstropyUserWarning)  # (reference pixels' telegraph)
        return forecast(scene, pipeline, {"bins": BINS})


def _clip(**params):
    """spherex-default with its sigma_clip's parameters changed."""
    steps = as_pipeline("spherex-default").config["steps"]
    return {"steps": [s if "sigma_clip" not in s else {"sigma_clip": {**s["sigma_clip"],
                                                                      **params}}
                      for s in steps]}


HOT = {"hot_pixel_fraction": 0.03, "hot_pixel_current": 300.0, "hot_pixel_current_spread": 100.0}


@pytest.mark.parametrize("pipeline, terms, runs, without", [
    # no clip, each population the largest term in turn (the others' columns could go)
    (None, {"dark_current_spread": 2.0, "rtn": TELEGRAPH}, 200, "telegraph"),
    (None, {"dark_current_spread": 2.0, **HOT}, 200, "hot_pixels"),
    (None, {"dark_current_spread": 40.0}, 200, "dark_spread"),
    # the shipped pipeline's 5-sigma clip masks the steps of most telegraph pixels and
    # every hot pixel of 2000 e/s; keeps those of 30 e/s; masks the far tail of a dark
    # current spread as skewed as 5 +- 40 e/s
    ("spherex-default", {"hot_pixel_fraction": 0.005, "hot_pixel_current": 2000.0,
                         "hot_pixel_current_spread": 100.0, "rtn": TELEGRAPH}, 250, None),
    ("spherex-default", {"hot_pixel_fraction": 0.03, "hot_pixel_current": 30.0,
                         "hot_pixel_current_spread": 10.0}, 250, "hot_pixels"),
    ("spherex-default", {"dark_current_spread": 40.0}, 250, None),
    # a clip above only (telegraph steps down kept) and one below only
    (_clip(sigma_lower=50.0), {"rtn": TELEGRAPH}, 200, "telegraph"),
    (_clip(sigma_upper=50.0), {"rtn": TELEGRAPH}, 200, "telegraph"),
])
def test_monte_carlo_of_the_populations_within_three_standard_errors(pipeline, terms, runs,
                                                                     without):
    """Slope images of the package's simulator (each seed another detector) reduced by the
    pipeline and measured as `spherex-reduce spectrum` measures them, against the forecast
    in every bin; the forecast without the population named (``without``), or with every
    population unclipped (the clip cases), is rejected by the same Monte Carlo."""
    scene = tiny([ROIC], terms={"dark_current": 5.0, **terms})
    table = _forecast(scene, pipeline)
    expect = u.Quantity(table["power"]).value
    mean, se = _monte_carlo(scene, pipeline, runs)
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se
    if without is not None:
        wrong = expect - table[f"power_{without}"].value
    else:  # the populations as if nothing were masked
        free = _forecast(scene, None)
        wrong = expect + sum(free[f"power_{k}"].value for k in POPULATIONS
                             if f"power_{k}" in free.colnames)
    assert np.any(np.abs(mean - wrong) > 5 * se), (mean - wrong) / se


def test_a_clip_with_populations_it_cannot_follow_is_refused_in_one_line():
    scene = tiny([ROIC], terms={"dark_current": 5.0, "rtn": TELEGRAPH})
    pair = {"steps": [{"sigma_clip": {}}, {"pair_difference": {"other": "b.fits"}}]}
    twice = {"steps": [*_clip()["steps"], {"sigma_clip": {}}]}
    for pipeline, words in ((_clip(stdfunc="mad_std"), "stdfunc 'mad_std'"),
                            (_clip(cenfunc="mean"), "cenfunc 'mean'"),
                            (pair, "before pair_difference"), (twice, "2 clips")):
        with pytest.raises(ConfigError, match=words) as info:
            forecast(scene, pipeline)
        assert "\n" not in str(info.value)
    many = tiny([ROIC], terms={"dark_current": 5.0, "hot_pixel_fraction": 0.5,
                               "rtn": {**TELEGRAPH, "fraction": 0.6}})
    with pytest.raises(ConfigError, match=r"add up to 1\.1 > 1"):
        forecast(many, "spherex-default")
    # without populations a clip is forecast as no clipping of Gaussian noise, twice too
    without = tiny([ROIC], terms={"dark_current": 5.0})
    once = forecast(without, "spherex-default")["power"]
    np.testing.assert_array_equal(forecast(without, twice)["power"], once)


def test_the_band_and_the_fft_image_forecast_hold_the_populations_too():
    """`band_power_forecast` (the band's cells alone) and the FFT image forecast take the
    populations as `forecast` does: the band power its table's, the FFT image's mean
    power over the plane less the image without them the populations' columns."""
    from spherex_reduce.analysis.forecast.engine import band_power_forecast
    from spherex_reduce.analysis.forecast.fft import forecast_fft_magnitude

    terms = {"dark_current": 5.0, "dark_current_spread": 3.0, "hot_pixel_fraction": 0.02,
             "hot_pixel_current": 40.0, "rtn": TELEGRAPH}
    scene = tiny([ROIC], terms=terms)
    for pipeline in (None, "spherex-default", "measured-dark-pair"):
        band = {"kmin": 0.3, "kmax": 1.2, "bins": BINS}
        table = _forecast(scene, pipeline) if pipeline != "spherex-default" else None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AstropyUserWarning)
            full = forecast(scene, pipeline, band)
            assert abs(band_power_forecast(scene, pipeline, 0.3, 1.2)
                       / full.meta["band_power"] - 1) < 1e-9
        if table is not None and pipeline is None:
            with_pops = forecast_fft_magnitude(scene, pipeline, size=16).magnitude.value ** 2
            bare = forecast_fft_magnitude(tiny([ROIC], terms={"dark_current": 5.0}), pipeline,
                                          size=16).magnitude.value ** 2
            added = sum(table[f"power_{k}"].value[0] for k in POPULATIONS)
            nonzero = bare > 0  # (the k = 0 cell: the mean, subtracted)
            np.testing.assert_allclose((with_pops - bare)[nonzero], added, rtol=1e-9)


def test_a_pair_of_one_detectors_exposures_cancels_its_fixed_patterns():
    """``pair_difference`` of two exposures of one detector (``population_seed`` per
    pair), then the reference correction and the clip (``measured-dark-pair``): the
    dark-current spread and the hot pixels' excess cancel, their Poisson noise stays
    (numbers from the real steps, each pair its own detector)."""
    from spherex_reduce import correct_reference, pair_difference, sigma_clip

    terms = {"dark_current": 5.0, "dark_current_spread": 10.0, "hot_pixel_fraction": 0.03,
             "hot_pixel_current": 30.0, "hot_pixel_current_spread": 10.0}  # (within the clip)
    table = _forecast(tiny([ROIC], terms=terms), "measured-dark-pair")
    assert "power_dark_spread" not in table.colnames
    expect = u.Quantity(table["power"]).value
    pre = as_pipeline({"steps": [{"unchop": {}}, {"subtract_phantom": {}}]})
    power = []
    for i in range(150):
        sc = tiny([ROIC], terms={**terms, "population_seed": 1000 + i})
        a, b = (pre.run(simulate(sc, seed=s)) for s in (i, 100_000 + i))
        d = sigma_clip(correct_reference(pair_difference(a, b), "mean"))
        power.append(power_spectrum(light_sensitive_image(d), bins=BINS)["power"].value)
    mean, se = np.mean(power, axis=0), np.std(power, axis=0, ddof=1) / np.sqrt(len(power))
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se
    dark, hot = 10.0 ** 2, 0.03 * (30.0 ** 2 + 10.0 ** 2) - (0.03 * 30.0) ** 2
    for fixed in (dark, hot):  # had either not cancelled
        assert np.any(np.abs(mean - (expect + fixed)) > 5 * se), fixed


def test_reference_pixels_telegraph_is_left_out_with_one_warning():
    scene = tiny([ROIC], terms={"rtn": {**TELEGRAPH, "pixels": "reference"}})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        table = forecast(scene, "spherex-default", {"bins": BINS})
        forecast(scene, None, {"bins": BINS})  # no reference correction: nothing left out
    said = [w for w in caught if "reference pixels" in str(w.message)]
    assert len(said) == 1 and issubclass(said[0].category, AstropyUserWarning)
    assert "power_telegraph" not in table.colnames
