"""The forecast of channels as rows (the stored image the readout frame's transpose) against
a brute-force covariance of every sample (tests/_forecast_brute.py) and the package's own
simulator, and the layouts it still refuses."""

import numpy as np
import pytest
from _forecast_brute import Samples, reduction_matrix
from astropy import units as u

from spherex_reduce.analysis import forecast, power_spectrum
from spherex_reduce.analysis.forecast.engine import band_power_forecast
from spherex_reduce.analysis.light import light_sensitive, light_sensitive_image
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.reduce.pipeline import as_pipeline
from spherex_reduce.simulation import load_scene, simulate

BINS = 5
PINK_ACN = {"name": "pink_acn", "beta": 8e-3, "acn": True}
ROIC = {"name": "roic", "alpha": 2e-3, "gamma": 0.1, "exponent": 1.3, "acn": True}
BOTH = {"name": "video8", "alpha": 1e-3, "beta": 5e-3, "visibility": "both", "acn": True}
COMMON = {"name": "bias", "beta": 2e-4, "scope": "common", "visibility": "both"}
PHANTOM = {"name": "phantom_only", "beta": 4e-5, "scope": "common", "visibility": "phantom"}
#: name: (what the brute force subtracts, the pipeline)
PIPELINES = {"none": ({}, None),
             "spherex-default": (dict(phantom=True, reference="mean", reference_phantom=True),
                                 "spherex-default")}


def tiny(components, terms=None, channels="rows"):
    """20 x 20 stored pixels in 2 channels of 10 rows (read along the columns), a reference
    border of 2 on the top and bottom and of 1 on the left and right (a 16 x 18 light
    rectangle: its transpose bins differently), skip 3, 4 reference reads, 2 phantom
    samples per read."""
    return load_scene({
        "geometry": {"nrows": 20, "ncols": 20, "nchannels": 2, "channels": channels,
                     "ref_border": {"top": 2, "bottom": 2, "left": 1, "right": 1}},
        "readout": {"skip": 3, "ref_reads": 4, "phantom_reads": 2, "nframes": 4,
                    "frame_overhead": 20000},
        "noise": {"components": components},
        "scene": terms or {},
    })


def brute_force(scene, subtract, exclude_horizontal):
    """E[power_spectrum] of the stored image: the brute force works in the readout frame,
    so each eigenvector of the reduced frame pixels' covariance is reshaped to the frame's
    light rectangle and transposed to the stored orientation before `power_spectrum`."""
    samples = Samples(scene)
    lmat = reduction_matrix(samples, **subtract)
    cov = sum(samples.covariance(scene.components).values())
    rows, cols = light_sensitive(samples.geometry)  # the readout frame's rectangle
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    lam, vec = np.linalg.eigh(lmat @ cov @ lmat.T)
    keep = lam > 1e-12 * lam.max()
    return sum(lv * power_spectrum(v.reshape(shape).T, bins=BINS,
                                   exclude_horizontal=exclude_horizontal)["power"].value
               for lv, v in zip(lam[keep], vec[:, keep].T, strict=True))


def test_the_scene_is_stored_as_the_frames_transpose():
    """What the tests below rest on: the frame is 20 x 20 with its reference columns where
    the stored image has reference rows, and the stored light rectangle is 16 x 18."""
    g = tiny([ROIC]).schedule.geometry
    assert g.layout.channels == "rows"
    assert light_sensitive(g) == (slice(1, 19), slice(2, 18))
    assert light_sensitive(g.stored_geometry) == (slice(2, 18), slice(1, 19))


@pytest.mark.parametrize("exclude_horizontal", [False, True])
@pytest.mark.parametrize("pipe", PIPELINES)
def test_rows_layout_equals_brute_force(pipe, exclude_horizontal):
    scene = tiny([PINK_ACN, BOTH, COMMON, PHANTOM])
    subtract, pipeline = PIPELINES[pipe]
    expect = brute_force(scene, subtract, exclude_horizontal)
    got = forecast(scene, pipeline, {"bins": BINS, "exclude_horizontal": exclude_horizontal})
    np.testing.assert_allclose(u.Quantity(got["power"]).value, expect, rtol=1e-3)


def test_the_stored_horizontal_row_is_the_frames_vertical_column():
    """A reference correction changes only the frame's k_y = 0 row, which the stored image
    sees as its k_x = 0 column: with the horizontal row excluded the correction still
    changes the spectrum (channels as columns: it would not)."""
    scene = tiny([PINK_ACN, COMMON])
    measure = {"bins": BINS, "exclude_horizontal": True}
    raw, red = (u.Quantity(forecast(scene, p, measure)["power"]).value
                for p in ("phantom-only", "spherex-default"))
    assert np.max(np.abs(red / raw - 1)) > 1e-3


@pytest.mark.parametrize("exclude_horizontal", [False, True])
def test_band_power_from_the_band_cells_alone(exclude_horizontal):
    """The band's stored cells, mapped to the frame's, give the full forecast's band power."""
    scene = tiny([ROIC, BOTH, COMMON], terms={"dark_current": 5.0})
    full = forecast(scene, "spherex-default", {"kmin": 0.3, "kmax": 1.2, "bins": BINS,
                                               "exclude_horizontal": exclude_horizontal})
    band = band_power_forecast(scene, "spherex-default", 0.3, 1.2,
                               exclude_horizontal=exclude_horizontal)
    assert band == pytest.approx(full.meta["band_power"], rel=1e-12)


def test_monte_carlo_of_spherex_default_within_three_standard_errors():
    """300 slope images of the simulator reduced by spherex-default, measured as
    `spherex-reduce spectrum` measures them (the stored image's light pixels), with and
    without the horizontal row (binning by |k| alone cannot tell an image from its
    transpose; the stored k_y = 0 row can)."""
    scene = tiny([ROIC, PINK_ACN, COMMON, BOTH, PHANTOM], terms={"dark_current": 20.0})
    p = as_pipeline("spherex-default")
    images = [light_sensitive_image(p.run(simulate(scene, seed=i))) for i in range(300)]
    for exclude in (False, True):
        runs = np.array([power_spectrum(im, bins=BINS, exclude_horizontal=exclude)["power"]
                         .value for im in images])
        mean, se = runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(len(runs))
        expect = u.Quantity(forecast(scene, "spherex-default",
                                     {"bins": BINS, "exclude_horizontal": exclude})["power"])
        assert np.all(np.abs(mean - expect.value) < 3 * se), (exclude, (mean - expect.value)
                                                              / se)


def test_quadrants_are_refused_in_one_line():
    scene = load_scene({"geometry": {"nrows": 16, "ncols": 16, "nchannels": 4, "ref_border": 2,
                                     "channels": "quadrants"},
                        "readout": {"nframes": 4, "phantom_reads": 0},
                        "noise": {"components": [ROIC]}})
    with pytest.raises(SpherexReduceError, match="not quadrants") as err:
        forecast(scene)
    assert "\n" not in str(err.value)
