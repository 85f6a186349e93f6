"""Telegraph reference pixels: the search (`find_telegraph`) and ``telegraph: auto | keep``."""

import numpy as np
import pytest
from astropy.stats import sigma_clip
from scipy import stats

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, correct_reference
from spherex_reduce.core import dq
from spherex_reduce.reduce.steps.reference.telegraph import find_telegraph

SIGMA = 10.0  # e, white noise of a reference pixel read


def _schedule(nframes=60):
    g = DetectorGeometry(32, 256, 4, ref_border=4)
    return ReadoutSchedule(g, skip=4, ref_reads=32, ref_mode="distributed", phantom_reads=0,
                           nframes=nframes)


def _telegraph(rng, times, rate):
    """Two-state telegraph sampled at increasing ``times`` (numpy, from the definition)."""
    p = (1 - np.exp(-2 * rate * np.diff(times))) / 2
    flips = np.r_[rng.random() < 0.5, rng.random(p.size) < p]
    return np.cumsum(flips) % 2


def _ramps(seed, pixels=(), amplitude=40.0, rate=3.0, nframes=60):
    """Noise ramps: white noise, offsets shared by each read of a channel and parity, and a
    telegraph in each of ``pixels`` (physical row, column) of the reference rows."""
    s = _schedule(nframes)
    g = s.geometry
    rng = np.random.default_rng(seed)
    shape = (s.nframes, s.n_reads, g.ncols)
    group = g.channel_of_column() * 2 + g.column_offsets() % 2
    common = rng.normal(0, 30, (s.nframes, s.n_reads, 8))[..., group]
    cube = rng.normal(0, SIGMA, shape) + common + rng.normal(0, 50, g.ncols)
    t = (np.arange(s.nframes)[:, None, None] * s.frame_time.value
         + s.pixel_times().value[None]).reshape(s.nframes * s.n_reads, g.ncols)
    for row, col in pixels:
        reads = np.flatnonzero(np.tile(s.rows == row, s.nframes))
        flat = cube.reshape(-1, g.ncols)
        flat[reads, col] += amplitude * _telegraph(rng, t[reads, col], rate)
    return Exposure.from_arrays(cube, s)


def _pixels(seed, n):
    g = _schedule().geometry
    rng = np.random.default_rng(seed)
    ref = [(r, c) for r in g.reference_rows for c in range(g.ncols)]
    return sorted(ref[i] for i in rng.choice(len(ref), n, replace=False))


def _tail(nu, sigma):
    """Probability that the log of a chi-square variance with ``nu`` degrees of freedom lies
    beyond its median plus ``sigma`` x 1.4826 median absolute deviations (scipy)."""
    logs = np.log(stats.chi2(nu).ppf((np.arange(200000) + 0.5) / 200000) / nu)
    med = np.median(logs)
    threshold = med + sigma * 1.4826 * np.median(np.abs(logs - med))
    return stats.chi2(nu).sf(nu * np.exp(threshold))


def test_false_alarms_follow_the_tail_of_the_log_variance():
    """Telegraph-free noise, 50 frames of 4 reads per pixel: the scales tested are every read
    (199 degrees of freedom) and means of 1 and 2 frames (49, 24).  At a 3-sigma threshold the
    fraction flagged lies between the largest of their chi-square tails (scipy) and their sum,
    within 3 Poisson sigma; at the default 5 sigma nothing of 65 536 pixels is flagged."""
    g = DetectorGeometry(64, 2048, 32, ref_border=4)
    rows = np.repeat(g.reference_rows, 4)  # 8 reference rows read 4 times per frame
    flagged = {3.0: 0, 5.0: 0}
    tested = 0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        values = rng.normal(0, 1, (50, rows.size, g.ncols)) + rng.normal(0, 5, (50, rows.size, 1))
        for sigma in flagged:
            found = find_telegraph(values, rows, g, sigma=sigma)
            flagged[sigma] += int(found.count.sum())
        tested += int(found.tested.sum())
    assert tested == 4 * 8 * 2048
    tails = [_tail(nu, 3.0) * tested for nu in (199, 49, 24)]
    assert max(tails) - 3 * np.sqrt(max(tails)) < flagged[3.0] < sum(tails) + 3 * np.sqrt(
        sum(tails)), (flagged, tails)
    assert flagged[5.0] == 0


def test_telegraph_pixels_are_found_and_nothing_else():
    """Telegraph steps of 4 sigma at 3 Hz (~10 switches in 60 frames): every one found,
    no other pixel; their reads are the ones masked."""
    pixels = _pixels(1, 12)
    e = _ramps(2, pixels)
    s = e.schedule
    ref = s.reference_read_indices
    found = find_telegraph(e.data.data[:, ref], s.rows[ref], s.geometry)
    assert sorted(zip(found.rows.tolist(), found.columns.tolist(), strict=True)) == pixels
    assert (found.score > 5).all()
    expected = np.zeros((ref.size, s.geometry.ncols), bool)
    for row, col in pixels:
        expected[s.rows[ref] == row, col] = True
    np.testing.assert_array_equal(found.reads, expected)
    np.testing.assert_array_equal(found.count, np.bincount(
        [c // s.geometry.channel_width for _, c in pixels], minlength=4))


def test_channels_of_odd_width_group_their_sample_parities():
    """A channel of 33 columns read right to left: the common mode of each read is removed
    per channel and sample parity (a large even/odd offset would otherwise make every pixel
    noisy); the one telegraph pixel is found."""
    g = DetectorGeometry(16, 66, 2, ref_border=2, scan="alternate")
    rng = np.random.default_rng(9)
    rows = np.array([0, 1, 14, 15, 0, 1, 14, 15])
    values = rng.normal(0, 1, (40, rows.size, g.ncols))
    parity = g.column_offsets() % 2
    values += rng.normal(0, 20, (40, rows.size, 1)) * parity  # alternating column noise
    values[:, rows == 14, 40] += 4.0 * (rng.random((40, 1)) < 0.5)
    found = find_telegraph(values, rows, g)
    assert (found.rows.tolist(), found.columns.tolist()) == ([14], [40])
    assert found.tested.tolist() == [4 * 33, 4 * 33]


def _clipped_offsets(e, leave_out=()):
    """Brute force, the reference mean's rule: each reference pixel's level is its median
    over the frames; per channel, the astropy sigma_clip mean (3 sigma, 5 iterations) of
    the levels, plus, per frame, the mean of the kept pixels' departures from their level,
    clipped (sigma_clip of the frame's pooled reads) on their departure from their read's
    median, each read's mean of the kept weighted by its pixels' count; the ``leave_out``
    pixels excluded."""
    s = e.schedule
    g = s.geometry
    ref = s.reference_read_indices
    keep = np.ones((ref.size, g.ncols), bool)
    for row, col in leave_out:
        keep[s.rows[ref] == row, col] = False
    values = e.data.data[:, ref].astype(np.float64)
    level = np.median(values, axis=0)
    out = np.empty((s.nframes, g.nchannels))
    for ch in range(g.nchannels):
        cols = slice(ch * g.channel_width, (ch + 1) * g.channel_width)
        lev = sigma_clip(level[:, cols][keep[:, cols]], sigma=3, maxiters=5)
        used = keep[:, cols].copy()
        used[used] = ~np.ma.getmaskarray(lev)
        for f in range(s.nframes):
            d = [(values[f, r, cols] - level[r, cols])[used[r]] for r in range(ref.size)]
            by = np.concatenate([x - np.median(x) for x in d])
            kept = np.split(~np.ma.getmaskarray(sigma_clip(by, sigma=3, maxiters=5)),
                            np.cumsum([x.size for x in d])[:-1])
            n = np.array([x.size for x, k in zip(d, kept, strict=True) if k.any()])
            means = [x[k].mean() for x, k in zip(d, kept, strict=True) if k.any()]
            out[f, ch] = lev.mean() + np.dot(n, means) / n.sum()
    return out


@pytest.mark.parametrize("order", ["readout", "physical"])
def test_auto_leaves_them_out_and_keep_uses_them(order):
    """``mean`` with ``telegraph: auto`` (the default) gives the clipped mean without the
    telegraph pixels, ``keep`` the clipped mean of all; recorded in REFOFFS, NTELEG and
    REFTELEG.  Also after ``unchop`` (the reference reads kept aside)."""
    from spherex_reduce import unchop

    pixels = _pixels(3, 10)
    raw = _ramps(4, pixels)
    e = unchop(raw) if order == "physical" else raw
    auto = correct_reference(e, "mean")
    keep = correct_reference(e, "mean", telegraph="keep")
    t = auto.tables["REFOFFS"]
    np.testing.assert_allclose(t["offset"].value.reshape(e.schedule.nframes, 4),
                               _clipped_offsets(raw, pixels), rtol=0, atol=1e-9)
    np.testing.assert_allclose(keep.tables["REFOFFS"]["offset"].value.reshape(-1, 4),
                               _clipped_offsets(raw), rtol=0, atol=1e-9)
    counts = np.bincount([c // 64 for _, c in pixels], minlength=4)
    np.testing.assert_array_equal(t["n_telegraph"].reshape(-1, 4), np.tile(counts, (60, 1)))
    assert auto.header["NTELEG"] == len(pixels)
    listed = auto.tables["REFTELEG"]
    assert sorted(zip(listed["row"].tolist(), listed["column"].tolist(), strict=True)) == pixels
    assert "NTELEG" not in keep.header and "n_telegraph" not in keep.tables["REFOFFS"].colnames
    assert "REFTELEG" not in keep.tables


def test_telegraph_free_data_are_corrected_as_before():
    """No telegraph: ``auto`` finds nothing, and the offsets are exactly ``keep``'s."""
    e = _ramps(5)
    auto, keep = correct_reference(e, "acn"), correct_reference(e, "acn", telegraph="keep")
    assert auto.header["NTELEG"] == 0
    np.testing.assert_array_equal(auto.data.data, keep.data.data)


def test_wiener_leaves_them_out():
    """``wiener`` with ``auto``: the drift does not depend on the telegraph pixels' values
    (steps of 40 e or 80 e, the same switches and noise: the same numbers), while with ``keep``
    it does; the pixels averaged are those of ``keep`` with the telegraph pixels' reads
    flagged DO_NOT_USE."""
    pixels = _pixels(6, 8)
    params = {"noise": "spherex-table2", "domain": "frames"}
    small, large = (_ramps(7, pixels, amplitude=a, rate=6.0, nframes=30) for a in (40.0, 80.0))
    auto = [correct_reference(e, "wiener", **params) for e in (small, large)]
    keep = [correct_reference(e, "wiener", telegraph="keep", **params) for e in (small, large)]
    assert auto[0].header["NTELEG"] == auto[1].header["NTELEG"] == len(pixels)
    np.testing.assert_allclose(auto[0].tables["REFDRIFT"]["drift"],
                               auto[1].tables["REFDRIFT"]["drift"], rtol=0, atol=1e-4)
    change = np.abs(keep[0].tables["REFDRIFT"]["drift"] - keep[1].tables["REFDRIFT"]["drift"])
    assert change.max() > 0.2
    s = small.schedule
    flags = np.zeros(small.data.data.shape, np.uint32)
    for row, col in pixels:
        flags[:, s.rows == row, col] = dq.DO_NOT_USE
    masked = correct_reference(small.replace(dq=flags), "wiener", telegraph="keep", **params)
    np.testing.assert_array_equal(auto[0].tables["REFOFFS"]["n_used"],
                                  masked.tables["REFOFFS"]["n_used"])


def test_a_slope_image_is_not_searched():
    """One frame: each reference pixel has a few samples only, fewer than a test needs."""
    e = _ramps(8, _pixels(8, 5), nframes=2)
    img = Exposure.from_arrays(e.data.data[1] - e.data.data[0], e.schedule)
    out = correct_reference(img, "mean")
    assert out.header["NTELEG"] == 0 and out.tables["REFTELEG"].meta["tested"] == 0


def test_a_side_column_telegraph_does_not_drag_its_partner_out():
    """Side reference columns hold 2 pixels per channel and parity in a read: their median
    is their mean, so a telegraph showed in both residuals and both were dropped."""
    g = DetectorGeometry(64, 64, 2, ref_border=4)
    rng = np.random.default_rng(0)
    reads, rows = 40, np.arange(4, 60)
    values = rng.normal(0, 1, (reads, rows.size, 64))
    values[..., ~g.reference_column_mask()] = np.nan
    values[:, 10, 0] += 6 * (rng.random(reads) < 0.5)  # row 14, column 0 only
    found = find_telegraph(values, rows, g)
    assert list(zip(found.rows.tolist(), found.columns.tolist(), strict=True)) == [(14, 0)]
