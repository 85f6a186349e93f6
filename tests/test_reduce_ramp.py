"""fit_ramp against float64 least squares, stcal, and the hard cases."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule, dq, fit_ramp
from spherex_reduce.errors import SpherexReduceError, StepSkipped
from spherex_reduce.examples import example_raw_exposure, tiny_schedule


def schedule(nframes=10, nrows=16, ncols=16, nch=2, frame_time=1.5):
    border = 2 if min(nrows, ncols) >= 8 else 1
    return ReadoutSchedule(DetectorGeometry(nrows, ncols, nch, ref_border=border), skip=3,
                           ref_reads=2 * border, phantom_reads=0, nframes=nframes,
                           frame_time=frame_time)


def frozen(a):
    a = np.array(a)
    a.setflags(write=False)
    return a


def lstsq_reference(cube, times, good=None):
    """Independent float64 reference: numpy.linalg.lstsq per pixel on its usable reads."""
    n, ny, nx = cube.shape
    slope = np.full((ny, nx), np.nan)
    resid = np.full((ny, nx), np.nan)
    for i in range(ny):
        for j in range(nx):
            g = np.ones(n, bool) if good is None else good[:, i, j]
            y = cube[g, i, j].astype(np.float64)
            if g.sum() < 2:
                continue
            a = np.stack([np.ones(g.sum()), times[g]], axis=1)
            coef, res, *_ = np.linalg.lstsq(a, y, rcond=None)
            slope[i, j] = coef[1]
            tc = times[g] - times[g].mean()
            if g.sum() > 2:
                resid[i, j] = (res[0] if res.size else 0.0) / (g.sum() - 2) / (tc @ tc)
    return slope, resid


def test_matches_float64_lstsq_and_residual_uncertainty():
    s = schedule(nframes=12)
    rng = np.random.default_rng(1)
    t = s.frame_starts.value
    cube = 500 + 3.0 * t[:, None, None] + rng.normal(0, 5, (12, 16, 16))
    cube = frozen(cube.astype(np.float32))
    e = Exposure.from_arrays(cube, s, order="physical")
    out = fit_ramp(e)
    ref, var = lstsq_reference(cube, t)
    assert out.unit == u.electron / u.s
    assert out.data.data.dtype == np.float64
    np.testing.assert_allclose(out.data.data, ref, rtol=1e-6, atol=1e-6 * 5 / np.sqrt(
        ((t - t.mean()) ** 2).sum()))
    np.testing.assert_allclose(out.data.uncertainty.array ** 2, var, rtol=1e-4)
    assert not out.data.mask.any()
    assert (out.tables["RAMPFIT"]["nreads"] == 12).all()


def test_float64_input_gives_float64_slopes_to_1e_minus_12():
    s = schedule(nframes=7)
    rng = np.random.default_rng(2)
    cube = rng.normal(0, 3, (7, 16, 16)) + 0.7 * s.frame_starts.value[:, None, None]
    out = fit_ramp(Exposure.from_arrays(cube, s))
    ref, _ = lstsq_reference(cube, s.frame_starts.value)
    assert out.data.data.dtype == np.float64
    np.testing.assert_allclose(out.data.data, ref, rtol=1e-10, atol=1e-12)


def test_agrees_with_stcal_ols_for_uniform_weights():
    from stcal.ramp_fitting.ramp_fit import ramp_fit_data
    from stcal.ramp_fitting.ramp_fit_class import RampData

    s = schedule(nframes=10)
    rng = np.random.default_rng(3)
    t = s.frame_starts.value
    cube = (1000 + 2.0 * t[:, None, None] + rng.normal(0, 10, (10, 16, 16))).astype(np.float32)
    ours = fit_ramp(Exposure.from_arrays(cube, s)).data.data
    rd = RampData()
    ny, nx = cube.shape[1:]
    rd.set_arrays(cube[None].copy(), np.zeros((1, *cube.shape), np.uint8),
                  np.zeros((ny, nx), np.uint32), np.zeros((ny, nx), np.float32))
    rd.set_meta(name="MIRI", frame_time=1.5, group_time=1.5, groupgap=0, nframes=1,
                drop_frames1=None)
    rd.set_dqflags({"DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4, "NO_GAIN_VALUE": 8,
                    "UNRELIABLE_SLOPE": 16, "PERSISTENCE": 32, "CHARGELOSS": 64})
    rd.start_row, rd.num_rows = 0, ny
    # read noise >> signal: stcal's optimal weighting has exponent 0, i.e. uniform weights
    img, _, _ = ramp_fit_data(rd, False, np.full((ny, nx), 1e4, np.float32),
                              np.ones((ny, nx), np.float32), "OLS_C", "optimal", "none")
    np.testing.assert_allclose(ours, img["slope"], rtol=2e-6, atol=2e-6)


def test_unflagged_nan_read_is_masked_not_a_wrong_number():
    s = schedule(nframes=10)
    t = s.frame_starts.value
    cube = 100 + 2.0 * t[:, None, None] * np.ones((10, 16, 16))
    cube[3, 4, 5] = np.nan  # stcal returns a wrong slope here (see the docs)
    out = fit_ramp(Exposure.from_arrays(frozen(cube.astype(np.float32)), s))
    assert out.data.data[4, 5] == pytest.approx(2.0, rel=1e-6)
    assert out.tables["RAMPFIT"]["nreads"][4][5] == 9
    assert not out.data.mask[4, 5]


def test_read_noise_zero_and_constant_ramps_give_numbers_not_nan():
    s = schedule(nframes=6)
    t = s.frame_starts.value
    cube = np.empty((6, 16, 16), np.float32)
    cube[:, :8] = 6e4  # constant
    cube[:, 8:] = (6e4 + 5.0 * t[:, None, None])  # perfect ramp, no noise
    out = fit_ramp(Exposure.from_arrays(cube, s))
    assert np.isfinite(out.data.data).all()
    assert np.all(out.data.data[:8] == 0)
    np.testing.assert_allclose(out.data.data[8:], 5.0, rtol=1e-6)
    assert np.isfinite(out.data.uncertainty.array).all()
    assert np.all(out.data.uncertainty.array < 1e-3)
    assert not out.data.mask.any()


def test_one_and_two_usable_reads_and_all_saturated():
    s = schedule(nframes=5)
    t = s.frame_starts.value
    cube = (100 + 4.0 * t[:, None, None] * np.ones((5, 16, 16))).astype(np.float32)
    cube[1:, 0, 0] = 7e4       # only read 0 usable
    cube[2:, 0, 1] = 7e4       # reads 0, 1 usable
    cube[:, 0, 2] = 7e4        # all saturated
    out = fit_ramp(Exposure.from_arrays(cube, s), saturation=65000.0)
    slope, nreads = out.data.data, out.tables["RAMPFIT"]["nreads"]
    flags = out.dq
    assert np.isnan(slope[0, 0]) and flags[0, 0] & dq.FEW_READS and flags[0, 0] & dq.SATURATED
    assert nreads[0][0] == 1 and out.data.mask[0, 0]
    assert slope[0, 1] == pytest.approx(4.0, rel=1e-6) and nreads[0][1] == 2
    assert np.isnan(out.data.uncertainty.array[0, 1])  # no residual with two reads
    assert np.isnan(slope[0, 2]) and flags[0, 2] == dq.FEW_READS | dq.SATURATED
    assert nreads[0][2] == 0
    assert isinstance(out.data.mask, np.ndarray) and out.data.mask.shape == (16, 16)
    assert out.header["NFEWRDS"] == 2


def test_per_read_and_per_pixel_flags_are_honoured():
    s = schedule(nframes=6)
    t = s.frame_starts.value
    cube = (10 + 1.0 * t[:, None, None] * np.ones((6, 16, 16))).astype(np.float32)
    cube[2, 1, 1] = 1e6            # a jump, flagged by the caller
    mask = np.zeros(cube.shape, np.uint16)
    mask[2, 1, 1] = dq.DO_NOT_USE
    mask[:, 3, 3] = dq.NOT_READ    # every read flagged: the pixel keeps the bit
    out = fit_ramp(Exposure.from_arrays(cube, s, mask=mask))
    assert out.data.data[1, 1] == pytest.approx(1.0, rel=1e-6)
    assert np.isnan(out.data.data[3, 3])
    assert out.dq[3, 3] == dq.NOT_READ | dq.FEW_READS
    assert out.dq[1, 1] == 0 and out.tables["RAMPFIT"]["nreads"][1][1] == 5


def test_float32_on_6e4_pedestal_to_1e_minus_3_sigma():
    s = schedule(nframes=74, nrows=32, ncols=32, nch=2, frame_time=1.51)
    rng = np.random.default_rng(4)
    t = s.frame_starts.value
    read_noise = 10.0
    cube = 6e4 + 0.01 * t[:, None, None] + rng.normal(0, read_noise, (74, 32, 32))
    cube32 = cube.astype(np.float32)
    out = fit_ramp(Exposure.from_arrays(cube32, s))
    tc = t - t.mean()
    ref = np.einsum("f,fij->ij", tc / (tc @ tc), cube32.astype(np.float64))
    sigma = read_noise / np.sqrt(tc @ tc)
    assert np.abs(out.data.data - ref).max() <= 1e-3 * sigma


def test_very_long_ramp_n386():
    s = schedule(nframes=386, nrows=8, ncols=8, nch=1)
    t = s.frame_starts.value
    rng = np.random.default_rng(5)
    cube = (6e4 + 0.5 * t[:, None, None] + rng.normal(0, 10, (386, 8, 8))).astype(np.float32)
    out = fit_ramp(Exposure.from_arrays(cube, s))
    ref, _ = lstsq_reference(cube, t)
    sigma = 10 / np.sqrt(((t - t.mean()) ** 2).sum())
    assert np.abs(out.data.data - ref).max() <= 1e-3 * sigma


def test_optimal_weighting_matches_brute_force_gls():
    s = schedule(nframes=8, nrows=4, ncols=4, nch=1)
    t = s.frame_starts.value
    rng = np.random.default_rng(6)
    rate, rn = 200.0, 5.0
    cube = 100 + rate * t[:, None, None] + rng.normal(0, rn, (8, 4, 4))
    out = fit_ramp(Exposure.from_arrays(cube, s), weighting="optimal", read_noise=rn)
    uniform = fit_ramp(Exposure.from_arrays(cube, s)).data.data
    # brute force: GLS with each pixel's own uniform-fit rate
    for i, j in [(0, 0), (2, 3)]:
        cov = rn**2 * np.eye(8) + max(uniform[i, j], 0) * np.minimum.outer(t - t[0], t - t[0])
        x = np.stack([np.ones(8), t], 1)
        ci = np.linalg.inv(cov)
        beta = np.linalg.solve(x.T @ ci @ x, x.T @ ci @ cube[:, i, j])
        # rates are quantised to 0.02 dex (4.7 %): the weights are near-optimal
        assert out.data.data[i, j] == pytest.approx(beta[1], abs=0.02 * abs(
            beta[1] - uniform[i, j]) + 1e-3)
    with pytest.raises(SpherexReduceError, match="read_noise"):
        fit_ramp(Exposure.from_arrays(cube, s), weighting="optimal")


def test_model_uncertainty_from_read_noise():
    s = schedule(nframes=10)
    t = s.frame_starts.value
    cube = np.zeros((10, 16, 16))
    out = fit_ramp(Exposure.from_arrays(cube, s), read_noise=7.0)
    tc = t - t.mean()
    np.testing.assert_allclose(out.data.uncertainty.array, 7.0 / np.sqrt(tc @ tc), rtol=1e-6)


def test_fits_phantom_and_reference_reads_and_never_modifies_input():
    raw = example_raw_exposure(tiny_schedule(nframes=5))
    before = raw.data.data.copy()
    raw.data.data.setflags(write=False)
    from spherex_reduce import unchop

    phys = unchop(raw)
    out = fit_ramp(phys)
    assert np.array_equal(raw.data.data, before)
    assert out.phantom.shape == (64, 4)
    assert out.reference.data.shape == (8, 64)
    t = raw.schedule.frame_starts.value
    tc = t - t.mean()
    w = tc / (tc @ tc)
    np.testing.assert_allclose(out.phantom, np.einsum("f,fij->ij", w, phys.phantom),
                               rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(out.reference.data,
                               np.einsum("f,fij->ij", w, phys.reference.data.astype(float)),
                               rtol=1e-5, atol=1e-4)
    with pytest.raises(StepSkipped):
        fit_ramp(out)


def test_pipeline_step_parameters():
    raw = example_raw_exposure(tiny_schedule(nframes=4))
    p = Pipeline({"steps": [{"fit_ramp": {"saturation": 1e9, "read_noise": 10}}]})
    out = p.run(raw)
    assert out.header["S_RAMPFT"] == "COMPLETE"
    assert out.data.data.shape == (raw.schedule.n_reads, 64)


def _stream(exposure, **params):
    """Feed the frames one at a time to the step's accumulator (as the pipeline does)."""
    from spherex_reduce.reduction_plugin import FitRampStep

    acc = FitRampStep().accumulator(exposure.schedule, exposure.header, **params)
    one = exposure.schedule.replace(nframes=1)
    for k in range(exposure.schedule.nframes):
        sl = slice(k, k + 1)
        acc.add(k, Exposure.from_arrays(
            exposure.data.data[sl], one, mask=None if exposure.dq is None else exposure.dq[sl],
            order=exposure.order))
    return acc.finish()


@pytest.mark.parametrize("nframes", [1, 2, 5, 9, 20])
def test_streaming_accumulator_equals_fit_ramp(nframes):
    s = schedule(nframes=nframes)
    t = s.frame_starts.value
    rng = np.random.default_rng(7)
    cube = (6e4 + 50.0 * t[:, None, None] + rng.normal(0, 5, (nframes, 16, 16)))
    cube = cube.astype(np.float32)
    cube[-1, 0, 0] = np.nan
    cube[0, 1, 1] = np.nan                     # first read unusable
    cube[:, 2, 2] = 7e4                        # all saturated
    if nframes > 3:
        cube[3:, 3, 3] = 7e4                   # saturates after 3 reads
    cube[:9, 6, 6] = np.nan                    # no usable read in the first buffered group
    cube[10:12, 7, 7] = np.nan                 # unusable reads in a later group
    mask = np.zeros(cube.shape, np.uint16)
    mask[:, 4, 4] = dq.NOT_READ
    mask[0, 5, 5] = dq.DO_NOT_USE
    mask[nframes // 2, 8, 8] = dq.DO_NOT_USE
    e = Exposure.from_arrays(cube, s, mask=mask)
    whole = fit_ramp(e, saturation=65000.0)
    streamed = _stream(e, saturation=65000.0)
    np.testing.assert_allclose(streamed.data.data, whole.data.data, rtol=1e-6, atol=1e-5,
                               equal_nan=True)
    np.testing.assert_allclose(streamed.data.uncertainty.array, whole.data.uncertainty.array,
                               rtol=1e-4, equal_nan=True)
    assert np.array_equal(streamed.dq, whole.dq)
    assert np.array_equal(streamed.tables["RAMPFIT"]["nreads"], whole.tables["RAMPFIT"]["nreads"])
    if nframes >= 3:  # the NaN read is left out, not turned into a wrong number
        assert streamed.data.data[0, 0] == pytest.approx(50.0, abs=10)


def test_streaming_with_read_noise_and_optimal():
    s = schedule(nframes=9)
    t = s.frame_starts.value
    rng = np.random.default_rng(8)
    cube = 100 + 30.0 * t[:, None, None] + rng.normal(0, 5, (9, 16, 16))
    cube[2, 0, 0] = np.nan
    e = Exposure.from_arrays(cube, s)
    for params in ({"read_noise": 5.0}, {"read_noise": 5.0, "weighting": "optimal"}):
        whole, streamed = fit_ramp(e, **params), _stream(e, **params)
        np.testing.assert_allclose(streamed.data.data, whole.data.data, rtol=1e-9)
        np.testing.assert_allclose(streamed.data.uncertainty.array,
                                   whole.data.uncertainty.array, rtol=1e-9)


def test_drift_dominating_by_1e5_stays_accurate():
    # a low-frequency stream 1e5 times the read noise (float32 values up to ~1e6)
    s = schedule(nframes=30)
    t = s.frame_starts.value
    rng = np.random.default_rng(9)
    drift = 1e5 * 10.0 * np.sin(2 * np.pi * t / (4 * t[-1]))
    cube = (6e4 + drift[:, None, None] + rng.normal(0, 10, (30, 16, 16))).astype(np.float32)
    out = fit_ramp(Exposure.from_arrays(cube, s))
    ref, var = lstsq_reference(cube, t)
    sigma = np.sqrt(var)  # the slope's sigma for this stream (the fit's uncertainty)
    np.testing.assert_allclose(out.data.uncertainty.array, sigma, rtol=1e-3)
    assert (np.abs(out.data.data - ref) <= 1e-3 * sigma).all()
    streamed = _stream(Exposure.from_arrays(cube, s))
    assert (np.abs(streamed.data.data - ref) <= 1e-3 * sigma).all()


@pytest.mark.parametrize("nframes", [10, 20])
def test_streamed_fit_on_a_pedestal_matches_float64_least_squares(nframes):
    # every buffered group of frames must be shifted by exactly the same per-pixel base:
    # a rounding difference between the first group and the later ones is a step in the
    # ramp (it once gave 1.7e-4 sigma for 10 frames)
    s = schedule(nframes=nframes, nrows=32, ncols=32)
    t = s.frame_starts.value
    rng = np.random.default_rng(11)
    cube = (6e4 + 0.02 * t[:, None, None] + rng.normal(0, 10, (nframes, 32, 32)))
    cube = cube.astype(np.float32)
    ref, _ = lstsq_reference(cube, t)
    sigma = 10.0 / np.sqrt(((t - t.mean()) ** 2).sum())
    streamed = _stream(Exposure.from_arrays(cube, s))
    assert np.abs(streamed.data.data - ref).max() <= 1e-5 * sigma


def test_streamed_sums_in_the_background_equal_the_whole_fit(monkeypatch):
    # large images sum each full buffer in a thread while the next one fills; force
    # that path on a small image (3 buffers of frames: both buffers are reused)
    from spherex_reduce.steps import ramp

    monkeypatch.setattr(ramp, "_ASYNC_PIXELS", 0)
    s = schedule(nframes=20)
    t = s.frame_starts.value
    rng = np.random.default_rng(12)
    cube = (6e4 + 30.0 * t[:, None, None] + rng.normal(0, 5, (20, 16, 16))).astype(np.float32)
    cube[12, 3, 4] = np.nan
    streamed = _stream(Exposure.from_arrays(cube, s))
    whole = fit_ramp(Exposure.from_arrays(cube, s))
    np.testing.assert_allclose(streamed.data.data, whole.data.data, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(streamed.data.uncertainty.array, whole.data.uncertainty.array,
                               rtol=1e-4)
    assert streamed.tables["RAMPFIT"]["nreads"][3][4] == 19
    import threading

    assert not [th for th in threading.enumerate() if th.name.startswith("spherex-reduce-sums")]


@pytest.mark.parametrize("background", [False, True])
@pytest.mark.parametrize("first_usable", [3, 7])
def test_streamed_variance_when_the_first_usable_read_ends_a_buffer(monkeypatch, background,
                                                                    first_usable):
    # with one usable read in its first buffer a pixel has no line yet; without one,
    # a bright pixel's float32 squares lost its residuals (variance off by -22 % / +275 %)
    from spherex_reduce.steps import ramp

    if background:
        monkeypatch.setattr(ramp, "_ASYNC_PIXELS", 0)
    s = schedule(nframes=30)
    t = s.frame_starts.value
    rng = np.random.default_rng(13)
    cube = (1000.0 * t[:, None, None] + rng.normal(0, 10, (30, 16, 16))).astype(np.float32)
    cube[:first_usable] = np.nan  # e.g. reset frames masked for every pixel
    cube[first_usable + 1 : first_usable + 6, 2, 3] = np.nan  # and a pixel with a gap
    streamed = _stream(Exposure.from_arrays(cube, s))
    whole = fit_ramp(Exposure.from_arrays(cube, s))
    np.testing.assert_allclose(streamed.data.uncertainty.array, whole.data.uncertainty.array,
                               rtol=1e-3)
    np.testing.assert_allclose(streamed.data.data, whole.data.data, rtol=1e-6)


def test_accumulator_finishes_once():
    from spherex_reduce.reduction_plugin import FitRampStep

    s = schedule(nframes=5)
    cube = np.random.default_rng(14).normal(0, 1, (5, 16, 16))
    acc = FitRampStep().accumulator(s, Exposure.from_arrays(cube, s).header)
    for k in range(5):
        acc.add(k, Exposure.from_arrays(cube[k : k + 1], s.replace(nframes=1)))
    acc.finish()
    with pytest.raises(RuntimeError, match="called already"):
        acc.finish()


@pytest.mark.parametrize("masked", [0, 7])
def test_streamed_fit_of_bright_ramps_matches_float64_least_squares(masked):
    # 1000 e/s over 74 frames on a 6e4 pedestal: float32 values to 1.7e5, and g t up to
    # 5e4 in the detrending (computed in float64 for such ramps); the first `masked`
    # frames unusable (the line then waits for a second usable read)
    s = schedule(nframes=74, nrows=32, ncols=32)
    t = s.frame_starts.value
    rng = np.random.default_rng(15)
    cube = (6e4 + 1000.0 * t[:, None, None] + rng.normal(0, 10, (74, 32, 32)))
    cube = cube.astype(np.float32)
    cube[:masked] = np.nan
    good = np.isfinite(cube)
    ref, _ = lstsq_reference(cube, t, good)
    tt = t[masked:]
    sigma = 10.0 / np.sqrt(((tt - tt.mean()) ** 2).sum())
    streamed = _stream(Exposure.from_arrays(cube, s))
    assert np.abs(streamed.data.data - ref).max() <= 5e-4 * sigma
