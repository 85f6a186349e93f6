"""The forecast through the linear reduction steps (phantom subtraction, the mean reference
correction) against a brute-force covariance of every sample propagated by explicit
matrices (tests/_forecast_brute.py) and against the package's own simulator and steps.  The
``wiener`` strategy's are in test_forecast_wiener.py, the chunked rows in
test_forecast_rows.py."""

import numpy as np
import pytest
from _forecast_scenes import (
    BINS,
    BOTH,
    BOTH_COMMON,
    COMMON,
    PHANTOM,
    PINK,
    PINK_ACN,
    PIPELINES,
    ROIC,
    check_against_brute_force,
    tiny,
)
from astropy import units as u

from spherex_reduce import correct_reference, pair_difference
from spherex_reduce.analysis import forecast, power_spectrum
from spherex_reduce.analysis.forecast.engine import band_power_forecast
from spherex_reduce.analysis.forecast.steps import reduction
from spherex_reduce.analysis.light import light_sensitive_image
from spherex_reduce.core.errors import ConfigError, SpherexReduceError
from spherex_reduce.reduce.pipeline import as_pipeline
from spherex_reduce.simulation import load_scene, simulate


@pytest.mark.parametrize("pipe", PIPELINES)
def test_steps_equal_brute_force(pipe):
    """Every noise term the phantom and the pixels see, alternating scan directions."""
    scene = tiny([PINK_ACN, BOTH, BOTH_COMMON, PHANTOM], scan="alternate")
    check_against_brute_force(scene, *PIPELINES[pipe])


@pytest.mark.parametrize("comp", [PINK, ROIC, COMMON, PHANTOM, BOTH],
                         ids=lambda c: c["name"])
def test_each_noise_term_through_spherex_default(comp):
    check_against_brute_force(tiny([comp]), *PIPELINES["spherex-default"])


def test_phantom_only_noise_is_seen_once_phantom_values_are_subtracted():
    scene = tiny([PINK, PHANTOM])
    raw = forecast(scene, None, {"bins": BINS})
    sub = forecast(scene, "phantom-only", {"bins": BINS})
    assert np.all(u.Quantity(raw["power_phantom_only"]).value == 0)
    assert np.all(u.Quantity(sub["power_phantom_only"]).value > 0)
    # pink is not in the phantom samples: subtracting them leaves it as it was (up to the
    # offset rule, over the phantom samples' offsets too once they are subtracted)
    np.testing.assert_allclose(u.Quantity(sub["power_pink"]).value,
                               u.Quantity(raw["power_pink"]).value, rtol=1e-4)


def test_the_reference_offset_changes_only_the_horizontal_row():
    """A channel's offset is the same in every row: only k_y = 0 changes, so with the
    horizontal row excluded the mean correction changes nothing."""
    scene = tiny([PINK_ACN, BOTH])
    a, b = (forecast(scene, p, {"bins": BINS, "exclude_horizontal": True})
            for p in ("phantom-only", "spherex-default"))
    np.testing.assert_allclose(u.Quantity(a["power"]).value, u.Quantity(b["power"]).value,
                               rtol=1e-12)


def test_fit_ramp_first_is_the_same_reduction():
    """spherex-slopes (the ramps fitted first) is forecast as spherex-default because the real
    steps give the same image: one ramp exposure reduced by each shipped pipeline, their
    reference means unclipped (as forecast), agree to rounding; clipped they do not
    (the clip sees frames in one, slopes in the other), so the check can fail."""
    scene = tiny([ROIC, BOTH, BOTH_COMMON, PHANTOM], scan="alternate",
                 terms={"dark_current": 20.0})
    raw = simulate(scene, seed=5, mode="ramps")

    def image(name, sigma):
        steps = [{k: dict(v, sigma=sigma) if k == "correct_reference" else v
                  for k, v in item.items()} for item in as_pipeline(name).config["steps"]]
        return np.asarray(light_sensitive_image(as_pipeline({"steps": steps}).run(raw)).data,
                          float)

    a, b = image("spherex-default", 1e6), image("spherex-slopes", 1e6)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5 * np.std(a))
    clipped = image("spherex-default", 3.0) - image("spherex-slopes", 3.0)
    assert np.max(np.abs(clipped)) > 1e-3 * np.std(a)


@pytest.mark.parametrize("pipe", ["spherex-default", "phantom-only", "acn-side-columns"])
def test_monte_carlo_of_the_real_steps_within_three_standard_errors(pipe):
    """300 slope images of the simulator reduced by the shipped pipeline itself (its
    reference mean σ-clipped, its 5σ clip of hot pixels: forecast unclipped), measured as
    `spherex-reduce spectrum` measures them, against the forecast in every bin."""
    scene = tiny([ROIC, PINK_ACN, COMMON, BOTH, PHANTOM], scan="alternate",
                 terms={"dark_current": 20.0})
    pipe = PIPELINES[pipe][1]
    p = as_pipeline(pipe)
    runs = np.array([power_spectrum(light_sensitive_image(p.run(simulate(scene, seed=i))),
                                    bins=BINS)["power"].value for i in range(300)])
    mean, se = runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(len(runs))
    expect = u.Quantity(forecast(scene, pipe, measure={"bins": BINS})["power"]).value
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se


@pytest.mark.parametrize("exclude_horizontal", [False, True])
def test_band_power_from_the_band_cells_alone(exclude_horizontal):
    scene = tiny([ROIC, BOTH, BOTH_COMMON], terms={"dark_current": 5.0})
    full = forecast(scene, "spherex-default", {"kmin": 0.3, "kmax": 1.2, "bins": BINS,
                                               "exclude_horizontal": exclude_horizontal})
    band = band_power_forecast(scene, "spherex-default", 0.3, 1.2,
                               exclude_horizontal=exclude_horizontal)
    assert band == pytest.approx(full.meta["band_power"], rel=1e-12)


def test_reduction_follows_the_order_of_the_steps():
    r = reduction({"steps": [{"correct_reference": {"strategy": "mean"}},
                             {"subtract_phantom": {}}]})
    assert (r.phantom, r.reference, r.reference_phantom) == (True, "mean", False)
    assert reduction("phantom-only").reference is None
    # a wiener estimate from the phantom values consumes them: a later subtraction is skipped
    steps = [{"correct_reference": {"strategy": "wiener"}}, {"subtract_phantom": {}}]
    assert not reduction({"steps": steps}).phantom
    steps[0]["correct_reference"]["phantom"] = "ignore"
    assert reduction({"steps": steps}).phantom
    r = reduction({"steps": [{"fit_ramp": {}}, {"correct_reference": {"strategy": "acn",
                                                                      "side_columns": True}}]})
    assert (r.reference, r.side_columns, r.reference_ramps) == ("acn", True, False)


@pytest.mark.parametrize("step, match", [
    ({"correct_reference": {"strategy": "median"}},
     r"steps\[1\]\.correct_reference\.strategy: 'median' is not forecast"),
    ({"correct_reference": {"strategy": "fourier"}},  # a plugin's strategy
     r"correct_reference\.strategy: 'fourier' is not forecast"),
    ({"fit_ramp": {"weighting": "optimal", "read_noise": 5.0}},
     r"steps\[1\]\.fit_ramp\.weighting: 'optimal' is not forecast"),
    ({"detect_jumps": {}}, r"steps\[1\]\.detect_jumps .* is not forecast"),
    ({"fit_ramp": {"saturation": 6e4}},  # the real fit drops the reads above it
     r"steps\[1\]\.fit_ramp\.saturation: 60000\.0 is not forecast .*only None"),
    ({"pair_difference": {"reduce_other": False}},
     r"steps\[1\]\.pair_difference\.reduce_other: False is not forecast"),
    ({"sigma_clip": {"sigma": 2.5}},
     r"steps\[1\]\.sigma_clip\.sigma: 2\.5 is not forecast .*only a number >= 3"),
    ({"sigma_clip": {"sigma_lower": 2}}, r"steps\[1\]\.sigma_clip\.sigma_lower: 2 is not"),
    ({"correct_reference": {"strategy": "acn", "sigma": 2.0}},
     r"steps\[1\]\.correct_reference\.sigma: 2\.0 is not forecast"),
])
def test_refuses_what_is_not_linear_in_one_line(step, match):
    with pytest.raises(ConfigError, match=match) as err:
        forecast(tiny([PINK]), {"steps": [{"unchop": {}}, step]})
    assert "\n" not in str(err.value)


def test_refuses_a_second_reference_correction():
    """Only one reference offset is propagated: a second correction would be dropped."""
    steps = [{"correct_reference": {"strategy": "mean"}}, {"subtract_phantom": {}},
             {"correct_reference": {"strategy": "acn"}}]
    with pytest.raises(ConfigError, match=r"steps\[2\]\.correct_reference: a second "
                                          "reference correction is not forecast"):
        reduction({"steps": steps})


def test_clips_from_three_sigma_up_are_forecast_as_no_clipping():
    steps = [{"correct_reference": {"sigma": 3}}, {"sigma_clip": {"sigma": 3.0,
                                                                  "sigma_upper": None}}]
    assert reduction({"steps": steps}).reference == "mean"


def test_pair_difference_of_independent_exposures_keeps_the_spectrum_of_one():
    """(a - b) / sqrt(2) of two realisations reduced the same way (the measured-dark-pair
    reduction through the real steps: its dark current cancels, its Poisson noise stays)
    against the forecast of one exposure, 300 pairs."""
    scene = tiny([ROIC, PINK_ACN, BOTH, PHANTOM], terms={"dark_current": 20.0})
    pre = as_pipeline({"steps": [{"unchop": {}}, {"subtract_phantom": {}}]})
    runs = []
    for i in range(300):
        a, b = (pre.run(simulate(scene, seed=s)) for s in (i, 100_000 + i))
        d = correct_reference(pair_difference(a, b), "mean")
        runs.append(power_spectrum(light_sensitive_image(d), bins=BINS)["power"].value)
    runs = np.array(runs)
    mean, se = runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(len(runs))
    expect = u.Quantity(forecast(scene, "measured-dark-pair", {"bins": BINS})["power"]).value
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se
    one = u.Quantity(forecast(scene, "spherex-default", {"bins": BINS})["power"]).value
    np.testing.assert_array_equal(expect, one)


def test_ramps_fitted_last_equal_ramps_fitted_first():
    """The ramps route: uniform least squares commute with the frame-wise linear steps, so
    ramps reduced frame by frame and then fitted (spherex-default) give the slopes of the
    ramps fitted first and then reduced (the slopes route's order), unclipped."""
    scene = tiny([ROIC, BOTH, BOTH_COMMON, PHANTOM])
    raw = simulate(scene, seed=5, mode="ramps")
    steps = [{"unchop": {}}, {"subtract_phantom": {}},
             {"correct_reference": {"strategy": "acn", "sigma": 1e6, "maxiters": 1}}]
    fit = {"fit_ramp": {"weighting": "uniform"}}
    last = as_pipeline({"steps": [*steps, fit]}).run(raw)
    first = as_pipeline({"steps": [fit, *steps]}).run(raw)
    a, b = (np.asarray(light_sensitive_image(e).data, float) for e in (last, first))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5 * np.std(a))


@pytest.mark.parametrize("strategy", ["mean", "wiener"])
def test_refuses_a_reference_correction_without_reference_reads(strategy):
    scene = load_scene({"geometry": {"nrows": 20, "ncols": 20, "nchannels": 2, "ref_border": 0},
                        "readout": {"ref_reads": 0, "nframes": 4},
                        "noise": {"components": [PINK]}})
    with pytest.raises(SpherexReduceError, match="needs reference reads; the schedule has none"):
        forecast(scene, {"steps": [{"correct_reference": {"strategy": strategy}}]})
