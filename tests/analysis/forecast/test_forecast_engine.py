"""The forecast of an uncorrected slope image against independent computations: Parseval
against the analytic pixel variance, a brute-force covariance of every pixel pair pushed
through `power_spectrum`, and the package's Monte Carlo."""

import numpy as np
import pytest
from _forecast_brute import Samples, expected_spectrum, read_time_covariance, reduction_matrix
from _forecast_scenes import BINS, COMMON, PINK, PINK_ACN, PIPELINES, ROIC, tiny
from astropy import units as u

from spherex_reduce import expected_slope_variance
from spherex_reduce.analysis import forecast, power_spectrum
from spherex_reduce.analysis.forecast.sweep import SweepForecast
from spherex_reduce.analysis.light import light_sensitive_image
from spherex_reduce.analysis.sweep import load_sweep
from spherex_reduce.core.errors import ConfigError, ResourceError
from spherex_reduce.noise.variance import slope_covariance
from spherex_reduce.simulation import load_scene, simulate

#: seen by the phantom reads only; ten times weaker than _forecast_scenes.PHANTOM
PHANTOM = {"name": "phantom_only", "beta": 4e-6, "scope": "common", "visibility": "phantom"}


def brute_force(scene, bins):
    """E[power_spectrum] from the covariance of every pair of light pixels: their slope
    covariance at their sampling lag (zero across channels for a channel-scope component,
    across column parities with ACN), then E[y^T Q y] = sum_i lambda_i (v_i^T Q v_i) over
    the covariance's eigenvectors, each pushed through power_spectrum itself."""
    s = scene.schedule
    g = s.geometry
    rows = np.arange(2, 18)
    cols = np.arange(2, 18)
    read = np.array([np.flatnonzero((s.rows == p) & ~s.is_reference)[0] for p in rows])
    t = (s.starts[read][:, None] + g.column_offsets()[cols][None, :]).ravel()
    chan = np.broadcast_to(g.channel_of_column()[cols], (16, 16)).ravel()
    parity = np.broadcast_to(g.column_offsets()[cols] % 2, (16, 16)).ravel()
    cov = np.zeros((t.size, t.size))
    for comp in scene.components:
        if not comp.seen_by_pixels:
            continue
        c = slope_covariance(comp, s, t[:, None] - t[None, :])[0]
        if comp.scope == "channel":
            c = c * (chan[:, None] == chan[None, :])
        if comp.acn:
            c = c * (parity[:, None] == parity[None, :])
        cov += c
    lam, vec = np.linalg.eigh(cov)
    keep = lam > 1e-12 * lam.max()
    total = 0.0
    for lv, v in zip(lam[keep], vec[:, keep].T, strict=True):
        total = total + lv * power_spectrum(v.reshape(16, 16), bins=bins)["power"].value
    return total, cov


CASES = {
    "pink": [PINK],
    "pink_acn": [PINK_ACN],
    "common": [PINK_ACN, COMMON, PHANTOM],
    "table2_like": [ROIC, PINK_ACN, COMMON],
}


@pytest.mark.parametrize("name", CASES)
def test_equals_brute_force(name):
    scene = tiny(CASES[name], scan="alternate" if name == "common" else "same")
    expect, _ = brute_force(scene, BINS)
    got = forecast(scene, measure={"bins": BINS})
    p = u.Quantity(got["power"]).value
    assert p.size == expect.size
    np.testing.assert_allclose(p, expect, rtol=1e-3)
    # band power over every bin, weighted by modes (the image is too small for 5-20')
    n = np.asarray(got["nmodes"], float)
    assert abs(np.sum(p * n) / np.sum(expect * n) - 1) < 1e-4


def test_components_add_up_and_phantom_only_is_invisible():
    got = forecast(tiny(CASES["common"]), measure={"bins": BINS})
    parts = sum(u.Quantity(got[f"power_{n}"]).value for n in ("pink_acn", "common"))
    np.testing.assert_allclose(u.Quantity(got["power"]).value, parts, rtol=1e-12)
    assert np.all(u.Quantity(got["power_phantom_only"]).value == 0)
    # ACN halves the column pairs that correlate: the pixel variance is the same
    var = [forecast(tiny([c]), measure={"bins": BINS}).meta["variance"] for c in (PINK, PINK_ACN)]
    assert var[0] == pytest.approx(var[1], rel=1e-9)


def test_parseval_against_expected_slope_variance():
    """The mean of P over the whole plane is the pixel variance, analytic (Table 2 timing,
    a 128 x 128 array of 4 channels with distributed reference reads)."""
    scene = load_scene({"geometry": {"nrows": 128, "ncols": 128, "nchannels": 4},
                        "readout": {"skip": 8, "ref_reads": 8, "nframes": 20}})
    got = forecast(scene)
    expect = expected_slope_variance(list(scene.components), scene.schedule).value
    assert got.meta["variance"] == pytest.approx(expect, rel=1e-6)


def test_monte_carlo_within_three_standard_errors():
    """300 slope images of the package's simulator (its exact slopes route), measured as
    `spherex-reduce spectrum` measures them, against the forecast in every bin."""
    scene = tiny([ROIC, PINK_ACN, COMMON], scan="alternate", terms={"dark_current": 20.0})
    runs = np.array([power_spectrum(light_sensitive_image(simulate(scene, seed=i)),
                                    bins=BINS)["power"].value for i in range(300)])
    mean, se = runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(len(runs))
    expect = u.Quantity(forecast(scene, measure={"bins": BINS})["power"]).value
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se


def test_poisson_noise_is_white_at_the_analytic_slope_variance():
    """Least-squares slope of N reads T apart of a Poisson charge at i e/s: variance
    6 (N^2 + 1) / (5 N (N^2 - 1)) i / T, written out here."""
    scene = tiny([PINK], terms={"dark_current": 3.0, "photocurrent": 1.0})
    got = forecast(scene, measure={"bins": BINS})
    n, t = 4, scene.schedule.frame_samples / scene.schedule.geometry.pixel_rate
    expect = 6 * (n**2 + 1) / (5 * n * (n**2 - 1)) * 4.0 / t
    np.testing.assert_allclose(u.Quantity(got["power_poisson"]).value, expect, rtol=1e-12)
    without = forecast(tiny([PINK]), measure={"bins": BINS})
    np.testing.assert_allclose(u.Quantity(got["power"]).value,
                               u.Quantity(without["power"]).value + expect, rtol=1e-12)


@pytest.mark.parametrize("pipeline", ["spherex-default", "side-columns"])
def test_light_sensitive_read_noise_equals_brute_force_and_the_reference_pixels_miss_it(
        pipeline):
    """``scene.active_read_noise`` σ: each light-sensitive sample's slope gets ``σ² Σ w²``
    more variance (``w`` the least-squares weights, computed here), no reference pixel
    any; the covariance of every sample pushed through the pipeline as a matrix.  Had the
    reference pixels seen it too (a white level of every pixel), their mean would move
    the band power by far more than the tolerance."""
    sigma = 40.0
    scene = tiny([ROIC, PINK_ACN, COMMON], scan="alternate",
                 terms={"active_read_noise": sigma})
    s = scene.schedule
    g = s.geometry
    samples = Samples(scene)
    t = np.arange(s.nframes) * s.frame_samples / g.pixel_rate
    w = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    active = np.zeros(samples.t.size, bool)
    active[:samples.npix] = ((~s.is_reference)[:, None]
                             & ~g.reference_column_mask()[None, :]).ravel()
    cov = sum(samples.covariance(scene.components).values())
    subtract, config = PIPELINES[pipeline]
    lmat = reduction_matrix(samples, **subtract)
    expect = expected_spectrum(samples, lmat, cov + np.diag(active * sigma**2 * np.sum(w * w)),
                               BINS)
    got = forecast(scene, config, {"bins": BINS})
    p = u.Quantity(got["power"]).value
    np.testing.assert_allclose(p, expect, rtol=1e-3)
    np.testing.assert_allclose(u.Quantity(got["power_active_white"]).value,
                               sigma**2 * np.sum(w * w), rtol=1e-12)
    seen = samples.is_pixel * sigma**2 * np.sum(w * w)
    wrong = expected_spectrum(samples, lmat, cov + np.diag(seen), BINS)
    assert np.max(np.abs(wrong / expect - 1)) > 0.1, wrong / expect - 1


def test_refuses_a_measure_that_is_not_linear_and_unknown_steps():
    scene = tiny([PINK])
    with pytest.raises(ConfigError, match="mask_sources"):
        forecast(scene, measure={"mask_sources": True})
    with pytest.raises(ConfigError, match=r"steps\[1\]\.fit_ramp\.weighting: 'optimal'"):
        forecast(scene, {"steps": [{"unchop": {}},
                                   {"fit_ramp": {"weighting": "optimal", "read_noise": 5.0}}]})


@pytest.mark.parametrize("name", ["poisson", "active_white", "telegraph", "masked"])
def test_a_component_named_as_one_of_the_forecasts_own_columns_is_refused(name):
    """Its plane would be overwritten by the forecast's own part of that name (and the band's
    fast path, which sums them apart, would disagree with the table)."""
    with pytest.raises(ConfigError, match=f"'{name}' is the name of one of the forecast's"):
        forecast(tiny([{**PINK, "name": name}], terms={"active_read_noise": 5.0}))


def test_band_follows_the_measure():
    """The band power is the bin of the measure's band, by the spectrum's own estimator."""
    scene = tiny([PINK_ACN])
    got = forecast(scene, measure={"kmin": 0.5, "kmax": 2.0, "bins": BINS})
    _, cov = brute_force(scene, BINS)
    lam, vec = np.linalg.eigh(cov)
    keep = lam > 1e-12 * lam.max()
    expect = sum(lv * power_spectrum(v.reshape(16, 16), bins=[0.5, 2.0])["power"].value[0]
                 for lv, v in zip(lam[keep], vec[:, keep].T, strict=True))
    assert got.meta["band_power"] == pytest.approx(expect, rel=1e-4)


def test_a_sweep_refuses_mask_sources_with_the_forecasts_own_message():
    """One refusal: the sweep's names the sweep, then says what `forecast` says."""
    sweep = load_sweep({"scene": {"geometry": {"nrows": 20, "ncols": 20, "nchannels": 2}},
                        "pipeline": "unchop", "grid": {"skip": [1]}, "realizations": 0,
                        "measure": {"mask_sources": True}})
    with pytest.raises(ConfigError) as own:
        forecast(tiny([PINK]), measure={"mask_sources": True})
    with pytest.raises(ConfigError) as err:
        SweepForecast(sweep)
    assert str(err.value) == f"{sweep.source}: {own.value}"


def test_refuses_an_image_this_machine_cannot_hold_before_allocating():
    """A 64 x 2**20 array in one channel: its row functional alone is ~10 TB (the number of
    columns squared).  Refused in one line (the command line's exit 2), not a MemoryError
    (or the kernel's kill) once numpy is asked for it."""
    scene = {"geometry": {"nrows": 64, "ncols": 2**20, "nchannels": 1, "ref_border": 4},
             "readout": {"nframes": 8}, "noise": {"components": [PINK]}}
    with pytest.raises(ResourceError, match=r"^forecast: the 56 x 524285 cells of a 56 x "
                                            r"1048568 image .* needs [0-9.]+ TB of memory"):
        forecast(scene, "unchop")


#: uneven read times (s): the slope's weights are (t - mean t) / sum (t - mean t)^2
READ_TIMES = [0.0, 1.0, 2.0, 5.0, 10.0, 20.0]


def test_uneven_read_times_white_and_poisson_are_the_closed_forms():
    """White read noise of per-sample variance sigma^2 = alpha fs / 2 read at times t_k:
    the least-squares slope's variance sigma^2 / sum (t - tbar)^2 (flat in k); Poisson
    noise of rate i: i w^T min(t_j, t_k) w.  Evenly read frames give other numbers."""
    white = {"name": "white", "alpha": 2e-3}
    scene = tiny([white], terms={"photocurrent": 1.5},
                 readout={"nframes": 6, "read_times": READ_TIMES})
    t = np.array(READ_TIMES)
    d = t - t.mean()
    sigma2 = 2e-3 * scene.schedule.geometry.pixel_rate / 2
    w = d / np.sum(d * d)
    shot = 1.5 * w @ np.minimum.outer(t, t) @ w
    got = forecast(scene, measure={"bins": BINS})
    np.testing.assert_allclose(u.Quantity(got["power_white"]).value, sigma2 / np.sum(d * d),
                               rtol=1e-9)
    np.testing.assert_allclose(u.Quantity(got["power_poisson"]).value, shot, rtol=1e-12)
    assert got.meta["variance"] == pytest.approx(sigma2 / np.sum(d * d) + shot, rel=1e-9)
    assert expected_slope_variance(scene.components, scene.schedule).value == pytest.approx(
        sigma2 / np.sum(d * d), rel=1e-12)
    even = forecast(tiny([white], readout={"nframes": 6}), measure={"bins": BINS})
    assert even.meta["variance"] > 10 * got.meta["variance"]


def test_uneven_read_times_correlated_noise_equals_brute_force():
    """1/f, power-law, ACN, common and phantom-only noise read at uneven times through
    phantom subtraction and the reference correction, against every sample's covariance
    written from the components' structure functions and the read times
    (`read_time_covariance`, not the package's slope covariance) pushed through the
    reduction as a matrix."""
    times = [0.0, 0.3, 1.2, 3.0]
    scene = tiny([ROIC, PINK, COMMON, PHANTOM], readout={"read_times": times})
    samples = Samples(scene)
    cov = sum(read_time_covariance(samples, scene.components, times).values())
    lmat = reduction_matrix(samples, phantom=True, reference="mean", reference_phantom=True)
    expect = expected_spectrum(samples, lmat, cov, BINS)
    got = u.Quantity(forecast(scene, "spherex-default", {"bins": BINS})["power"]).value
    np.testing.assert_allclose(got, expect, rtol=1e-6)


def test_forecast_tables_are_the_forecasts_of_each_measure():
    """Several measures of one scene from one set of planes: each table equals `forecast`'s
    with that measure to the last digit (the design report's binned and one-bin tables)."""
    from spherex_reduce.analysis.forecast.engine import forecast_tables

    scene = tiny([PINK_ACN, COMMON])
    measures = [{"bins": BINS}, {"kmin": 0.4, "kmax": 1.2, "bins": [0.4, 1.2]}]
    for got, m in zip(forecast_tables(scene, "spherex-default", measures), measures,
                      strict=True):
        want = forecast(scene, "spherex-default", m)
        assert got.colnames == want.colnames and got.meta == want.meta
        for col in want.colnames:
            assert np.array_equal(np.asarray(got[col]), np.asarray(want[col]))
