"""stcal's ramp-fitting and jump test cases, run through ``detect_jumps`` and ``fit_ramp``.

The cases (inputs and the values stcal's tests assert) are data in
``tests/_stcal_cases.py``, each naming the stcal tests it re-creates.  stcal's
conventions are translated here: its group DQ bits to ours, its read noise (of
a difference of two frames) to our per-read noise, ``read_noise / sqrt(2)``.

stcal weights the segments of a ramp, and the integrations of an exposure, by
their read-noise variance alone; we weight by the inverse of the whole
variance.  The two agree when shot noise is negligible, so slopes and the
read-noise variance are compared from fits with a gain so large that the
shot noise vanishes (`NO_SHOT_NOISE`); the whole uncertainty is compared, with
the case's gain, where stcal's shot-noise variance is exact (two-group
segments, falling ramps).  stcal's slopes agree to 2e-5 (its test tolerance;
it computes in float32).  Where stcal weights a segment's groups by its
signal to noise (``snr_weighted``) the slope is compared with uniform least
squares on the same segments (numpy, below) instead; the differences are
listed in the docs ("Agreement with stcal's test cases").

With stcal installed, `test_stcal_gives_the_recorded_values` checks that the
recorded values are what stcal 1.20 computes from the same inputs.
"""

import numpy as np
import pytest
from _stcal_cases import (
    CAS22_FLUX,
    CAS22_JUMP,
    CAS22_READ_NOISE,
    CAS22_READ_PATTERN,
    CAS22_READ_TIME,
    DNU,
    JUMP,
    JUMP_CASES,
    MULTI_CASES,
    RAMP_CASES,
    SAT,
)
from astropy import units as u

import spherex_reduce
from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, dq, fit_ramp
from spherex_reduce.reduce.integrations import combine_integrations

#: a gain (electrons per data unit) at which the shot noise is nothing
NO_SHOT_NOISE = 1e30
#: stcal's own test tolerance (relative and absolute; it computes in float32)
TOL = 2e-5


def _ids(cases):
    return [c.id.split("::")[1] for c in cases]


def _our_flags(stcal_dq):
    """stcal group DQ bits as ours (the input mask)."""
    stcal_dq = np.asarray(stcal_dq)
    out = np.zeros(stcal_dq.shape, np.uint32)
    for theirs, ours in ((DNU, dq.DO_NOT_USE), (SAT, dq.SATURATED), (JUMP, dq.JUMP)):
        out[(stcal_dq & theirs) != 0] |= ours
    return out


def _expected_image_flags(stcal_dq):
    """What an output DQ of stcal means in our bits: DO_NOT_USE is "no slope"
    (our FEW_READS), SATURATED and JUMP inform."""
    out = 0
    if stcal_dq & DNU:
        out |= dq.FEW_READS
    if stcal_dq & SAT:
        out |= dq.SATURATED
    if stcal_dq & JUMP:
        out |= dq.JUMP
    return out


def _schedule(ngroups, npix, case, frame_time=None):
    """A one-row schedule of ``npix`` pixels read as ``ngroups`` groups of ``case``."""
    geometry = DetectorGeometry(1, npix, 1, ref_border=0)
    extra = {}
    groups = getattr(case, "groups", None)
    nframes, gap = getattr(case, "nframes", 1), getattr(case, "groupgap", 0)
    if frame_time is None:
        frame_time = getattr(case, "group_time", 1.0) / (nframes + gap)
    if groups is not None:
        extra["groups"] = [list(g) for g in groups]
    elif nframes > 1 or gap:
        extra.update(frames_per_group=nframes, group_gap=gap)
    return ReadoutSchedule(geometry, ref_mode="none", phantom_reads=0, skip=1, ref_reads=0,
                           nframes=ngroups, frame_time=frame_time, **extra)


def _fit(case, k, gain):
    """``fit_ramp`` of integration ``k`` of ``case``."""
    data, flags = case.cube(k)
    exposure = Exposure.from_arrays(data, _schedule(data.shape[0], data.shape[2], case),
                                    unit=u.electron, mask=_our_flags(flags))
    extra = {"dark_current": case.dark_current} if case.dark_current else {}
    return fit_ramp(exposure, read_noise=case.read_noise / np.sqrt(2), gain=gain, **extra)


def _values(image):
    return (image.data.data[0], image.data.uncertainty.array[0] ** 2, image.dq[0])


def _uniform_segments(values, flags, times, sigma):
    """Uniform least squares on each segment, combined by read-noise variance (numpy).

    The usable groups are those before the first saturated one and not
    DO_NOT_USE; a group flagged JUMP starts a new segment; segments of one
    group carry no slope.
    """
    slopes, weights = [], []
    segment = []
    sat = np.flatnonzero(np.asarray(flags) & SAT)
    end = sat[0] if sat.size else len(values)
    for k in range(end):
        if flags[k] & DNU:
            continue
        if flags[k] & JUMP and segment:
            slopes, weights = _close(segment, values, times, sigma, slopes, weights)
            segment = []
        segment.append(k)
    slopes, weights = _close(segment, values, times, sigma, slopes, weights)
    weights = np.array(weights)
    if not weights.size:
        return np.nan, np.nan
    return float(np.dot(slopes, weights) / weights.sum()), float(1 / weights.sum())


def _close(segment, values, times, sigma, slopes, weights):
    if len(segment) >= 2:
        t, y = np.asarray(times)[segment], np.asarray(values, float)[segment]
        slopes = [*slopes, np.polyfit(t, y, 1)[0]]
        weights = [*weights, ((t - t.mean()) ** 2).sum() / sigma**2]
    return slopes, weights


def _check_image(case, slope, var_r, flags, expected_slope, expected_dq, expected_var_r):
    """Compare an image with stcal's values, except the pixels of one-group slopes."""
    for p, want in enumerate(expected_slope):
        if p in case.one_group:
            continue
        if np.isnan(want):
            assert np.isnan(slope[p]), f"pixel {p}: slope {slope[p]}, stcal has none"
        else:
            np.testing.assert_allclose(slope[p], want, rtol=TOL, atol=TOL,
                                       err_msg=f"pixel {p} slope")
            if expected_var_r is not None:
                np.testing.assert_allclose(var_r[p], expected_var_r[p], rtol=TOL, atol=1e-9,
                                           err_msg=f"pixel {p} read-noise variance")
    for p, want in enumerate(expected_dq):
        if want is None or p in case.one_group:  # not asserted by stcal, or one group
            continue
        mine = int(flags[p]) & (dq.FEW_READS | dq.SATURATED | dq.JUMP)
        assert dq.describe(mine) == dq.describe(_expected_image_flags(want)), (
            f"pixel {p}: flags {dq.describe(flags[p])}, stcal's {want} means "
            f"{dq.describe(_expected_image_flags(want))}")
        assert bool(dq.image_usable(flags[p])) == (not want & DNU), f"pixel {p} usable"


def _uniform_expected(case, k):
    """Slopes and read-noise variances of uniform least squares on the segments of
    integration ``k`` (NaN where no segment has two groups)."""
    data, stcal_flags = case.cube(k)
    times = np.arange(data.shape[0]) * case.group_time
    sigma = case.read_noise / np.sqrt(2 * case.nframes)  # one group's read noise
    out = []
    for p in range(data.shape[2]):
        with np.errstate(invalid="ignore", divide="ignore"):
            out.append(_uniform_segments(data[:, 0, p], stcal_flags[:, 0, p], times, sigma))
    return np.array(out).T


@pytest.mark.parametrize("case", RAMP_CASES, ids=_ids(RAMP_CASES))
def test_ramp_case(case):
    slope, var_r, flags = _values(_fit(case, 0, NO_SHOT_NOISE))
    expected = _uniform_expected(case, 0)[0] if case.snr_weighted else case.slope
    _check_image(case, slope, var_r, flags, expected, case.dq, case.var_rnoise)
    if case.err is not None:
        _, var, _ = _values(_fit(case, 0, case.gain))
        for p, want in enumerate(case.err):
            if want is not None and np.isfinite(want) and p not in case.one_group:
                np.testing.assert_allclose(np.sqrt(var[p]), want, rtol=TOL,
                                           err_msg=f"pixel {p} uncertainty")
    if case.dark_current:
        # stcal: the Poisson variance of the falling ramp is the dark current's, 0.11
        _, var, _ = _values(_fit(case, 0, case.gain))
        np.testing.assert_almost_equal(var[0] - var_r[0], 0.11, 2)


@pytest.mark.parametrize("case", MULTI_CASES, ids=_ids(MULTI_CASES))
def test_integrations_case(case):
    fits = [_fit(case, k, NO_SHOT_NOISE) for k in range(case.nints)]
    expected = case.slope
    if case.snr_weighted:  # uniform least squares on every segment of every integration
        slopes, var_r = np.array([_uniform_expected(case, k) for k in range(case.nints)]).transpose(
            1, 0, 2)
        with np.errstate(invalid="ignore"):
            expected = np.nansum(slopes / var_r, axis=0) / np.nansum(1 / var_r, axis=0)
    for k, image in enumerate(fits):
        slope, _, flags = _values(image)
        if case.int_slope is not None:
            want = slopes[k] if case.snr_weighted else case.int_slope[k]
            _check_image(case, slope, None, flags, want, (None,) * slope.size, None)
        if case.int_dq is not None:
            for p, want in enumerate(case.int_dq[k]):
                if p in case.one_group:
                    continue
                assert bool(dq.image_usable(flags[p])) == (not want & DNU), (
                    f"integration {k} pixel {p}: {dq.describe(flags[p])}, stcal's DQ {want}")
    mean = combine_integrations(fits).exposure
    slope, var_r, flags = _values(mean)
    _check_image(case, slope, var_r, flags, expected, case.dq, case.var_rnoise)
    if case.err is not None:
        combined = combine_integrations([_fit(case, k, case.gain) for k in range(case.nints)])
        np.testing.assert_allclose(combined.exposure.data.uncertainty.array[0],
                                   [e for e in case.err], rtol=TOL)


@pytest.mark.parametrize("case", JUMP_CASES, ids=_ids(JUMP_CASES))
def test_jump_case(case):
    data, flags = case.cube()
    exposure = Exposure.from_arrays(data, _schedule(data.shape[0], data.shape[2], case,
                                                    frame_time=1.0),
                                    unit=u.electron, mask=_our_flags(flags))
    out = spherex_reduce.detect_jumps(exposure, read_noise=case.read_noise / np.sqrt(2),
                                      gain=case.gain)
    jumped = (out.dq[:, 0, :] & dq.JUMP) != 0
    assert not ((out.dq[:, 0, :] & ~np.uint32(dq.JUMP)) != _our_flags(flags)[:, 0, :]).any(), (
        "detect_jumps changed flags other than JUMP")
    for p in range(data.shape[2]):
        got = np.flatnonzero(jumped[:, p]).tolist()
        if case.any_jump:
            assert got, f"pixel {p}: no jump found"
        else:
            assert set(case.jumps[p]) <= set(got), f"pixel {p}: jumps at {got}, stcal's at " \
                                                   f"{list(case.jumps[p])}"
        wrong = set(got) & set(case.clean[p])
        assert not wrong, f"pixel {p}: jumps at {sorted(wrong)}, which stcal leaves clean"


def _resultants(rng, n, jumps=False):
    """Roman resultants of ``n`` x ``n`` pixels as stcal's cas22 tests simulate them
    (100 e/s, read noise 5 e); with ``jumps``, 1000 e at a random read of each pixel."""
    nread = np.array([len(g) for g in CAS22_READ_PATTERN])
    nreads = CAS22_READ_PATTERN[-1][-1]
    counts = np.cumsum(rng.poisson(CAS22_READ_TIME * CAS22_FLUX, (nreads, n * n)), axis=0)
    counts = counts.astype(np.float64)
    if jumps:
        at = rng.integers(nreads - 1, size=n * n)  # the read at which the charge steps
        counts += CAS22_JUMP * (np.arange(nreads)[:, None] >= at[None, :])
    resultants = np.stack([counts[np.array(g) - 1].mean(axis=0) for g in CAS22_READ_PATTERN])
    resultants += rng.standard_normal(resultants.shape) * (CAS22_READ_NOISE
                                                           / np.sqrt(nread))[:, None]
    return resultants.reshape(len(nread), n, n).astype(np.float32)


def _resultant_schedule(n):
    geometry = DetectorGeometry(n, n, 1, ref_border=0)
    return ReadoutSchedule(geometry, ref_mode="none", phantom_reads=0, skip=1, ref_reads=0,
                           nframes=len(CAS22_READ_PATTERN), frame_time=CAS22_READ_TIME,
                           groups=[[r - 1 for r in g] for g in CAS22_READ_PATTERN])


def _chi2(image, okay):
    slope = image.data.data.ravel()[okay]
    sigma = image.data.uncertainty.array.ravel()[okay]
    assert np.isfinite(slope).all()
    return np.mean((slope - CAS22_FLUX) ** 2 / sigma**2)


@pytest.mark.parametrize("detect", [False, True], ids=["fit", "detect-fit"])
@pytest.mark.parametrize("use_dq", [False, True], ids=["all-reads", "30%-flagged"])
def test_simulated_resultants(use_dq, detect):
    """test_ramp_fitting_cas22.py::test_simulated_ramps and test_jump_cas22.py::
    test_fit_ramps: Roman resultants of 100 e/s with read noise 5 e, 30 % of them
    flagged or none, with or without jump detection (there are no jumps): the
    slopes scatter as their uncertainties say (chi2 per ramp within 0.03 of 1 on
    320 x 320 ramps)."""
    rng = np.random.default_rng(42)
    n = 320
    cube = _resultants(rng, n)
    flags = np.zeros(cube.shape, np.uint32)
    if use_dq:
        flags[rng.uniform(size=cube.shape) > 0.7] = dq.DO_NOT_USE
    exposure = Exposure.from_arrays(cube, _resultant_schedule(n), unit=u.electron, mask=flags)
    if detect:
        exposure = spherex_reduce.detect_jumps(exposure, read_noise=CAS22_READ_NOISE, gain=1.0)
    image = fit_ramp(exposure, read_noise=CAS22_READ_NOISE, gain=1.0)
    # a ramp has a slope when two adjacent groups are usable
    okay = (((flags[1:] == 0) & (flags[:-1] == 0)).any(axis=0)).ravel()
    assert abs(_chi2(image, okay) - 1) < 0.03


def test_resultants_with_jumps():
    """test_jump_cas22.py::test_find_jumps: the same resultants with a jump of
    1000 e at a random read of every pixel.  stcal leaves out the pixels whose jump
    it missed and asserts chi2 within 0.03 of 1 on the rest; we leave out only pixels
    with no two-read segment (1 of 102400), and a
    jump between the reads of a long group (up to 8 reads averaged) is partly missed
    under heavy shot noise: chi2 1.26 (the docs list it), against ~17 without
    ``detect_jumps`` and 1.005 with the true jump flags."""
    rng = np.random.default_rng(619)
    n = 320
    exposure = Exposure.from_arrays(_resultants(rng, n, jumps=True), _resultant_schedule(n),
                                    unit=u.electron)
    found = spherex_reduce.detect_jumps(exposure, read_noise=CAS22_READ_NOISE, gain=1.0)
    image = fit_ramp(found, read_noise=CAS22_READ_NOISE, gain=1.0)
    usable = dq.image_usable(image.dq).ravel()
    assert usable.mean() > 0.999  # a pixel flagged at every group has no slope
    chi2 = _chi2(image, usable)
    plain = fit_ramp(exposure, read_noise=CAS22_READ_NOISE, gain=1.0)
    missed = np.nanmean((plain.data.data - CAS22_FLUX) ** 2 / plain.data.uncertainty.array**2)
    assert chi2 < 1.3 and missed > 10 * chi2, (chi2, missed)


def _stcal_ramp_fit(case):
    """stcal's OLS_C on the inputs of ``case`` (all integrations)."""
    from stcal.ramp_fitting.ramp_fit import ramp_fit_data
    from stcal.ramp_fitting.ramp_fit_class import RampData

    data = np.stack([case.cube(k)[0] for k in range(case.nints)])
    gdq = np.stack([case.cube(k)[1] for k in range(case.nints)]).astype(np.uint8)
    shape = data.shape[2:]
    ramp = RampData()
    ramp.set_arrays(data=data, groupdq=gdq, pixeldq=np.zeros(shape, np.uint32),
                    average_dark_current=np.full(shape, case.dark_current, np.float32))
    ramp.set_meta(name=case.instrument, frame_time=case.group_time / (case.nframes + case.groupgap),
                  group_time=case.group_time, groupgap=case.groupgap, nframes=case.nframes,
                  drop_frames1=None)
    ramp.set_dqflags({"GOOD": 0, "DO_NOT_USE": DNU, "SATURATED": SAT, "JUMP_DET": JUMP,
                      "PERSISTENCE": 2**5, "CHARGELOSS": 2**7, "NO_GAIN_VALUE": 2**19,
                      "UNRELIABLE_SLOPE": 2**24})
    ramp.suppress_one_group_ramps = case.suppress_one_group
    rnoise = np.full(shape, case.read_noise, np.float32)
    gain = np.full(shape, case.gain, np.float32)
    slopes, _, _ = ramp_fit_data(ramp, False, rnoise, gain, "OLS_C", "optimal", "none")
    return slopes


@pytest.mark.parametrize("case", RAMP_CASES + MULTI_CASES, ids=_ids(RAMP_CASES + MULTI_CASES))
def test_stcal_gives_the_recorded_values(case):
    """The recorded values are what stcal 1.20 computes (a check of the transcription)."""
    pytest.importorskip("stcal")
    slopes = _stcal_ramp_fit(case)
    np.testing.assert_allclose(slopes["slope"][0], case.slope, rtol=TOL, atol=TOL)
    for p, want in enumerate(case.dq):
        if want is not None:
            assert slopes["dq"][0, p] == want, f"pixel {p}"
    if case.var_rnoise is not None:
        np.testing.assert_allclose(slopes["var_rnoise"][0], case.var_rnoise, rtol=TOL,
                                   atol=1e-9)


def _stcal_find_crs(case):
    """stcal's two-point difference search on ``case`` (its tests' parameters)."""
    from stcal.jump.twopoint_difference import find_crs
    from stcal.jump.twopoint_difference_class import TwoPointParams

    data, flags = case.cube()
    p = TwoPointParams()
    p.normal_rej_thresh = p.two_diff_rej_thresh = p.three_diff_rej_thresh = 3
    p.nframes, p.flag_4_neighbors = 1, False
    p.max_jump_to_flag_neighbors, p.min_jump_to_flag_neighbors = 200, 10
    p.fl_jump, p.fl_sat, p.fl_dnu = JUMP, SAT, DNU
    p.after_jump_flag_e1 = p.after_jump_flag_e2 = 0.0
    p.after_jump_flag_n1 = p.after_jump_flag_n2 = 0
    p.minimum_groups, p.minimum_sigclip_groups, p.only_use_ints = 3, 100, True
    p.min_diffs_single_pass, p.copy_arrs = 10, True
    p.dt_group, p.n_reads_groupdiff = np.ones(1), np.full(1, 2.0)
    read_noise = np.full(data.shape[1:], case.read_noise, np.float32)
    out = find_crs(data[None], flags[None], read_noise, p)[0]
    return (out[0, :, 0, :] & JUMP) != 0


@pytest.mark.parametrize("case", JUMP_CASES, ids=_ids(JUMP_CASES))
def test_stcal_flags_the_recorded_jumps(case):
    """The recorded jumps are where stcal 1.20's two-point search puts them."""
    pytest.importorskip("stcal")
    jumped = _stcal_find_crs(case)
    for p in range(jumped.shape[1]):
        got = set(np.flatnonzero(jumped[:, p]).tolist())
        assert got if case.any_jump else set(case.jumps[p]) <= got, f"pixel {p}: {sorted(got)}"
        assert not got & set(case.clean[p]), f"pixel {p}: {sorted(got)}"
