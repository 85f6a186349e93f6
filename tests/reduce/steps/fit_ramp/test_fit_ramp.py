"""fit_ramp against float64 least squares, stcal, and the hard cases; its consumer of bands."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule, dq, fit_ramp
from spherex_reduce.core.block import Block
from spherex_reduce.core.errors import SpherexReduceError, StepSkipped
from spherex_reduce.io.examples import example_raw_exposure, tiny_schedule
from spherex_reduce.io.sources import MemorySource
from spherex_reduce.reduce.executor import execute
from spherex_reduce.reduce.options import RunOptions
from spherex_reduce.reduce.steps.fit_ramp.expected_rates import expected_rates
from spherex_reduce.reduce.steps.fit_ramp.step import FitRampStep, RampFit


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
    again = fit_ramp(out)  # slopes already: skipped, the input comes back
    assert again.header["S_RAMPFT"] == "SKIPPED"
    np.testing.assert_array_equal(again.data.data, out.data.data)


def test_pipeline_step_parameters():
    raw = example_raw_exposure(tiny_schedule(nframes=4))
    p = Pipeline({"steps": [{"fit_ramp": {"saturation": 1e9, "read_noise": 10}}]})
    out = p.run(raw)
    assert out.header["S_RAMPFT"] == "COMPLETE"
    assert out.data.data.shape == (raw.schedule.n_reads, 64)


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


@pytest.mark.parametrize("masked", [0, 7])
def test_bright_ramps_match_float64_least_squares(masked):
    # 1000 e/s over 74 frames on a 6e4 pedestal: float32 values to 1.7e5; the first
    # `masked` frames unusable (those pixels are refitted in float64)
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
    out = fit_ramp(Exposure.from_arrays(cube, s))
    assert np.abs(out.data.data - ref).max() <= 5e-4 * sigma


def test_unknown_weighting_is_one_clear_error():
    s = schedule(nframes=4)
    e = Exposure.from_arrays(np.zeros((4, 16, 16)), s)
    with pytest.raises(SpherexReduceError, match=r"weighting: 'best' is not one of"):
        fit_ramp(e, weighting="best")


# -- the consumer of bands -------------------------------------------------------------

CASES = ["masked", "saturation", "nan", "optimal", "read_noise", "phantom_reference",
         "raw_phantom", "int", "two_frames", "read_noise_middle", "read_noise_uint16"]


def _case(name):
    """An input exercising one path of the fit: ``(exposure, params, cube, usable reads)``."""
    rng = np.random.default_rng(CASES.index(name) + 20)
    s = schedule(nframes=2 if name == "two_frames" else 9)
    t = s.frame_starts.value
    rate = rng.uniform(0, 300, (16, 16))
    cube = 6e4 + rate * t[:, None, None] + rng.normal(0, 5, (t.size, 16, 16))
    params, mask = {}, None
    if name in ("phantom_reference", "raw_phantom"):
        raw = example_raw_exposure(tiny_schedule(nframes=5))
        from spherex_reduce import unchop

        e = unchop(raw) if name == "phantom_reference" else raw
        data = e.data.data
        good = np.isfinite(data) & (e.dq == 0 if e.dq is not None else True)
        return e, params, data, good
    if name == "masked":
        mask = np.zeros(cube.shape, np.uint16)
        mask[2, 1, 1] = dq.DO_NOT_USE
        mask[:, 3, 3] = dq.NOT_READ
        mask[:7, 9, 9] = dq.DO_NOT_USE
        cube[2, 1, 1] = 1e6  # a jump the caller flagged
    elif name == "saturation":
        params = {"saturation": 6.1e4}
        cube[:, 0, 2] = 7e4
    elif name in ("nan", "optimal", "read_noise"):
        cube[3, 4, 5] = cube[0, 7, 7] = np.nan
        cube[:, 6, 6] = np.nan
        if name == "optimal":
            params = {"weighting": "optimal", "read_noise": 5.0}
        elif name == "read_noise":
            params = {"read_noise": 5.0, "gain": 2.0}
    elif name == "read_noise_middle":  # the middle of 9 symmetric reads weighs nothing in the
        # slope, but a ramp with it unusable is not whole (nreads)
        cube[4, 2, 2] = np.nan
        cube[4, 5, :3] = np.inf
        params = {"read_noise": 5.0, "gain": 2.0}
    elif name == "read_noise_uint16":  # integer ADU, made float32 read by read
        params = {"read_noise": 5.0}
    if name == "int":
        cube = np.round(cube).astype(np.int32)
    elif name == "read_noise_uint16":
        cube = np.round(cube).astype(np.uint16)
    else:
        cube = cube.astype(np.float32)
    good = np.isfinite(cube)
    if mask is not None:
        good &= mask == 0
    if "saturation" in params:
        good &= cube <= params["saturation"]
    return Exposure.from_arrays(cube, s, mask=mask, order="physical"), params, cube, good


def _in_bands(exposure, rows, threads, **params):
    source = MemorySource(exposure)
    return execute(source, [], FitRampStep().consumer(source.context, **params),
                   options=RunOptions(threads=threads), rows_per_band=rows)[0]


def _assert_identical(a, b):
    for x, y in [(a.data.data, b.data.data), (a.data.uncertainty.array, b.data.uncertainty.array),
                 (a.dq, b.dq), (a.tables["RAMPFIT"]["nreads"], b.tables["RAMPFIT"]["nreads"]),
                 (a.phantom, b.phantom)]:
        assert (x is None and y is None) or np.array_equal(np.asarray(x), np.asarray(y),
                                                           equal_nan=True)
    if a.reference is not None:
        for name in ("data", "phantom", "dq", "rows", "reads"):
            x, y = getattr(a.reference, name), getattr(b.reference, name)
            assert (x is None and y is None) or np.array_equal(x, y, equal_nan=True), name
    else:
        assert b.reference is None
    for key in ("NFEWRDS", "RAMPWGT"):
        assert a.header[key] == b.header[key]
    assert (a.unit, a.order) == (b.unit, b.order)


@pytest.mark.parametrize("name", CASES)
def test_bands_and_threads_give_one_band_bit_for_bit(name):
    exposure, params, *_ = _case(name)
    one = _in_bands(exposure, exposure.shape[-2], 1, **params)
    _assert_identical(fit_ramp(exposure, **params), one)
    for rows in (1, 3, 7):
        for threads in (1, 3):
            _assert_identical(_in_bands(exposure, rows, threads, **params), one)


@pytest.mark.parametrize("name", CASES)
def test_every_path_matches_float64_least_squares(name):
    exposure, params, cube, good = _case(name)
    out = fit_ramp(exposure, **params)
    t = exposure.schedule.frame_starts.value
    ref, var = lstsq_reference(np.asarray(cube, np.float64), t, good)
    n = good.sum(axis=0)
    assert np.array_equal(np.asarray(out.tables["RAMPFIT"]["nreads"]), n)
    assert np.array_equal(np.isnan(out.data.data), n < 2)
    assert np.array_equal(out.dq & dq.FEW_READS != 0, n < 2)
    slope = out.data.data
    sigma = 5.0 / np.sqrt(((t - t.mean()) ** 2).sum())
    if "read_noise" in params:  # the rate of the shot noise in ERR (tested against the truth
        # in test_a_darks_uncertainty_is_its_scatter and test_a_skys_...)
        parts = out.tables["RAMPFIT"]
        rate = expected_rates(slope, np.asarray(parts["var_rnoise"]),
                              np.asarray(parts["var_per_rate"]),
                              ~exposure.reference_pixel_mask())
        assert rate is not None
    if name == "optimal":
        # GLS on each pixel's usable reads, for its uniform-fit rate binned in
        # rate / read_noise**2 to 0.02 dex (the documented bins), masked reads or not
        rn = params["read_noise"]
        sel = (n < t.size) & (n >= 2)
        for i, j in [(0, 0), (5, 9), (12, 3), *np.argwhere(sel)[:3]]:
            use = good[:, i, j]
            ratio = 10 ** (np.round(np.log10(ref[i, j] / rn**2) * 50) / 50)
            tu = t[use]
            cov = rn**2 * (np.eye(tu.size) + ratio * np.minimum.outer(tu - t[0], tu - t[0]))
            x = np.stack([np.ones(tu.size), tu], 1)
            ci = np.linalg.inv(cov)
            beta = np.linalg.solve(x.T @ ci @ x, x.T @ ci @ cube[use, i, j].astype(float))
            assert slope[i, j] == pytest.approx(beta[1], rel=1e-9)
            unc = out.data.uncertainty.array[i, j]
            w = (np.linalg.inv(x.T @ ci @ x) @ x.T @ ci)[1]  # the GLS weights, at the rate
            m = np.minimum.outer(tu - t[0], tu - t[0])
            assert unc**2 == pytest.approx(rn**2 * (w @ w) + rate[i, j] * (w @ m @ w),
                                           rel=1e-6)
    else:
        np.testing.assert_allclose(slope, ref, rtol=1e-6, atol=1e-3 * sigma)
    if name.startswith("read_noise"):  # the ramps fitted whole: the variance of their reads
        whole = n == t.size
        tc = t - t.mean()
        shot = rate[whole] / params.get("gain", 1.0) * (tc @ np.minimum.outer(t, t) @ tc)
        np.testing.assert_allclose(out.data.uncertainty.array[whole] ** 2,
                                   (params["read_noise"] ** 2 * (tc @ tc) + shot) / (tc @ tc) ** 2,
                                   rtol=1e-6)
    unc2 = out.data.uncertainty.array ** 2
    if "read_noise" not in params:
        np.testing.assert_allclose(unc2, var, rtol=1e-3, atol=1e-12)
    elif name == "read_noise":
        rn, gain = params["read_noise"], params["gain"]
        for i, j in [(0, 0), (4, 5), (6, 6), (7, 7)]:
            g = good[:, i, j]
            if g.sum() < 2:
                assert np.isnan(unc2[i, j])
                continue
            tc = t[g] - t[g].mean()
            w = tc / (tc @ tc)
            shot = rate[i, j] / gain * (w @ np.minimum.outer(t[g], t[g]) @ w)
            assert unc2[i, j] == pytest.approx(rn**2 * (w @ w) + shot, rel=1e-6)
    if exposure.phantom is not None:
        tc = t - t.mean()
        np.testing.assert_allclose(out.phantom, np.einsum("f,fij->ij", tc / (tc @ tc),
                                                          exposure.phantom.astype(float)),
                                   rtol=1e-6, atol=1e-4)
    if exposure.reference is not None:
        rdata = exposure.reference.data.astype(float)
        rref, _ = lstsq_reference(rdata, t, np.isfinite(rdata))
        np.testing.assert_allclose(out.reference.data, rref, rtol=1e-6, atol=1e-4)


def test_consumer_takes_bands_of_scattered_rows_from_several_threads():
    # bands whose rows are not consecutive (e.g. after a kernel reorders rows) are
    # fitted apart and written at their rows; the result is the whole fit, bit for bit
    import threading

    exposure, params, *_ = _case("masked")
    whole = fit_ramp(exposure, **params)
    source = MemorySource(exposure)
    consumer = RampFit(source.context, **params)
    data, flags = exposure.data.data, exposure.dq
    parts = [np.arange(0, 16, 2), np.arange(1, 16, 4), np.arange(15, 2, -4)]
    workers = [threading.Thread(target=consumer.band, args=(
        Block(data[:, idx], idx, "physical", dq=flags[:, idx]),)) for idx in parts]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    out = consumer.finish(None, exposure.header.copy(), dict(exposure.tables))
    _assert_identical(out, whole)


def test_consumer_refuses_images_and_bad_parameters():
    s = schedule(nframes=4)
    image = MemorySource(Exposure.from_arrays(np.zeros((16, 16)), s))
    with pytest.raises(StepSkipped, match="2-D image"):
        FitRampStep().consumer(image.context)
    ramps = MemorySource(Exposure.from_arrays(np.zeros((4, 16, 16)), s))
    with pytest.raises(SpherexReduceError, match="read_noise > 0"):
        FitRampStep().consumer(ramps.context, weighting="optimal", read_noise=0)
    consumer = FitRampStep().consumer(ramps.context)
    with pytest.raises(ValueError, match="3 frames"):
        consumer.band(Block(np.zeros((3, 2, 16)), np.arange(2), "readout"))


def test_threads_are_the_steps_option_not_fixed_at_import():
    exposure, params, *_ = _case("nan")
    step = FitRampStep(threads=3)
    calls = []
    import spherex_reduce.reduce.options as executor_module  # where the bands' pool is made

    real = executor_module.ThreadPoolExecutor

    class Counting(real):
        def __init__(self, n, **kw):
            calls.append(n)
            super().__init__(n, **kw)

    try:
        executor_module.ThreadPoolExecutor = Counting
        source = MemorySource(exposure)
        out, _ = execute(source, [], step.consumer(source.context, **params),
                         options=step.options, rows_per_band=4)
    finally:
        executor_module.ThreadPoolExecutor = real
    assert calls == [3]
    _assert_identical(out, fit_ramp(exposure, **params))


def test_optimal_weighting_of_bright_float32_ramps_is_gls_not_uniform():
    # bright float32 ramps were refitted with uniform weights in float64 (their float32
    # sums are too coarse for a uniform slope), silently dropping the optimal weights
    s = schedule(nframes=9, nrows=4, ncols=4, nch=1)
    t = s.frame_starts.value
    rng = np.random.default_rng(30)
    rn = 5.0
    cube = (6e4 + 200.0 * t[:, None, None] + rng.normal(0, rn, (9, 4, 4))).astype(np.float32)
    out = fit_ramp(Exposure.from_arrays(cube, s), weighting="optimal", read_noise=rn)
    uniform, _ = lstsq_reference(cube, t)
    x = np.stack([np.ones(t.size), t], 1)
    for i, j in [(0, 0), (3, 2)]:
        rate = rn**2 * 10 ** (np.round(np.log10(uniform[i, j] / rn**2) * 50) / 50)
        ci = np.linalg.inv(rn**2 * np.eye(t.size) + rate * np.minimum.outer(t - t[0], t - t[0]))
        beta = np.linalg.solve(x.T @ ci @ x, x.T @ ci @ cube[:, i, j].astype(float))
        assert out.data.data[i, j] == pytest.approx(beta[1], rel=1e-9)
        assert abs(beta[1] - uniform[i, j]) > 1e-3


def test_least_squares_refuses_an_output_it_could_not_write_through():
    from spherex_reduce.reduce.steps.fit_ramp.least_squares import LeastSquares, RampSolution

    ls = LeastSquares(np.arange(4.0))
    whole = RampSolution((3, 8))
    cols = RampSolution.__new__(RampSolution)
    for name in whole.arrays:
        setattr(cols, name, getattr(whole, name)[:, ::2])  # a strided view: reshape copies
    cols.var_rnoise = cols.var_per_rate = None
    with pytest.raises(ValueError, match="C-ordered"):
        ls.fit(np.zeros((4, 3, 4)), out=cols)
    ramps = np.arange(4.0)[:, None, None] * np.ones((4, 3, 8))
    assert np.array_equal(ls.fit(ramps, out=whole).slope, np.ones((3, 8)))


def test_big_endian_float64_ramps_are_fitted_in_float64(tmp_path):
    """FITS stores float64 big-endian: the fit must not fall back to float32 sums for it."""
    s = schedule(nframes=5)
    rng = np.random.default_rng(3)
    cube = 6e4 + rng.normal(0, 10, (5, 16, 16)) + 0.37 * np.arange(5)[:, None, None]
    native = fit_ramp(Exposure.from_arrays(cube, s))
    swapped = fit_ramp(Exposure.from_arrays(cube.astype(">f8"), s))
    np.testing.assert_array_equal(swapped.data.data, native.data.data)
    np.testing.assert_array_equal(swapped.data.uncertainty.array,
                                  native.data.uncertainty.array)


@pytest.mark.parametrize("shape", [(1, 8, 8), (2, 1, 8, 8)], ids=["3-D", "4-D"])
def test_one_frame_ramps_are_refused_in_one_line(tmp_path, capsys, shape):
    """A ramp of one frame has no slope: it gave an all-NaN image with exit 0."""
    from astropy.io import fits

    from spherex_reduce.cli import main

    path = tmp_path / "one.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.ones(shape, np.float32), name="SCI")]
                 ).writeto(path)
    config = tmp_path / "fit.yaml"
    config.write_text("geometry: {nrows: 8, ncols: 8, nchannels: 1, ref_border: 0, "
                      "pixel_rate: 1.0e+5}\n"
                      "readout: {skip: 1, ref_reads: 0, ref_mode: none, phantom_reads: 0, "
                      "nframes: 1, frame_time: 1.0}\nsteps: [fit_ramp]\n")
    assert main(["-q", "reduce", str(path), "-c", str(config), "-o",
                 str(tmp_path / "out.fits")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at least 2 frames; this one has 1" in err[0]
    assert not (tmp_path / "out.fits").exists()


@pytest.mark.parametrize("weighting", ["uniform", "optimal"])
def test_bright_and_dark_ramps_with_read_noise_match_float64_least_squares(weighting):
    # float32 ramps on a 6e4 pedestal over 74 reads, 0 to 3000 e/s side by side: the bright
    # ones' float32 sums are too coarse and are summed again in float64; every slope is the
    # float64 least-squares (or GLS) slope and every uncertainty the model's
    s = schedule(nframes=74, nrows=16, ncols=16)
    t = s.frame_starts.value
    rng = np.random.default_rng(41)
    rn = 10.0
    rate = np.where(rng.random((16, 16)) < 0.3, rng.uniform(50, 3000, (16, 16)),
                    rng.uniform(0, 1, (16, 16)))
    rate[0, :4] = -200.0  # negative slopes too
    cube = (6e4 + rate * t[:, None, None] + rng.normal(0, rn, (74, 16, 16))).astype(np.float32)
    exposure = Exposure.from_arrays(cube, s)
    out = fit_ramp(exposure, read_noise=rn, weighting=weighting)
    for rows in (1, 5):  # the pixels summed again in float64 do not depend on the band
        _assert_identical(_in_bands(exposure, rows, 2, read_noise=rn, weighting=weighting), out)
    ref, _ = lstsq_reference(cube, t)
    tc = t - t.mean()
    w = tc / (tc @ tc)
    sigma = rn * np.sqrt(w @ w)
    shot = w @ np.minimum.outer(t - t[0], t - t[0]) @ w
    if weighting == "uniform":
        assert np.abs(out.data.data - ref).max() <= 5e-4 * sigma
        # the shot noise of the expected rates (which keep each pixel's own where the rates
        # spread this much; see test_a_skys_uncertainty_keeps_each_pixels_rate)
        model = rn**2 * (w @ w) + expected_rates(ref, np.full(ref.shape, rn**2 * (w @ w)),
                                                 np.full(ref.shape, shot),
                                                 ~exposure.reference_pixel_mask()) * shot
        np.testing.assert_allclose(out.data.uncertainty.array ** 2, model, rtol=1e-6)
    else:  # GLS at the uniform slope's rate binned to 0.02 dex (rate <= 0: uniform weights)
        x = np.stack([np.ones(t.size), t], 1)
        for i, j in [*np.argwhere(rate > 1000)[:3], (0, 0), (0, 1)]:
            ratio = max(ref[i, j], 0) / rn**2
            q = 10 ** (np.round(np.log10(ratio) * 50) / 50) if ratio > 1e-6 else 0.0
            ci = np.linalg.inv(rn**2 * (np.eye(t.size) + q * np.minimum.outer(t - t[0],
                                                                             t - t[0])))
            beta = np.linalg.solve(x.T @ ci @ x, x.T @ ci @ cube[:, i, j].astype(float))
            assert out.data.data[i, j] == pytest.approx(beta[1], rel=1e-9, abs=1e-3 * sigma)
    parts = out.tables["RAMPFIT"]
    if weighting == "uniform":
        np.testing.assert_allclose(np.asarray(parts["var_per_rate"]), shot, rtol=1e-6)
        np.testing.assert_allclose(np.asarray(parts["var_rnoise"]), rn**2 * (w @ w), rtol=1e-6)


def _dark_ramps(rng, nframes, shape, rate, read_noise, dt):
    """Poisson charge at ``rate`` e/s plus white read noise, on a pedestal (float32)."""
    charge = np.cumsum(rng.poisson(rate * dt, (nframes, *shape)), axis=0)
    charge -= charge[0]
    return (6e4 + charge + rng.normal(0, read_noise, (nframes, *shape))).astype(np.float32)


@pytest.mark.parametrize("rate", [0.01, 0.0])
def test_a_darks_uncertainty_is_its_scatter(rate):
    """Issue 35: the shot noise in ERR came from each pixel's own slope clipped at 0; on a
    dark the slope is mostly read noise, so ERR overstated the slopes' scatter (~6 % on 74
    reads of 10 e) and most where the slope fluctuated up.  ``(slope - rate) / ERR`` must
    have rms 1 within 2 % (2**16 pixels: +-0.3 %), and ERR be the true sigma of the
    least-squares slope for read noise and the rate's shot noise (numpy, in the test)
    within 1 % for 99 % of the pixels and 5 % for 99.9 % (the others' slopes lie 3.5
    sigma or more out, where the rate moves to their own: a warm pixel's)."""
    nf, dt, rn = 74, 1.5, 10.0
    rows, cols = 128, 512
    s = ReadoutSchedule(DetectorGeometry(rows, cols, 8, ref_border=0), skip=1, ref_reads=0,
                        ref_mode="none", phantom_reads=0, nframes=nf, frame_time=dt)
    cube = _dark_ramps(np.random.default_rng(3521), nf, (rows, cols), rate, rn, dt)
    out = fit_ramp(Exposure.from_arrays(cube, s), read_noise=rn)
    t = dt * np.arange(nf)
    w = (t - t.mean()) / ((t - t.mean()) ** 2).sum()
    sigma = np.sqrt(rn ** 2 * (w @ w) + rate * (w @ np.minimum.outer(t, t) @ w))
    err = out.data.uncertainty.array
    pull = (out.data.data - rate) / err
    assert abs(np.sqrt(np.mean(pull ** 2)) - 1) < 0.02
    off = np.abs(err / sigma - 1)
    assert np.quantile(off, 0.99) < 0.01 and np.quantile(off, 0.999) < 0.05


def test_a_skys_uncertainty_keeps_each_pixels_rate():
    """Rates that spread more than the slopes' noise (a sky) and a hot pixel on it keep
    their own shot noise: ``(slope - rate) / ERR`` has rms 1 within 3 % over the sky, and
    the hot pixel's ERR is the sigma at its true rate within 3 % (numpy, in the test)."""
    nf, dt, rn = 74, 1.5, 10.0
    rows, cols = 64, 256
    s = ReadoutSchedule(DetectorGeometry(rows, cols, 4, ref_border=0), skip=1, ref_reads=0,
                        ref_mode="none", phantom_reads=0, nframes=nf, frame_time=dt)
    rng = np.random.default_rng(3522)
    rate = 0.5 * np.exp(rng.standard_normal((rows, cols)))
    rate[0, 0] = 50.0  # a hot pixel
    cube = _dark_ramps(rng, nf, (rows, cols), rate, rn, dt)
    out = fit_ramp(Exposure.from_arrays(cube, s), read_noise=rn)
    t = dt * np.arange(nf)
    w = (t - t.mean()) / ((t - t.mean()) ** 2).sum()
    sigma = np.sqrt(rn ** 2 * (w @ w) + rate * (w @ np.minimum.outer(t, t) @ w))
    err = out.data.uncertainty.array
    assert abs(np.sqrt(np.mean(((out.data.data - rate) / err) ** 2)) - 1) < 0.03
    assert err[0, 0] == pytest.approx(sigma[0, 0], rel=0.03)


@pytest.mark.parametrize("sky", [False, True])
def test_expected_rates_of_a_large_exposure_follow_the_whole_bulks_formula(sky):
    """Above `BULK_SAMPLE` (2**16) pixels the bulk is measured on every k-th one: the rates
    stay those of the documented formula with the medians of every pixel to 0.1 of the
    slopes' sigma (the sampled MAD's ~1 % error lets ~1 % of each slope's departure
    through on a flat dark), and ERR's variance to 0.5 % rms; NaN slopes and variances take
    the pixel's own rate."""
    from scipy.special import expit

    n, sigma = 1 << 20, 0.036
    rng = np.random.default_rng(31)
    truth = rng.lognormal(-0.7, 1.0, n) if sky else np.full(n, 0.01)
    slope = truth + sigma * rng.standard_normal(n)
    slope[::997] = 50.0  # hot pixels: their own rate
    var_rnoise = np.full(n, sigma**2 * 0.9, np.float32)
    var_per_rate = np.full(n, sigma**2 * 0.1 / 0.01, np.float32)
    slope[::501] = np.nan
    var_rnoise[::777] = np.nan
    # the formula of the docstring, with the medians of every pixel (float64)
    vr, vp = var_rnoise.astype(np.float64), var_per_rate.astype(np.float64)
    ok = np.isfinite(slope) & np.isfinite(vr)
    m = np.median(slope[ok])
    mad2 = (1.482602218505602 * np.median(np.abs(slope[ok] - m))) ** 2
    v = vr + max(m, 0) * vp
    tau2 = max(mad2 - np.median(v[ok]), 0.0)
    d = slope - m
    shrunk = m + tau2 * d / (tau2 + v)
    far = expit(d * d / (2 * (tau2 + v)) - 8.0)
    want = np.where(ok, np.maximum((1 - far) * shrunk + far * slope, 0), np.maximum(slope, 0))
    got = expected_rates(slope, var_rnoise, var_per_rate)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.nanmax(np.abs(got - want)) < 0.1 * sigma
    hot = np.isfinite(got[::997])
    assert np.allclose(got[::997][hot], 50.0)
    # the variance they give ERR (a tenth of it shot noise): 0.5 % rms of the formula's,
    # at most 3 %
    dev = (vr + got * vp) / (vr + want * vp) - 1
    assert np.sqrt(np.nanmean(dev ** 2)) < 5e-3
    assert np.nanmax(np.abs(dev)) < 3e-2


@pytest.mark.parametrize("pattern", ["even-odd", "channel-edge"])
def test_the_sampled_bulk_sees_every_column(pattern):
    """The sample of the bulk walks through every column: on 2048 columns of 64-column
    channels a stride of 64 saw one column of each channel, and a column pattern (ACN's
    even/odd offset, a channel's first column) moved the bulk's median by 0.5-1.4 sigma."""
    nrows, ncols, sigma = 1024, 2048, 0.036
    rng = np.random.default_rng(32)
    slope = 0.01 + sigma * rng.standard_normal((nrows, ncols))
    if pattern == "even-odd":
        slope[:, 0::2] += 0.02
        slope[:, 1::2] -= 0.02
    else:
        slope[:, ::64] += 0.05
    var_rnoise = np.full(slope.shape, sigma**2 * 0.9, np.float32)
    var_per_rate = np.full(slope.shape, sigma**2 * 0.1 / 0.01, np.float32)
    rate = expected_rates(slope, var_rnoise, var_per_rate)
    # a flat bulk's expected rate is its median: that of every pixel, to its sampling error
    m = np.median(slope)
    typical = np.median(rate)
    assert abs(typical - m) < 0.05 * sigma, (typical, m)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_two_reads_are_one_difference_and_no_pixel_is_refitted(monkeypatch, dtype):
    """With two reads the line goes through both: no residual whose precision the
    segment refit would keep (it was given every pixel: ~1 s of a full-size 2-read
    reduction, for slopes the same to float32 rounding of float32 reads), no variance from
    the data; the slope is numpy's difference over the interval."""
    from spherex_reduce.reduce.steps.fit_ramp.least_squares import LeastSquares

    refit = []
    original = LeastSquares._refit
    monkeypatch.setattr(LeastSquares, "_refit", lambda self, block, rmask, bidx, *a:
                        (refit.append(len(bidx)), original(self, block, rmask, bidx, *a))[1])
    rng = np.random.default_rng(3)
    t = np.array([0.0, 1.37])
    cube = (rng.normal(1e4, 50.0, (2, 64, 64)) + rng.normal(0, 3e3, (2, 64, 64))).astype(dtype)
    out = LeastSquares(t).fit(cube)
    assert sum(refit) == 0
    want = (cube[1].astype(np.float64) - cube[0]) / 1.37
    np.testing.assert_allclose(out.slope, want, rtol=2e-7 if dtype == np.float32 else 1e-14)
    assert np.isnan(out.var).all() and (out.nsegments == 1).all()


def test_optimal_weighting_of_unequal_groups_at_no_rate_is_weighted_least_squares():
    """Groups of 1, 2, 4 and 8 frames of read noise alone (gain 1e9: no shot noise): the
    optimal slope is weighted least squares with weights 1, 2, 4, 8 (numpy), and its error
    that fit's; they were the uniform fit's, the weights of equal reads at no rate."""
    groups = [[0], [1, 2], [3, 4, 5, 6], [7, 8, 9, 10, 11, 12, 13, 14]]
    s = ReadoutSchedule(DetectorGeometry(16, 16, 1, ref_border=0), skip=1, ref_reads=0,
                        ref_mode="none", phantom_reads=0, nframes=4, frame_time=1.5,
                        groups=groups)
    t = s.frame_starts.to_value(u.s)
    n = np.array([1.0, 2.0, 4.0, 8.0])
    rng = np.random.default_rng(5)
    cube = 6e4 + rng.standard_normal((4, 16, 16)) * 10.0 / np.sqrt(n)[:, None, None]
    out = fit_ramp(Exposure.from_arrays(cube.astype(np.float32), s), weighting="optimal",
                   read_noise=10.0, gain=1e9)
    x = np.stack([np.ones(4), t], 1)
    cov = np.linalg.inv(x.T @ np.diag(n) @ x)
    want = (cov @ x.T @ np.diag(n) @ cube.reshape(4, -1).astype(np.float32).astype(float))[1]
    np.testing.assert_allclose(out.data.data.ravel(), want, rtol=0, atol=1e-6)
    np.testing.assert_allclose(out.data.uncertainty.array, 10.0 * np.sqrt(cov[1, 1]),
                               rtol=1e-6)


@pytest.mark.parametrize("kind", ["uniform", "optimal", "jump_prior"])
def test_maps_without_a_gain_mean_read_noise_alone_on_every_path(kind):
    """``RampMaps(read_noise=..., pscale=None)`` ("no shot noise") on ramps fitted whole and
    on a ramp split by a JUMP: the slopes are numpy's least squares and their variances
    the read noise's alone, ``sigma**2 / sum(tc**2)`` (and the two segments' inverse-variance
    combination).  It raised (None times a number) on every path but the split ramp's."""
    from spherex_reduce.reduce.steps.fit_ramp.least_squares import LeastSquares, RampMaps

    t = np.arange(12) * 1.5
    rng = np.random.default_rng(8)
    cube = 6e4 + 0.5 * t[:, None, None] + rng.standard_normal((12, 3, 4)) * 2.0
    mask = np.zeros(cube.shape, np.uint32)
    mask[5, 1, 2] = dq.JUMP  # a step starts at read 5
    cube[5:, 1, 2] += 300.0
    fitter = LeastSquares(t, weighting="optimal" if kind == "optimal" else "uniform",
                          jump_prior=0.01 if kind == "jump_prior" else None)
    fit = fitter.fit(cube.astype(np.float32), mask, maps=RampMaps(read_noise=2.0, pscale=None))

    def lsq(y, tt):
        tc = tt - tt.mean()
        return tc @ (y - y.mean()) / (tc @ tc), 4.0 / (tc @ tc)

    y = cube.astype(np.float32).astype(np.float64)
    slope, var = np.empty((3, 4)), np.empty((3, 4))
    for r in range(3):
        for c in range(4):
            slope[r, c], var[r, c] = lsq(y[:, r, c], t)
    (s1, v1), (s2, v2) = lsq(y[:5, 1, 2], t[:5]), lsq(y[5:, 1, 2], t[5:])
    var[1, 2] = 1.0 / (1.0 / v1 + 1.0 / v2)
    slope[1, 2] = (s1 / v1 + s2 / v2) * var[1, 2]
    if kind != "jump_prior":  # (the prior weighs plausible steps: its slopes are its own)
        np.testing.assert_allclose(fit.slope, slope, rtol=0, atol=1e-4)
        np.testing.assert_allclose(fit.var, var, rtol=1e-6)
    else:
        assert np.all(np.isfinite(fit.var)) and np.all(fit.var >= var * (1 - 1e-6))
        np.testing.assert_allclose(fit.slope[1, 2], slope[1, 2], rtol=0, atol=1e-4)
