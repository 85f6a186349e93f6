"""What a fitted model predicts for the darks' slope images, and what is measured on them.

Independent expectations: the telegraph slope variance against a Monte Carlo of
two-state chains and a least-squares slope written here with numpy; the clipped
standard deviation of a mixture against astropy's clip of draws from it; the
slope scatter of white darks against the closed form ``12 σ² / (N (N² - 1)
T²)``; the measured scatter against numpy's lstsq slopes of the same ramps,
differenced and clipped here.
"""

import threading
import warnings

import numpy as np
import pytest
from astropy.stats import sigma_clip

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
from spherex_reduce.analysis.characterize import characterize, check_model
from spherex_reduce.analysis.characterize.check import DarkScatter, reduction_pipeline
from spherex_reduce.analysis.characterize.figure import AUTO, CROSS, plot_characterization
from spherex_reduce.analysis.characterize.predict import (
    clipped_sigma,
    predict_scatter,
    telegraph_slope_variance,
)
from spherex_reduce.simulation import simulate

SLOPES_ONLY = {"name": "slopes", "steps": [{"unchop": {}},
                                           {"fit_ramp": {"weighting": "uniform"}}]}


def _telegraph_ramps(times, amplitude, rate, n, rng):
    """``(n, reads)`` two-state telegraph values read at ``times``: a coin for the first
    state, then each interval switches with ``(1 - exp(-2 rate dt)) / 2``."""
    p = (1 - np.exp(-2 * rate * np.diff(times))) / 2
    state = np.empty((n, len(times)), dtype=bool)
    state[:, 0] = rng.random(n) < 0.5
    for k in range(1, len(times)):
        state[:, k] = state[:, k - 1] ^ (rng.random(n) < p[k - 1])
    return amplitude * state


@pytest.mark.parametrize("rate", [0.05, 0.5, 3.0])
def test_telegraph_slope_variance_is_that_of_a_monte_carlo(rate):
    rng = np.random.default_rng(7)
    times = np.array([0.0, 1.0, 2.0, 3.5, 5.0, 6.0, 8.0, 9.5, 11.0, 12.0])
    x = _telegraph_ramps(times, 40.0, rate, 200_000, rng)
    design = np.vstack([np.ones_like(times), times]).T
    slopes = np.linalg.lstsq(design, x.T, rcond=None)[0][1]
    mc = slopes.var()
    se = mc * np.sqrt(np.var((slopes - slopes.mean()) ** 2) / mc**2 / slopes.size)
    assert abs(40.0**2 * telegraph_slope_variance(times, rate) - mc) < 4 * se


def test_clipped_sigma_is_astropys_clip_of_draws_from_the_mixture():
    rng = np.random.default_rng(3)
    n = 400_000
    outliers = rng.choice([-9.0, -4.0, 4.0, 9.0], n)  # 4: kept by a 5 sigma clip, 9: cut
    pick = rng.random(n) < 0.06
    x = rng.normal(0, 1.0, n) + np.where(pick, outliers, 0.0)
    measured = np.ma.std(sigma_clip(x, sigma=5, maxiters=None))
    means = np.array([0.0, -9.0, -4.0, 4.0, 9.0])
    weights = np.array([0.94, 0.015, 0.015, 0.015, 0.015])
    assert clipped_sigma(weights, means, 1.0) == pytest.approx(measured, rel=4e-3)
    # unclipped: the mixture's standard deviation
    assert clipped_sigma(weights, means, 1.0, sigma=None) == pytest.approx(
        np.sqrt(1 + 0.06 * (81 + 16) / 2), rel=1e-12)


def _white_scene(nframes=12, seed_rtn=None):
    scene = {"geometry": {"nrows": 128, "ncols": 128, "nchannels": 2, "ref_border": 4},
             "readout": {"skip": 4, "ref_reads": 8, "phantom_reads": 0, "nframes": nframes},
             "noise": {"components": [{"name": "white", "alpha": 2e-3}]},
             "output": {"mode": "ramps"}}
    if seed_rtn is not None:
        scene["scene"] = {"rtn": seed_rtn}
    return scene


def test_white_darks_scatter_is_the_closed_form():
    scene = _white_scene()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = characterize([simulate(scene, seed=s) for s in range(4)], SLOPES_ONLY)
    s = model.schedule
    frames = [2, 3, 6, 12]
    got = predict_scatter(model, SLOPES_ONLY, frames, sigma=None)
    var_read = 2e-3 * s.geometry.pixel_rate / 2  # a white read's variance, e^2
    t = s.frame_time.to_value("s")
    n = np.array(frames, dtype=float)
    want = np.sqrt(12 * var_read / (n * (n**2 - 1) * t**2))
    # the read-noise map of 4 darks of 128 x 128 pixels: its own error is ~0.3 %
    np.testing.assert_allclose(got["sigma_streams"], want, rtol=0.02)
    assert np.all(got["telegraph_variance"] == 0)


def _plain_schedule(nframes):
    g = DetectorGeometry(32, 32, 1, ref_border=0)
    return ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, nframes=nframes)


@pytest.mark.parametrize(("given", "threads"), [("memory", 1), ("memory", 3), ("file", 3)])
def test_measured_scatter_is_numpys_lstsq_of_the_ramps_differenced_and_clipped(
        given, threads, tmp_path, monkeypatch):
    """The darks in memory, or as raw files reduced band by band from their first N reads
    (a file read whole is refused here: characterize's scatter held each dark whole), the
    frame counts reduced one by one or several at once (threads)."""
    from spherex_reduce.analysis.characterize import check
    from spherex_reduce.io import FrameReader, open_input, write

    monkeypatch.setattr(check, "SCATTER_THREADS", threads)
    monkeypatch.setattr(check, "default_threads", lambda: 4)
    s = _plain_schedule(8)
    rng = np.random.default_rng(11)
    t = s.frame_starts.to_value("s")
    ramps = []
    for _ in range(2):
        x = rng.normal(0, 5.0, (8, 32, 32)) + 3.0 * t[:, None, None]
        x[:, 4, 7] += np.where(np.arange(8) >= 3, 500.0, 0.0)  # a jump: clipped
        ramps.append(x)
    frames = [2, 4, 8]
    image, together = check._image, threading.Barrier(min(threads, len(frames)), timeout=60)

    def reduced_together(*args, **kwargs):  # the frame counts' reductions at once
        together.wait()
        return image(*args, **kwargs)

    monkeypatch.setattr(check, "_image", reduced_together)
    acc = DarkScatter(reduction_pipeline({"name": "fit", "steps": [
        {"fit_ramp": {"weighting": "uniform"}}]}), 8, frames=frames,
        measure={"kmin": 0.3, "kmax": 1.5, "bins": 4})
    for k, x in enumerate(ramps):
        e = Exposure.from_arrays(x, s)
        if given == "memory":
            acc.add(e)
            continue
        write(e.replace(data=x.astype(np.float32)), tmp_path / f"d{k}.fits")
        monkeypatch.setattr(FrameReader, "exposure", _refused)
        with open_input(tmp_path / f"d{k}.fits") as inp:
            acc.add(inp.source())
        ramps[k] = x.astype(np.float32).astype(np.float64)  # as stored
    got = acc.result()
    assert got["differenced"] and got["pairs"] == 1
    for i, n in enumerate(frames):
        design = np.vstack([np.ones(n), t[:n]]).T
        sl = [np.linalg.lstsq(design, x[:n].reshape(n, -1), rcond=None)[0][1] for x in ramps]
        d = (sl[0] - sl[1]) / np.sqrt(2)
        keep = np.ones(d.size, bool)
        while True:  # iterative 5 sigma clip about the median
            std = d[keep].std()
            new = np.abs(d - np.median(d[keep])) <= 5 * std
            if (new == keep).all():
                break
            keep = new
        assert got["sigma"][i] == pytest.approx(d[keep].std(), rel=1e-6)


def _refused(self):
    raise AssertionError("a raw file read whole")


def test_a_pairs_statistics_are_taken_while_its_other_frame_counts_are_reduced(monkeypatch):
    """The second dark of a pair: the scatter at its longest frame count is measured as soon
    as that image is done, while the shortest is still being reduced (which waits for it,
    bounded: measured only once every image was done, it would wait in vain); the numbers
    are the pair's differences measured after the fact."""
    from spherex_reduce.analysis.characterize import check

    monkeypatch.setattr(check, "SCATTER_THREADS", 2)
    monkeypatch.setattr(check, "default_threads", lambda: 2)
    s = _plain_schedule(8)
    rng = np.random.default_rng(12)
    darks = [Exposure.from_arrays(rng.normal(0, 5.0, (8, 32, 32)), s) for _ in range(2)]
    frames = [2, 8]
    measure = {"kmin": 0.3, "kmax": 1.5, "bins": 4}
    pipeline = reduction_pipeline({"name": "fit", "steps": [
        {"fit_ramp": {"weighting": "uniform"}}]})
    after = DarkScatter(pipeline, 8, frames=frames, measure=measure)
    images = []
    for dark in darks:
        images.append(after._images(check.MemorySource(dark)))
    want = after._measure([(a.astype(np.float64) - b) / np.sqrt(2.0)
                           for a, b in zip(*images, strict=True)])

    acc = DarkScatter(pipeline, 8, frames=frames, measure=measure)
    acc.add(darks[0])
    measured, waited = threading.Event(), []
    image, scatter = check._image, DarkScatter._scatter

    def reduce_shortest_last(pipe, source, threads=None):
        if source.context.schedule.nframes == 2:
            waited.append(measured.wait(timeout=20))
        return image(pipe, source, threads=threads)

    def scattering(self, img, last=False):
        out = scatter(self, img, last)
        measured.set()
        return out

    monkeypatch.setattr(check, "_image", reduce_shortest_last)
    monkeypatch.setattr(DarkScatter, "_scatter", scattering)
    acc.add(darks[1])
    assert waited == [True]
    got = acc.result()
    np.testing.assert_array_equal(got["sigma"], want["sigma"])
    np.testing.assert_array_equal(got["power"], want["power"])
    assert got["band_power"] == want["band"]


def test_held_out_darks_with_telegraph_pixels_and_the_report_and_plot():
    rtn = {"fraction": 0.05, "amplitude": 200.0, "rate": 0.5}
    scene = _white_scene(nframes=16, seed_rtn=rtn)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = characterize([simulate(scene, seed=s) for s in range(4)], SLOPES_ONLY,
                             scatter=True)
        table = check_model(model, [simulate(scene, seed=s) for s in range(4, 8)],
                            SLOPES_ONLY, frames=[2, 4, 8, 16])
    assert table.meta["pairs"] == 2 and table.meta["telegraph"] is not None
    sc = table[table["quantity"] == "slope_scatter"]
    assert list(sc["frames"]) == [2, 4, 8, 16]
    # white darks and a telegraph population: within 5 % from 2 reads to all
    np.testing.assert_allclose(sc["ratio"], 1.0, atol=0.05)
    # the telegraph pixels raise the prediction at the most frames (their step is slow)
    assert sc["predicted"][-1] > sc["predicted_streams"][-1]
    # the model's own darks: in the report, summary and plot
    rep = model.report()
    kinds = set(rep["kind"])
    assert {"slope_scatter", "band_power", "power_spectrum"} <= kinds
    ratio = rep[(rep["kind"] == "slope_scatter") & (rep["parameter"] == "ratio")]
    assert len(ratio) == len(model.check[model.check["quantity"] == "slope_scatter"])
    assert any(line.startswith("slope scatter measured / predicted")
               for line in model.summary())
    fig = plot_characterization(model)
    assert len(fig.axes) == 4
    labels = [t.get_text() for ax in fig.axes if ax.get_legend()
              for t in ax.get_legend().get_texts()]
    assert not set(labels) & (set(AUTO) | set(CROSS))  # words, not internal names
    assert "predicted without the telegraph pixels" in labels


def test_the_drift_about_the_pixels_read_together_is_what_the_fit_holds_of_it():
    """`group_drift`: a 1/f stream common to the channels and one of each channel (ACN on
    it), read by the package's simulator, no white noise; the per-pixel fit's sums
    (`lag_sums`: each pixel's residual differences less its group's mean, one row of one
    channel and one column parity) at every lag, over their white reads' trace, are the
    white level the fit takes from them: that is ``group_drift`` (before, the prediction's
    white level held this drift twice on NGHXRG's pink: 0.953 of the measured scatter,
    0.998 with it out)."""
    from spherex_reduce.analysis.characterize.result import group_drift
    from spherex_reduce.analysis.faint_telegraph import common_labels, lag_design, lag_sums

    comps = [{"name": "common", "beta": 0.5, "scope": "common"},
             {"name": "own", "beta": 0.2, "gamma": 0.05, "acn": True}]
    scene = {"geometry": {"nrows": 128, "ncols": 128, "nchannels": 4, "ref_border": 4,
                          "scan": "alternate"},
             "readout": {"nframes": 40, "phantom_reads": 0, "ref_reads": 0, "skip": 1,
                         "ref_mode": "none"},
             "noise": {"components": comps}, "output": {"mode": "ramps"}}
    e = simulate(scene, seed=2)
    s = e.schedule
    data = np.asarray(e.data.data, dtype=np.float64)  # (frames, reads, cols): reads = rows
    labels = common_labels(s.geometry)[s.rows]
    keep = labels >= 0  # groups of 14 and 16 pixels: the fit holds 1.07 and 1.06 of their
    expect = group_drift(comps, s)  # variance about the mean
    assert expect > 0
    d = np.diff(data, axis=0)
    res = (d - d.mean(axis=0)).astype(np.float32)
    design = lag_design(s.frame_starts.to_value("s"))
    q = lag_sums(res, labels, np.zeros(labels.shape, bool), design["lags"])
    white = q[:, keep].mean(axis=1) / design["a"]  # per lag: what the fit takes as white
    assert np.all(np.abs(white / expect - 1) < 0.03), white / expect
