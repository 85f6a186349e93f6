"""``fit_ramp`` on ramps as detectors give them: jumps, saturation, foreign flags, maps.

Every expectation is an independent numpy computation: a least-squares fit with one
intercept per segment and a common slope, the analytic variance of a weighted sum, or
generalised least squares built from the covariance matrix.
"""

import numpy as np
import pytest
from astropy.io import fits

from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule, dq, fit_ramp
from spherex_reduce.reduce.steps.fit_ramp.segments import RampNoise, fit_segments


def schedule(nframes=12, nrows=8, ncols=8, skip=1, frame_time=1.5):
    return ReadoutSchedule(DetectorGeometry(nrows, ncols, 1, ref_border=0), skip=skip,
                           ref_reads=0, ref_mode="none", phantom_reads=0, nframes=nframes,
                           frame_time=frame_time)


def ramps(s, rate=2.0, noise=3.0, seed=1):
    rng = np.random.default_rng(seed)
    t = s.frame_starts.value[:, None, None]
    shape = (s.nframes, s.n_reads, s.geometry.ncols)
    return 1000.0 + rate * t + rng.normal(0, noise, shape)


def common_slope(y, t, segment, usable):
    """Least squares with one intercept per segment and one slope (numpy lstsq)."""
    segs = sorted(set(segment[usable]))
    design = np.column_stack([(segment == k) & usable for k in segs] + [t * usable])
    return np.linalg.lstsq(design[usable].astype(float), y[usable], rcond=None)[0][-1]


def test_segments_between_jumps_share_one_slope():
    s = schedule()
    t = s.frame_starts.value
    cube = ramps(s)
    flags = np.zeros(cube.shape, np.uint32)
    cube[5:, 2, 3] += 500.0  # a cosmic ray between reads 4 and 5
    flags[5, 2, 3] = dq.JUMP
    cube[3:, 4, 4] += 80.0  # two jumps
    cube[9:, 4, 4] += 300.0
    flags[3, 4, 4] = flags[9, 4, 4] = dq.JUMP
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=flags))
    for (r, c), segment in (((2, 3), np.cumsum(flags[:, 2, 3] != 0)),
                            ((4, 4), np.cumsum(flags[:, 4, 4] != 0))):
        expected = common_slope(cube[:, r, c], t, segment, np.ones(t.size, bool))
        assert out.data.data[r, c] == pytest.approx(expected, rel=1e-10)
        assert out.dq[r, c] == dq.JUMP and not out.data.mask[r, c]  # informs, not masks
    rampfit = out.tables["RAMPFIT"]
    assert rampfit["njumps"][2][3] == 1 and rampfit["nsegments"][2][3] == 2
    assert rampfit["njumps"][4][4] == 2 and rampfit["nsegments"][4][4] == 3
    assert out.header["NJUMPPX"] == 2
    # a jump at the last read leaves a one-read segment, which carries no slope
    cube2, flags2 = cube.copy(), flags.copy()
    cube2[-1, 0, 0] += 1e4
    flags2[-1, 0, 0] = dq.JUMP
    out2 = fit_ramp(Exposure.from_arrays(cube2, s, mask=flags2))
    lstsq = np.polyfit(t[:-1], cube2[:-1, 0, 0], 1)[0]
    assert out2.data.data[0, 0] == pytest.approx(lstsq, rel=1e-10)


def test_segments_with_a_read_noise_model_are_combined_by_inverse_variance():
    """Each segment's variance is rn^2 / stt + rate / gain * w^T min(t_i, t_j) w, the rate
    pooled over the segments (not the segment's own slope)."""
    s = schedule(nframes=10)
    t = s.frame_starts.value
    rate, rn, gain = 40.0, 4.0, 2.0
    rng = np.random.default_rng(5)
    cube = 100 + rate * t[:, None, None] + rng.normal(0, rn, (10, 8, 8))
    cube[4:, 1, 1] += 700.0
    flags = np.zeros(cube.shape, np.uint32)
    flags[4, 1, 1] = dq.JUMP
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=flags), read_noise=rn, gain=gain)
    y = cube[:, 1, 1]
    parts = []
    for reads in (np.arange(4), np.arange(4, 10)):
        tc = t[reads] - t[reads].mean()
        w = tc / (tc @ tc)
        m = np.minimum.outer(t[reads] - t[0], t[reads] - t[0])
        parts.append((w @ y[reads], rn**2 * (w @ w), w @ m @ w / gain))
    pooled = sum(b / v for b, v, _ in parts) / sum(1 / v for _, v, _ in parts)
    for _ in range(2):
        var = [v + max(pooled, 0) * p for _, v, p in parts]
        pooled = sum(b / v for (b, _, _), v in zip(parts, var, strict=True)) / sum(
            1 / v for v in var)
    assert out.data.data[1, 1] == pytest.approx(pooled, rel=1e-10)
    assert out.data.uncertainty.array[1, 1] ** 2 == pytest.approx(1 / sum(1 / v for v in var),
                                                                  rel=1e-10)


def test_saturation_ends_the_ramp_and_says_so():
    s = schedule()
    t = s.frame_starts.value
    cube = ramps(s)
    flags = np.zeros(cube.shape, np.uint32)
    flags[7, 1, 2] = dq.SATURATED  # an input flag: reads 7.. are not used
    cube[6:, 3, 3] = 70000.0  # above the threshold from read 6 ...
    cube[9, 3, 3] = 1000.0  # ... a later read below it (a reset) does not come back
    cube[1:, 5, 5] = 70000.0  # saturated from read 1: fewer than two reads
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=flags), saturation=65000.0)
    for (r, c), n in (((1, 2), 7), ((3, 3), 6)):
        assert out.data.data[r, c] == pytest.approx(np.polyfit(t[:n], cube[:n, r, c], 1)[0],
                                                    rel=1e-10)
        assert out.dq[r, c] == dq.SATURATED and not out.data.mask[r, c]
        assert out.tables["RAMPFIT"]["nreads"][r][c] == n
    assert np.isnan(out.data.data[5, 5]) and out.dq[5, 5] == dq.SATURATED | dq.FEW_READS
    assert out.data.mask[5, 5]
    assert out.header["NSATPX"] == 3


def test_any_foreign_bit_masks_its_read():
    """A read flagged 2**19 (a uint32 JWST bit) is not fitted: it was fitted as good."""
    s = schedule()
    t = s.frame_starts.value
    cube = ramps(s)
    flags = np.zeros(cube.shape, np.uint32)
    cube[6, 0, 0] += 1e4
    flags[6, 0, 0] = 2**19
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=flags))
    keep = np.arange(t.size) != 6
    assert out.data.data[0, 0] == pytest.approx(np.polyfit(t[keep], cube[keep, 0, 0], 1)[0],
                                                rel=1e-10)
    assert out.dq[0, 0] == 0


def test_a_pixel_mask_covers_every_read_of_its_row():
    s = schedule(skip=2)  # reads rows 0, 2, 4, 6, 1, 3, 5, 7
    cube = ramps(s)
    bad = np.zeros((8, 8), bool)
    bad[1, 5] = True
    e = Exposure.from_arrays(cube, s, mask=bad)
    read = int(np.flatnonzero(s.rows == 1)[0])
    assert e.dq.shape == cube.shape and e.dq[:, read, 5].all() and e.dq.sum() == s.nframes
    assert np.isnan(fit_ramp(e).data.data[read, 5])


def test_read_noise_gain_and_dark_maps(tmp_path):
    """Per-pixel maps (arrays in Python, FITS images in YAML) set each pixel's variance:
    rn^2 sum(w^2) + (max(rate, 0) + dark) / gain * w^T min(t_i, t_j) w; in readout order each read
    takes its physical row's value."""
    s = schedule(nframes=8, skip=2)
    t = s.frame_starts.value
    rng = np.random.default_rng(2)
    rn_map = rng.uniform(2, 8, (8, 8))
    gain_map = rng.uniform(1, 3, (8, 8))
    dark_map = rng.uniform(0, 5, (8, 8))
    cube = ramps(s, rate=20.0)
    out = fit_ramp(Exposure.from_arrays(cube, s), read_noise=rn_map, gain=gain_map,
                   dark_current=dark_map)
    tc = t - t.mean()
    w = tc / (tc @ tc)
    pf = w @ np.minimum.outer(t - t[0], t - t[0]) @ w
    rows = s.rows  # physical row of each read
    slope = out.data.data
    expected = (rn_map[rows] ** 2 * (w @ w)
                + (np.maximum(slope, 0) + dark_map[rows]) / gain_map[rows] * pf)
    np.testing.assert_allclose(out.data.uncertainty.array ** 2, expected, rtol=1e-6)
    # the same maps from FITS files named in a pipeline's YAML, streamed in bands
    paths = {}
    for name, values in (("rn", rn_map), ("gain", gain_map), ("dark", dark_map)):
        paths[name] = tmp_path / f"{name}.fits"
        fits.PrimaryHDU(values).writeto(paths[name])
    p = Pipeline({"steps": [{"fit_ramp": {"read_noise": str(paths["rn"]),
                                          "gain": f"{paths['gain']}[0]",
                                          "dark_current": str(paths["dark"])}}]})
    streamed = p.run(Exposure.from_arrays(cube, s))
    np.testing.assert_array_equal(streamed.data.data, slope)
    np.testing.assert_allclose(streamed.data.uncertainty.array, out.data.uncertainty.array,
                               rtol=1e-12)
    assert "rn.fits" in str(streamed.header["HISTORY"])


@pytest.mark.parametrize("bad", [np.ones((3, 3)), np.full((8, 8), np.nan), -np.ones((8, 8)),
                                 "missing.fits"])
def test_bad_maps_are_refused_in_one_line(bad):
    from spherex_reduce.core.errors import ConfigError
    s = schedule()
    with pytest.raises(ConfigError, match=r"fit_ramp\.read_noise") as err:
        fit_ramp(Exposure.from_arrays(ramps(s), s), read_noise=bad)
    assert "\n" not in str(err.value)


def test_optimal_weighting_honours_each_pixels_masked_reads():
    """A MIRI-like first and last read DO_NOT_USE on every pixel: every pixel is still fitted
    by GLS on its usable reads (it fell back to uniform weights for the whole array)."""
    s = schedule(nframes=10)
    t = s.frame_starts.value
    rn, rate = 3.0, 400.0
    rng = np.random.default_rng(8)
    cube = (5000 + rate * t[:, None, None] + rng.normal(0, rn, (10, 8, 8))
            + np.cumsum(rng.normal(0, np.sqrt(rate * 1.5), (10, 8, 8)), axis=0))
    flags = np.zeros(cube.shape, np.uint32)
    flags[[0, -1]] = dq.DO_NOT_USE
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=flags), weighting="optimal",
                   read_noise=rn)
    use = slice(1, -1)
    tu = t[use]
    for r, c in [(0, 0), (3, 5), (7, 7)]:
        y = cube[use, r, c]
        ols = np.polyfit(tu, y, 1)[0]
        ratio = 10 ** (np.round(np.log10(ols / rn**2) * 50) / 50)
        cov = rn**2 * (np.eye(tu.size) + ratio * np.minimum.outer(tu - t[0], tu - t[0]))
        x = np.column_stack([np.ones(tu.size), tu])
        ci = np.linalg.inv(cov)
        gls = np.linalg.solve(x.T @ ci @ x, x.T @ ci @ y)[1]
        assert out.data.data[r, c] == pytest.approx(gls, rel=1e-9)
        assert abs(gls - ols) > 1e-4 * abs(ols)  # not the uniform fit


def test_zero_read_noise_gives_numbers_with_and_without_jumps():
    """read_noise 0 on noise-free ramps: the variance model is 0 (constant ramps) or shot
    noise alone; segment weights never divide by zero."""
    s = schedule(nframes=6)
    t = s.frame_starts.value
    cube = np.empty((6, 8, 8))
    cube[:, :, :4] = 500.0
    cube[:, :, 4:] = 500.0 + 5.0 * t[:, None, None]
    flags = np.zeros(cube.shape, np.uint32)
    cube[3:, 0, 0] += 100.0
    cube[3:, 6, 6] += 100.0
    flags[3, 0, 0] = flags[3, 6, 6] = dq.JUMP
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=flags), read_noise=0.0)
    np.testing.assert_allclose(out.data.data[:, :4], 0.0, atol=1e-12)
    np.testing.assert_allclose(out.data.data[:, 4:], 5.0, rtol=1e-12)
    assert np.isfinite(out.data.uncertainty.array).all()
    assert out.data.uncertainty.array[0, 0] == 0.0 and out.dq[0, 0] == dq.JUMP


@pytest.mark.parametrize("groups", [{"frames_per_group": 4, "group_gap": 1},
                                    {"groups": [[0], [1, 2], [3, 4, 5, 6], [7, 8, 9, 10, 11],
                                                [12, 13, 14, 15, 16, 17]]}])
def test_groups_of_averaged_frames(groups):
    """Reads simulated one by one (Poisson + read noise) and averaged into groups: the fit
    is unbiased and its uncertainty is the Monte Carlo scatter; the variance is w^T C w for
    C built read by read (read noise / n per group, mean of min(t_a, t_b) for the charge)."""
    nframes = 5
    s = ReadoutSchedule(DetectorGeometry(64, 64, 1, ref_border=0), skip=1, ref_reads=0,
                        ref_mode="none", phantom_reads=0, nframes=nframes, frame_time=2.0,
                        **groups)
    reads = [np.asarray(g) for g in s.group_reads]
    nreads = reads[-1][-1] + 1
    rate, rn = 30.0, 6.0
    rng = np.random.default_rng(4)
    charge = rng.poisson(rate * 2.0, (nreads, 64, 64)).cumsum(axis=0)
    frames = charge + rng.normal(0, rn, charge.shape)
    cube = np.stack([frames[r].mean(axis=0) for r in reads])
    out = fit_ramp(Exposure.from_arrays(cube, s), read_noise=rn)
    # brute force: read times t_a = 2 a (+ a constant), group means and covariance
    ta = 2.0 * np.arange(nreads)
    tg = np.array([ta[r].mean() for r in reads])
    cov = np.array([[rate * np.minimum.outer(ta[a], ta[b]).mean() for b in reads]
                    for a in reads]) + np.diag([rn**2 / len(r) for r in reads])
    w = (tg - tg.mean()) / ((tg - tg.mean()) ** 2).sum()
    sigma = np.sqrt(w @ cov @ w)
    np.testing.assert_allclose(np.median(out.data.uncertainty.array), sigma, rtol=0.01)
    assert abs(np.mean(out.data.data) - rate) < 4 * sigma / 64
    np.testing.assert_allclose(np.std(out.data.data), sigma, rtol=0.05)


@pytest.mark.parametrize("read_noise", [None, 3.0])
def test_pixels_with_any_number_of_segments_are_fitted_as_alone(read_noise):
    # a batch whose pixels hold 0 to 4 jumps and masked reads: each pixel's fit is the fit
    # of that pixel alone (bit for bit; segments are fitted on the pixels that have them)
    # and its slope the common slope of its segments (numpy lstsq)
    from spherex_reduce.reduce.steps.fit_ramp.segments import RampNoise, fit_segments

    rng = np.random.default_rng(8)
    nf, m = 20, 40
    t = np.arange(nf) * 1.5
    y = 1000.0 + 2.0 * t[:, None] + rng.normal(0, 3.0, (nf, m))
    flags = np.zeros((nf, m), np.uint32)
    for p in range(m):
        reads = rng.choice(np.arange(1, nf), p % 5, replace=False)
        flags[reads, p] = dq.JUMP
        y[np.sort(reads)[0] if reads.size else nf:, p] += 50.0 * reads.size
    flags[rng.integers(0, nf, 10), rng.integers(0, m, 10)] |= dq.DO_NOT_USE
    noise = RampNoise(t)
    batch = fit_segments(y, flags, noise, read_noise=read_noise)
    for p in range(m):
        alone = fit_segments(y[:, [p]], flags[:, [p]], noise, read_noise=read_noise)
        for name in ("slope", "var", "nreads", "njumps", "nsegments", "flags"):
            assert np.array_equal(getattr(batch, name)[[p]], getattr(alone, name),
                                  equal_nan=True), (p, name)
        usable = dq.read_usable(flags[:, p])
        segment = np.cumsum((flags[:, p] & dq.JUMP) != 0)
        assert batch.slope[p] == pytest.approx(common_slope(y[:, p], t, segment, usable),
                                               rel=1e-9)


def test_optimal_segments_without_a_gain_are_read_noise_weighted_least_squares():
    """``fit_segments(pscale=None)`` means no shot noise, in the weights too: the optimal
    fit of ramps of 2 e/s under read noise 1 is then uniform least squares of each
    segment, combined by inverse variance (numpy).  It weighed them for shot noise at
    gain 1 (slopes 0.05-0.2 off), with a variance of read noise alone."""
    t = np.arange(10) * 1.5
    rng = np.random.default_rng(3)
    y = 2.0 * t[:, None] + rng.standard_normal((10, 3))
    y[6:, 1] += 80.0
    flags = np.zeros(y.shape, np.uint32)
    flags[6, 1] = dq.JUMP
    fit = fit_segments(y, flags, RampNoise(t), read_noise=1.0, pscale=None,
                       weighting="optimal")

    def lsq(v, tt):
        tc = tt - tt.mean()
        return tc @ v / (tc @ tc), 1.0 / (tc @ tc)

    want = [lsq(y[:, 0], t), None, lsq(y[:, 2], t)]
    (s1, v1), (s2, v2) = lsq(y[:6, 1], t[:6]), lsq(y[6:, 1], t[6:])
    var = 1.0 / (1.0 / v1 + 1.0 / v2)
    want[1] = ((s1 / v1 + s2 / v2) * var, var)
    np.testing.assert_allclose(fit.slope, [w[0] for w in want], rtol=0, atol=1e-10)
    np.testing.assert_allclose(fit.var, [w[1] for w in want], rtol=1e-10)
