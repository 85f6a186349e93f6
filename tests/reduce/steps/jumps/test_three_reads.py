"""Three reads: one test of the ramp's bend, the step placed where it is positive."""

import numpy as np
import pytest
from scipy.stats import norm

from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule, detect_jumps, dq
from spherex_reduce.reduce.steps.jumps.events import JumpWarning

RN, DT = 10.0, 1.5


def schedule(nrows, ncols, frames_per_group=1, group_gap=0):
    return ReadoutSchedule(DetectorGeometry(nrows, ncols, max(1, ncols // 64), ref_border=0),
                           skip=1, ref_reads=0, ref_mode="none", phantom_reads=0, nframes=3,
                           frame_time=DT, frames_per_group=frames_per_group,
                           group_gap=group_gap)


def white(rng, nrows, ncols, frames_per_group=1):
    """Three reads of white read noise (each the mean of ``frames_per_group`` frames) on a
    pedestal, no charge."""
    noise = rng.standard_normal((3, nrows, ncols)) * RN / np.sqrt(frames_per_group)
    return (6e4 + noise).astype(np.float32)


@pytest.mark.parametrize("frames_per_group, group_gap", [(1, 0), (4, 1)])
@pytest.mark.parametrize("threshold", [2.5, 3.0])
def test_false_alarms_are_one_two_sided_test(frames_per_group, group_gap, threshold):
    """Jump-free ramps of white read noise (given, no shot term) are flagged with the
    probability of one two-sided normal test, 2 Phi(-threshold): the two steps of three
    reads are one test, not two (within 5 Poisson sigmas of 2^17 ramps)."""
    rng = np.random.default_rng(int(threshold * 10) + frames_per_group)
    s = schedule(256, 512, frames_per_group, group_gap)
    e = Exposure.from_arrays(white(rng, 256, 512, frames_per_group), s)
    out = detect_jumps(e, read_noise=RN, gain=1e9, threshold=threshold,
                       scale_read_noise=False)
    n = 256 * 512
    flagged = int(((out.dq & dq.JUMP) != 0).any(axis=0).sum())
    expected = 2 * norm.sf(threshold) * n
    assert abs(flagged - expected) <= 5 * np.sqrt(expected)


def test_a_positive_step_is_placed_at_its_read_and_the_slope_is_the_other_difference():
    """150 e steps (6.1 sigmas of the bend) after read 1 or read 2: found at their read, never
    at the other; the slope of a found one is the difference of the two reads on the other
    side (numpy), its error that difference's read noise, sqrt(2) RN / DT; clean ramps keep
    the line through three reads, error RN / sqrt(sum (t - mean t)**2)."""
    rng = np.random.default_rng(3)
    cube = white(rng, 128, 512)
    flat = cube.reshape(3, -1)
    pix = rng.choice(flat.shape[1], 1200, replace=False)
    first, second = pix[:600], pix[600:]
    flat[1:, first] += np.float32(150)
    flat[2:, second] += np.float32(150)
    e = Exposure.from_arrays(cube, schedule(128, 512))
    steps = [{"detect_jumps": {"read_noise": RN, "gain": 1e9}},
             {"fit_ramp": {"read_noise": RN, "gain": 1e9}}]
    flags = (detect_jumps(e, read_noise=RN, gain=1e9).dq & dq.JUMP).reshape(3, -1) != 0
    assert flags[1, first].mean() > 0.95 and not flags[2, first].any()
    assert flags[2, second].mean() > 0.95 and not flags[1, second].any()
    out = Pipeline({"steps": steps}).run(e)
    slope, err = out.data.data.ravel(), out.data.uncertainty.array.ravel()
    d = np.diff(flat.astype(np.float64), axis=0) / DT
    for px, other, read in ((first, d[1], 1), (second, d[0], 2)):
        found = px[flags[read, px]]
        np.testing.assert_allclose(slope[found], other[found], rtol=0, atol=1e-4)
        np.testing.assert_allclose(err[found], np.sqrt(2) * RN / DT, rtol=1e-6)
    clean = np.setdiff1d(np.arange(flat.shape[1]), pix)
    clean = clean[~flags[:, clean].any(axis=0)]
    np.testing.assert_allclose(slope[clean], (flat[2, clean] - flat[0, clean]) / (2 * DT),
                               rtol=0, atol=1e-4)
    np.testing.assert_allclose(err[clean], RN / np.sqrt(2 * DT ** 2), rtol=1e-6)


def test_three_groups_flag_the_reads_stcal_flags():
    """stcal 1.20's two-point detection on the same three groups (its read noise that of a
    difference, gain 1): every pixel with a step of 200 e or 1000 e is flagged by both at
    the same group, and by neither at the other; on the jump-free pixels we flag no more
    often than stcal does."""
    stcal_jump = pytest.importorskip("stcal.jump.jump")
    from stcal.jump.jump_class import JumpData

    rng = np.random.default_rng(7)
    cube = white(rng, 64, 256)
    flat = cube.reshape(3, -1)
    pix = rng.choice(flat.shape[1], 400, replace=False)
    at = rng.integers(1, 3, pix.size)
    amp = rng.choice([200.0, 1000.0], pix.size)
    for k in (1, 2):
        flat[k:, pix[at == k]] += amp[at == k].astype(np.float32)
    ours = (detect_jumps(Exposure.from_arrays(cube, schedule(64, 256)),
                         read_noise=RN).dq & dq.JUMP).reshape(3, -1) != 0
    names = {"GOOD": 0, "DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4, "NO_GAIN_VALUE": 8,
             "UNRELIABLE_SLOPE": 16, "PERSISTENCE": 32, "CHARGELOSS": 64,
             "REFERENCE_PIXEL": 128}
    jd = JumpData(gain2d=np.ones((64, 256), np.float32),
                  rnoise2d=np.full((64, 256), RN * np.sqrt(2), np.float32), dqflags=names)
    jd.init_arrays_from_arrays(cube[None].copy(), np.zeros((1, 3, 64, 256), np.uint8),
                               np.zeros((64, 256), np.uint32))
    jd.nframes, jd.dt_group, jd.n_reads_groupdiff = 1, np.ones(1) * DT, np.ones(1) * 2
    jd.max_cores = "none"
    theirs = (stcal_jump.detect_jumps_data(jd)[0][0] & names["JUMP_DET"]).reshape(3, -1) != 0
    np.testing.assert_array_equal(ours[at, pix], True)
    np.testing.assert_array_equal(theirs[at, pix], True)
    np.testing.assert_array_equal(ours[3 - at, pix], False)
    clean = np.setdiff1d(np.arange(flat.shape[1]), pix)
    assert ours[:, clean].any(axis=0).sum() <= theirs[:, clean].any(axis=0).sum()


def test_without_read_noise_three_reads_say_to_give_it():
    s = schedule(8, 8)
    e = Exposure.from_arrays(white(np.random.default_rng(1), 8, 8), s)
    with pytest.warns(JumpWarning, match=r"3 reads: too few to estimate .*give "
                                         r"detect_jumps\.read_noise"):
        out = detect_jumps(e)
    assert out.header["S_JUMP"] == "SKIPPED"


def test_bright_ramps_false_alarm_at_one_tests_rate():
    """Jump-free ramps of 100 e/s (gain 1: Poisson charge, 10 e reads) are flagged at 2
    Phi(-3) within 5 Poisson sigmas (2^18 ramps): their shot noise is the line's rate.  The
    slope less the positive step (the smaller difference) less one of its sigmas (9.4 e/s on
    3 reads), the rule of longer ramps, understated it: 1.5-3.5x the rate."""
    rng = np.random.default_rng(17)
    charge = np.cumsum(rng.poisson(100.0 * DT, (3, 512, 512)), axis=0).astype(np.float64)
    cube = (6e4 + charge - charge[0] + rng.standard_normal((3, 512, 512)) * RN)
    out = detect_jumps(Exposure.from_arrays(cube.astype(np.float32), schedule(512, 512)),
                       read_noise=RN, gain=1.0, threshold=3.0, scale_read_noise=False,
                       read_events=False)
    flagged = int(((out.dq & dq.JUMP) != 0).any(axis=0).sum())
    expected = 2 * norm.sf(3.0) * 512 * 512
    assert abs(flagged - expected) <= 5 * np.sqrt(expected)


def test_a_read_off_for_every_pixel_is_a_bend_said_once_not_thousands_of_jumps():
    """The first read 60 e low in every pixel bends every 3-read ramp alike (so would the
    middle read high or the last low: 3 reads cannot name the read).  It is said in one
    line and recorded (RDEVT), no read is left out and no clean ramp flagged: each is
    fitted as its line (numpy), while the cosmic rays are still flagged at their read,
    the bend's read too (searched again about the set's median bend)."""
    rng = np.random.default_rng(21)
    cube = white(rng, 64, 64)
    flat = cube.reshape(3, -1)
    flat[0] -= np.float32(60)
    pix = rng.choice(flat.shape[1], 60, replace=False)
    cr, cr1 = pix[:30], pix[30:]
    flat[2:, cr] += np.float32(300)
    flat[1:, cr1] += np.float32(3000)  # at read 1, where the array bends
    e = Exposure.from_arrays(cube, schedule(64, 64))
    with pytest.warns(JumpWarning, match=r"3 reads: the ramps of most pixels bend alike "
                                         r".*drop_first_reads: 1") as w:
        out = detect_jumps(e, read_noise=RN, gain=1e9)
    assert all("\n" not in str(x.message) for x in w)
    assert "bend" in out.header["RDEVT1"]
    flags = ((out.dq & dq.JUMP) != 0).reshape(3, -1)
    assert flags[2, cr].all() and flags[1, cr1].all() and out.header["NJUMPS"] == 60
    assert not (out.dq & dq.DO_NOT_USE).any()
    steps = [{"detect_jumps": {"read_noise": RN, "gain": 1e9}},
             {"fit_ramp": {"read_noise": RN, "gain": 1e9}}]
    with pytest.warns(JumpWarning):
        slope = Pipeline({"steps": steps}).run(e).data.data.ravel()
    clean = np.setdiff1d(np.arange(flat.shape[1]), pix)
    y = flat.astype(np.float64)
    np.testing.assert_allclose(slope[clean], (y[2, clean] - y[0, clean]) / (2 * DT), atol=1e-4)


@pytest.mark.parametrize("nframes", [4, 5])
def test_short_dark_ramps_false_alarm_as_without_shot_noise(nframes):
    """On 4-5 reads of a 0.01 e/s dark (gain 1: Poisson charge) the shot term takes the
    line's rate: the jump-free ramps flagged at 4 sigma are 0.85-1.2 of those flagged with
    no shot term (gain 1e9), whose rate is the docs' (2^20 ramps; 0.90-0.97 over 7 seeds in
    a review).  The slope less the best step, lowest where the step statistic is largest,
    made them 0.76-0.77."""
    rng = np.random.default_rng(nframes)
    charge = np.cumsum(rng.poisson(0.01 * DT, (nframes, 1024, 1024)), axis=0)
    cube = (6e4 + charge + rng.standard_normal((nframes, 1024, 1024), np.float32) * RN)
    s = ReadoutSchedule(DetectorGeometry(1024, 1024, 16, ref_border=0), skip=1, ref_reads=0,
                        ref_mode="none", phantom_reads=0, nframes=nframes, frame_time=DT)
    counts = []
    for gain in (1.0, 1e9):
        out = detect_jumps(Exposure.from_arrays(cube.astype(np.float32), s), read_noise=RN,
                           gain=gain, scale_read_noise=False, read_events=False)
        counts.append(int(((out.dq & dq.JUMP) != 0).any(axis=0).sum()))
    assert 0.85 <= counts[0] / counts[1] <= 1.2
