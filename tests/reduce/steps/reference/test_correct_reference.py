"""Phantom and reference correction: injected offsets, hard cases, strategies."""

import numpy as np
import pytest
from astropy.stats import sigma_clip as astropy_sigma_clip

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    Pipeline,
    ReadoutSchedule,
    correct_reference,
    dq,
    fit_ramp,
    subtract_phantom,
    unchop,
)
from spherex_reduce.core.errors import ConfigError, StepSkipped
from spherex_reduce.core.source_mask import source_mask
from spherex_reduce.reduce.steps.phantom import SubtractPhantomStep
from spherex_reduce.reduce.steps.reference.strategies import (
    NoReferenceError,
    NoReferenceWarning,
    clipped_mean,
)


def sched(skip=3, ref_reads=8, ref_mode="distributed", phantom=2, nframes=3, nrows=32,
          ncols=32, nch=4, border=4, scan="same"):
    return ReadoutSchedule(DetectorGeometry(nrows, ncols, nch, ref_border=border, scan=scan),
                           skip=skip, ref_reads=ref_reads, ref_mode=ref_mode,
                           phantom_reads=phantom, nframes=nframes)


def offsets_image(s, per_channel, even_odd=None, nframes=None, rng=None, noise=0.0):
    """Raw ramps (readout order) made of per-channel (and even/odd) offsets only."""
    g = s.geometry
    col = np.repeat(per_channel, g.channel_width).astype(float)
    if even_odd is not None:
        col = col + np.where(g.column_offsets() % 2 == 0, even_odd[0], even_odd[1])
    nf = s.nframes if nframes is None else nframes
    data = np.broadcast_to(col, (nf, s.n_reads, g.ncols)).copy()
    if noise:
        data += rng.normal(0, noise, data.shape)
    return data


# -- clipped mean ---------------------------------------------------------------------------
@pytest.mark.parametrize("sigma,maxiters", [(3.0, 5), (2.0, None), (1.5, 1)])
def test_clipped_mean_equals_astropy_sigma_clip_mean(sigma, maxiters):
    rng = np.random.default_rng(0)
    vals = rng.normal(0, 1, (6, 300))
    vals[:, :5] += 40  # outliers
    vals[0, 7] = np.nan
    mean, used, clipped = clipped_mean(vals, sigma=sigma, maxiters=maxiters)
    for i in range(6):
        row = vals[i][np.isfinite(vals[i])]
        ref = astropy_sigma_clip(row, sigma=sigma, maxiters=maxiters, masked=True)
        assert mean[i] == pytest.approx(ref.mean(), rel=1e-12, abs=1e-12)
        assert used[i] == ref.count()
        assert clipped[i] == row.size - ref.count()


def test_clipped_mean_zero_spread_and_empty():
    mean, used, clipped = clipped_mean([[5.0] * 10, [np.nan] * 10])
    assert mean[0] == 5.0 and used[0] == 10 and clipped[0] == 0
    assert np.isnan(mean[1]) and used[1] == 0


def test_clipped_mean_ignores_infinite_values_as_unusable():
    # -inf sorts first, not last with the NaNs: it once made every value unusable
    vals = [-np.inf, 1.0, 1.1, 0.9, 1.0, 50.0, np.inf, np.nan]
    mean, used, clipped = clipped_mean(vals, sigma=2)
    ref = astropy_sigma_clip(np.array([1.0, 1.1, 0.9, 1.0, 50.0]), sigma=2, masked=True)
    assert float(mean) == pytest.approx(ref.mean(), rel=1e-12)
    assert int(used) == ref.count() == 4 and int(clipped) == 1


# -- phantom -----------------------------------------------------------------------------------
def test_subtract_phantom_per_channel_and_row_read_and_reference_reads():
    s = sched()
    rng = np.random.default_rng(1)
    phantom = rng.normal(0, 5, (3, s.n_reads, 4))
    data = np.repeat(phantom, 8, axis=2) + 7.0  # pixels see the phantom drift
    e = Exposure.from_arrays(data, s, phantom=phantom)
    out = subtract_phantom(e)
    np.testing.assert_allclose(out.data.data, 7.0, atol=1e-12)
    assert out.phantom is None
    phys = subtract_phantom(unchop(e))
    np.testing.assert_allclose(phys.reference.data, 7.0, atol=1e-12)
    again = subtract_phantom(out)
    assert again.header["S_PHANTM"] == "SKIPPED"
    np.testing.assert_array_equal(again.data.data, out.data.data)
    with pytest.raises(StepSkipped, match="no phantom"):
        SubtractPhantomStep().run(out)


def test_phantom_skipped_with_c_zero_in_pipeline():
    s = sched(phantom=0)
    e = Exposure.from_arrays(np.zeros((3, s.n_reads, 32)), s)
    out = Pipeline({"steps": ["subtract_phantom"]}).run(e)
    assert out.header["S_PHANTM"] == "SKIPPED"


# -- reference: exact removal on noise-free input -------------------------------------------------
@pytest.mark.parametrize("mode,skip", [("distributed", 3), ("repeated", 1), ("none", 40),
                                      ("distributed", 5)])
def test_mean_removes_channel_offsets_exactly(mode, skip):
    s = sched(ref_mode=mode, skip=skip)
    offs = np.array([10.0, -3.0, 2.5, 100.0])
    raw = Exposure.from_arrays(offsets_image(s, offs), s)
    for e in (raw, unchop(raw)):
        out = correct_reference(e, "mean")
        np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)
        t = out.tables["REFOFFS"]
        assert t.colnames == ["frame", "channel", "parity", "offset", "n_used", "n_clipped",
                              "flag", "n_telegraph"]
        assert (t["n_telegraph"] == 0).all() and out.header["NTELEG"] == 0
        np.testing.assert_allclose(t["offset"].value, np.tile(offs, 3))
        assert (t["parity"] == -1).all() and (t["flag"] == 0).all()
        if e.order == "physical" and e.reference is not None:
            np.testing.assert_allclose(out.reference.data, 0.0, atol=1e-9)


def test_acn_removes_even_odd_offsets_exactly_also_with_alternate_scan():
    for scan in ("same", "alternate"):
        s = sched(scan=scan)
        offs = np.array([1.0, 2.0, 3.0, 4.0])
        e = unchop(Exposure.from_arrays(offsets_image(s, offs, even_odd=(0.5, -0.7)), s))
        out = correct_reference(e, "acn")
        np.testing.assert_allclose(out.data.data[:, 4:-4], 0.0, atol=1e-9)
        t = out.tables["REFOFFS"]
        assert len(t) == 3 * 4 * 2 and set(t["parity"]) == {0, 1}
        mean_only = correct_reference(e, "mean")
        assert np.abs(mean_only.data.data).max() == pytest.approx(0.6)


def test_statistical_error_on_noisy_input():
    s = sched(nframes=40, ref_reads=16)
    rng = np.random.default_rng(2)
    offs = np.array([5.0, -5.0, 0.0, 20.0])
    e = Exposure.from_arrays(offsets_image(s, offs, rng=rng, noise=1.0), s)
    out = correct_reference(unchop(e), "mean", sigma=5.0)
    t = out.tables["REFOFFS"]
    err = t["offset"].value - np.tile(offs, 40)
    n = t["n_used"]
    assert (n == 16 * 8).all()  # 16 reference reads x 8 columns per channel
    z = err * np.sqrt(n)  # unit-variance if the error is the statistical one
    assert abs(z.mean()) < 4 / np.sqrt(z.size)
    assert 0.8 < z.std() < 1.2


def test_outlier_reference_pixels_are_clipped():
    s = sched()
    raw = offsets_image(s, np.zeros(4))
    raw[:, s.reference_read_indices[0], 3] = 1e4  # a hot reference pixel
    rng = np.random.default_rng(3)
    raw += rng.normal(0, 1, raw.shape)
    out = correct_reference(Exposure.from_arrays(raw, s), "mean")
    t = out.tables["REFOFFS"]
    assert (t["n_clipped"][t["channel"] == 0] >= 1).all()
    assert np.abs(t["offset"].value).max() < 1.0


def test_all_reference_values_identical():
    s = sched()
    e = Exposure.from_arrays(np.full((3, s.n_reads, 32), 42.0), s)
    out = correct_reference(e, "mean", sigma=3.0)
    assert (out.tables["REFOFFS"]["n_clipped"] == 0).all()
    np.testing.assert_allclose(out.data.data, 0.0)


def test_no_usable_reference_pixels_flag_warning_channel_left_alone():
    s = sched()
    data = offsets_image(s, np.array([1.0, 2.0, 3.0, 4.0]))
    data[:, s.reference_read_indices, 8:16] = np.nan  # channel 1's reference pixels
    before = data.copy()
    e = Exposure.from_arrays(data, s)
    with pytest.warns(NoReferenceWarning, match=r"channel\(s\) \[1\]"):
        out = correct_reference(e, "mean")
    t = out.tables["REFOFFS"]
    bad = t["channel"] == 1
    assert np.isnan(t["offset"][bad]).all() and (t["flag"][bad] == dq.NO_REFERENCE).all()
    assert (t["flag"][~bad] == 0).all()
    active = s.active_read_indices
    np.testing.assert_array_equal(out.data.data[:, active, 8:16], before[:, active, 8:16])
    np.testing.assert_allclose(out.data.data[:, active, :8], 0.0)
    assert (out.dq[:, :, 8:16] & dq.NO_REFERENCE).all()
    assert not (out.dq[:, :, :8]).any()
    assert np.array_equal(e.data.data, before, equal_nan=True)  # input untouched


def test_no_reference_rows_is_a_clear_error():
    s = sched(ref_reads=0, border=4)  # distributed with r = 0: reference rows never read
    e = unchop(Exposure.from_arrays(np.zeros((3, s.n_reads, 32)), s))
    with pytest.raises(NoReferenceError, match="no reference rows"):
        correct_reference(e, "mean")
    s0 = sched(ref_reads=0, ref_mode="none", border=0)
    with pytest.raises(NoReferenceError, match="ref_border=0"):
        correct_reference(Exposure.from_arrays(np.zeros((3, s0.n_reads, 32)), s0), "acn")


def test_side_columns_are_used_for_the_edge_channels():
    s = sched()
    data = offsets_image(s, np.zeros(4))
    data[:, s.active_read_indices, :4] = 9.0  # the left side reference columns
    e = unchop(Exposure.from_arrays(data, s))
    without = correct_reference(e, "mean", sigma=100.0).tables["REFOFFS"]
    from spherex_reduce.reduce.steps.reference.strategies import UnequalReferenceWarning

    with pytest.warns(UnequalReferenceWarning):  # the left side's channel only
        with_side = correct_reference(e, "mean", sigma=100.0,
                                      side_columns=True).tables["REFOFFS"]
    assert without["offset"].value[0] == 0
    nref = 8 * 8  # reference reads x channel width
    nside = 24 * 4  # active rows x side columns
    assert with_side["offset"].value[0] == pytest.approx(9.0 * nside / (nref + nside))
    assert with_side["n_used"][0] == nref + nside and with_side["n_used"][1] == nref


def test_slopes_are_corrected_too():
    s = sched(nframes=1)
    img = offsets_image(s, np.array([1.0, -1.0, 2.0, 0.5]), nframes=1)[0]
    out = correct_reference(unchop(Exposure.from_arrays(img, s)), "mean")
    np.testing.assert_allclose(out.data.data[4:-4], 0.0, atol=1e-12)
    assert "frame" not in out.tables["REFOFFS"].colnames


# -- median ------------------------------------------------------------------------------------
def test_median_strategy_and_source_mask():
    s = sched(nframes=1, nrows=64, ncols=64)
    rng = np.random.default_rng(4)
    offs = np.array([3.0, -2.0, 1.0, 0.0])
    img = np.repeat(offs, 16)[None, :] + rng.normal(0, 1, (64, 64))
    img[10:40, 2:14] += 30.0  # a large source in channel 0 biases the plain median
    e = Exposure.from_arrays(img, s, order="physical")
    plain = correct_reference(e, "median").tables["REFOFFS"]["offset"].value
    masked = correct_reference(e, "median", mask_sources=True, box_size=16)
    mo = masked.tables["REFOFFS"]["offset"].value
    assert abs(plain[0] - offs[0]) > 0.5  # the source pulls the plain median up
    assert np.abs(mo - offs).max() < 0.2
    assert masked.tables["REFOFFS"]["n_clipped"][0] > 200
    # the median strategy's recipe (see MedianReference.estimate)
    m = source_mask(img, box_size=16, nsigma=3.0, npixels=5, dilate=5, background="sextractor",
                    two_sided=False, min_boxes=1)
    assert m[20:30, 5:10].all() and m[:, 40:].mean() < 0.05


def test_median_of_each_frame_and_channel_is_numpys_with_a_channel_without_pixels():
    # frames on threads: a frame where channel 1 has no finite pixel gives NaN there (and
    # no warning but the step's own: the suite turns warnings into errors, in any thread),
    # the others numpy's
    s = sched(nframes=5, nrows=64, ncols=64)
    rng = np.random.default_rng(5)
    img = rng.normal(0, 1, (5, 64, 64)) + np.repeat([3.0, -2.0, 1.0, 0.0], 16)
    img[2, :, 16:32] = np.nan
    img[3, 7, 40] = np.inf  # a value, as numpy's median takes it
    e = Exposure.from_arrays(img, s, order="physical")
    with pytest.warns(NoReferenceWarning, match=r"channel\(s\) \[1\]"):
        out = correct_reference(e, "median")
    got = np.asarray(out.tables["REFOFFS"]["offset"].value).reshape(5, 4)
    expected = np.array([[np.nanmedian(img[f][:, 16 * c:16 * (c + 1)]) if f != 2 or c != 1
                          else np.nan for c in range(4)] for f in range(5)])
    np.testing.assert_array_equal(got, expected)


def test_unknown_strategy_lists_the_valid_ones():
    s = sched()
    e = Exposure.from_arrays(np.zeros((3, s.n_reads, 32)), s)
    with pytest.raises(ConfigError, match=r"'nonesuch' is not one of .*mean"):
        correct_reference(e, "nonesuch")


@pytest.mark.parametrize("steps", [["correct_reference"], ["subtract_phantom",
                                                          "correct_reference"]])
def test_flags_never_go_into_the_callers_dq_array(steps):
    """A channel without reference pixels is flagged in the result, never in the input's dq."""
    s = sched()
    data = offsets_image(s, np.array([1.0, 2.0, 3.0, 4.0]))
    data[:, s.reference_read_indices, 8:16] = np.nan
    flags = np.zeros(data.shape, np.uint16)
    flags[0, 5, 3] = dq.DO_NOT_USE  # a caller's flag: the input has its own dq array
    e = Exposure.from_arrays(data, s, mask=flags, phantom=np.zeros((*data.shape[:2], 4)))
    before = e.dq.copy()
    with pytest.warns(NoReferenceWarning):
        out = Pipeline({"steps": steps}).run(e)
    assert (out.dq[:, :, 8:16] & dq.NO_REFERENCE).all()
    np.testing.assert_array_equal(e.dq, before)
    np.testing.assert_array_equal(e.data.mask, before != 0)


def test_flagged_reference_pixels_stay_unused_after_unchop():
    g = DetectorGeometry(16, 8, 2, ref_border=2)
    s = ReadoutSchedule(g, skip=3, ref_reads=4, phantom_reads=0, nframes=1)
    data = np.zeros((s.n_reads, 8))
    flags = np.zeros(data.shape, np.uint16)
    bad = s.reference_read_indices[0]
    data[bad, 1] = 50.0
    flags[bad, 1] = dq.DO_NOT_USE
    e = Exposure.from_arrays(data, s, mask=flags)
    readout = correct_reference(e, "mean", sigma=100.0)
    physical = correct_reference(unchop(e), "mean", sigma=100.0)
    np.testing.assert_allclose(readout.tables["REFOFFS"]["offset"], 0.0)
    np.testing.assert_allclose(physical.tables["REFOFFS"]["offset"], 0.0)


def test_a_channel_without_reference_is_fitted_uncorrected_not_nan():
    """The docs promise "left uncorrected (never NaN)": fit_ramp used to drop every read
    flagged NO_REFERENCE, leaving the channel's slopes NaN with FEW_READS."""
    s = sched(nframes=6)
    rng = np.random.default_rng(4)
    t = np.arange(s.nframes)[:, None, None] * s.frame_time.value
    data = offsets_image(s, np.array([1.0, 2.0, 3.0, 4.0]), nframes=6) + 0.5 * t
    data += rng.normal(0, 0.01, data.shape)
    data[:, s.reference_read_indices, 8:16] = np.nan  # channel 1 has no reference pixels
    with pytest.warns(NoReferenceWarning):
        corrected = correct_reference(Exposure.from_arrays(data, s), "mean")
    out = fit_ramp(corrected)
    active = s.active_read_indices
    slopes = out.data.data[active][:, 8:16]
    tt = t[:, 0, 0]
    expected = np.polyfit(tt, data[:, active][:, :, 8:16].reshape(6, -1), 1)[0]
    np.testing.assert_allclose(slopes.ravel(), expected, rtol=1e-9)
    assert (out.dq[active][:, 8:16] == dq.NO_REFERENCE).all()  # flagged: masked on the image
    assert out.data.mask[active][:, 8:16].all() and not out.data.mask[active][:, :8].any()


def test_the_offsets_table_carries_the_data_unit_into_the_file(tmp_path):
    """REFOFFS' offset had its unit only as a table-level BUNIT that astropy reads as no
    unit; it is the column's unit now, read back with the file."""
    from astropy import units as u
    from astropy.io import fits

    from spherex_reduce import read, write
    from spherex_reduce.io.examples import example_raw_exposure

    raw = example_raw_exposure(seed=2)  # electrons
    path = write(correct_reference(raw, "mean"), tmp_path / "c.fits")
    header = fits.getheader(path, "REFOFFS")
    column = next(k for k in header if header[k] == "offset").replace("TTYPE", "TUNIT")
    assert header[column] == "electron" and "BUNIT" not in header
    assert read(path).tables["REFOFFS"]["offset"].unit == u.electron


def test_offsets_are_subtracted_in_float64_so_slopes_keep_the_fits_precision():
    """Issue 31: the corrected reads were float32, each rounded to its spacing at the
    pixel's level (1e-3 ADU at 1e4 ADU) with an offset whose fraction changes frame to
    frame: the slopes were off by ~1e-5 of themselves.  A float32 raw cube with a 1e4 ADU
    pedestal, reference reads whose per-channel mean is 1/3 plus a drift: the slopes
    equal numpy's float64 fit of the reads minus those means."""
    g = DetectorGeometry(16, 48, 4, ref_border={"top": 4, "bottom": 0, "left": 0, "right": 0})
    s = ReadoutSchedule(g, skip=1, ref_reads=4, ref_mode="distributed", phantom_reads=0,
                        nframes=8)  # rows 0-3 read once each, as the reference reads
    t = np.arange(s.nframes) * s.frame_time.value
    drift = (0.37 * np.arange(s.nframes) ** 1.5).astype(np.float32)
    ref = (g.column_offsets() % 3 == 0).astype(np.float32)  # a third of each channel's
    data = np.empty((s.nframes, s.n_reads, g.ncols), np.float32)
    data[:] = (1e4 + 3.0 * t + drift)[:, None, None]
    data[:, s.reference_read_indices] = (drift[:, None] + ref)[:, None, :]
    out = fit_ramp(correct_reference(Exposure.from_arrays(data, s), "mean"))
    active = s.active_read_indices
    offsets = drift.astype(np.float64) + 1 / 3  # the mean of each channel's reference reads
    reads = data[:, active].astype(np.float64) - offsets[:, None, None]
    expected = np.polyfit(t, reads.reshape(s.nframes, -1), 1)[0]
    np.testing.assert_allclose(out.data.data[active].ravel(), expected, rtol=1e-9)


@pytest.mark.parametrize("strategy", ["mean", "acn"])
def test_raw_darks_with_a_bias_pattern_clip_each_pixel_about_its_own_level(strategy):
    """Raw darks: the reference pixels' fixed bias pattern (318 ADU spread) is far above
    their read noise (4 ADU).  Clipped on their values, a different handful of pixels was
    dropped in each frame by its bias, and the offsets scattered 1.6-1.85x a plain mean's;
    clipped about each pixel's own level they scatter as a plain mean's (numpy, here)."""
    s = sched(nframes=40, ref_reads=16, nrows=64, ncols=64, nch=4)
    g = s.geometry
    rng = np.random.default_rng(7)
    bias = rng.normal(0, 318, (s.n_reads, g.ncols))
    drift = rng.normal(0, 2.0, (s.nframes, g.nchannels))  # each channel's offset per frame
    raw = bias[None] + np.repeat(drift, g.channel_width, axis=1)[:, None, :]
    raw += rng.normal(0, 4.0, raw.shape)
    out = correct_reference(Exposure.from_arrays(raw, s), strategy)
    t = out.tables["REFOFFS"]
    off = np.asarray(t["offset"].value).reshape(s.nframes, g.nchannels, -1).mean(axis=-1)
    ref = raw[:, s.is_reference]  # (frames, reference reads, columns)
    plain = ref.reshape(s.nframes, -1, g.nchannels, g.channel_width).mean(axis=(1, 3))
    ours_err = (off - drift) - (off - drift).mean(axis=0)
    plain_err = (plain - drift) - (plain - drift).mean(axis=0)
    ratio = ours_err.std() / plain_err.std()
    assert ratio <= 1.1, ratio


def test_side_columns_on_some_channels_only_warn_in_one_line():
    """SIDECAR-like: side reference columns on the left and right edges only, so the two
    outer of four channels have them and the inner ones do not."""
    from spherex_reduce.reduce.steps.reference.strategies import UnequalReferenceWarning

    s = ReadoutSchedule(DetectorGeometry(32, 32, 4, ref_border={"top": 4, "bottom": 4,
                                                                "left": 4, "right": 4}),
                        skip=1, ref_reads=0, ref_mode="none", phantom_reads=0, nframes=3)
    e = Exposure.from_arrays(np.zeros((3, s.n_reads, 32)), s)
    with pytest.warns(UnequalReferenceWarning, match=r"only channel\(s\) \[0, 3\] of 4") as w:
        correct_reference(e, "mean", side_columns=True)
    assert len(w) == 1 and "\n" not in str(w[0].message)
    # one channel, or no side columns asked for: no warning
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", UnequalReferenceWarning)
        correct_reference(e, "mean")
