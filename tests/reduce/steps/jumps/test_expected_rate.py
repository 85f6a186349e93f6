"""detect_jumps' slope_prior: the step search against the bulk's slope, checked against
brute-force generalised least squares and a numpy matched filter with the slope known."""

import warnings

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, detect_jumps, dq
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.io.sources import MemorySource
from spherex_reduce.reduce.executor import execute
from spherex_reduce.reduce.options import RunOptions
from spherex_reduce.reduce.steps.fit_ramp.step_model import StepModel
from spherex_reduce.reduce.steps.jumps.events import JumpWarning
from spherex_reduce.reduce.steps.jumps.search import StepSearch
from spherex_reduce.reduce.steps.jumps.step import DetectJumpsStep

NF, DT, RN = 74, 1.5, 10.0


def schedule(nrows, ncols, nframes=NF):
    return ReadoutSchedule(DetectorGeometry(nrows, ncols, 1, ref_border=0), skip=1,
                           ref_reads=0, ref_mode="none", phantom_reads=0, nframes=nframes,
                           frame_time=DT)


def white(shape, rng):
    """Jump-free dark ramps of white read noise on a pedestal, float64 ``(nf, n, m)``."""
    return 6e4 + rng.normal(0.0, RN, shape)


def known_slope_z(y):
    """max |z| over the reads of a step against a line of known slope 0 and free
    intercept, for white noise RN (columns of ``y``, ``(nf, m)``): the numpy least
    squares of [1, step at k] for every k."""
    n = y.shape[0]
    best = np.zeros(y.shape[1])
    for k in range(1, n):
        x = np.stack([np.ones(n), (np.arange(n) >= k).astype(float)], axis=1)
        coef = np.linalg.lstsq(x, y, rcond=None)[0]
        se = RN * np.sqrt(np.linalg.inv(x.T @ x)[1, 1])
        best = np.maximum(best, np.abs(coef[1]) / se)
    return best


def uniform(e, rate=0.0):
    """A map of one rate for every pixel of ``e`` (a number is refused: see below)."""
    return np.full(e.shape[1:], rate)


def flagged(out):
    return ((out.dq & dq.JUMP) != 0).any(axis=0)


def test_a_prior_step_model_is_the_gls_of_the_reads_and_one_observation_of_the_slope():
    rng = np.random.default_rng(3)
    times = np.sort(rng.uniform(0, 30, 9))
    factors = rng.uniform(0.5, 2.0, 9)  # unequal read-noise variances
    kappa = 7.0  # the prior observation's weight (read-noise variance / its variance)
    model = StepModel(times, factors, slope_precision=kappa)
    y = rng.normal(0, 1, (9, 5))
    _, big_r, _ = model.step_sums(y)
    tau = times - times[0]
    for k in range(1, 9):
        # the augmented system: the reads (weights 1 / f) and a row observing the slope
        # as 0 (weight kappa), the unknowns intercept, slope and the step at k
        x = np.zeros((10, 3))
        x[:9, 0], x[:9, 1], x[:9, 2] = 1.0, tau, (np.arange(9) >= k)
        x[9, 1] = 1.0
        w = np.r_[1.0 / factors, kappa]
        cov = np.linalg.inv(x.T @ (w[:, None] * x))
        coef = cov @ x.T @ (w[:, None] * np.vstack([y, np.zeros((1, 5))]))
        # the step's amplitude R_k / q_k and its variance 1 / q_k (read-noise units)
        np.testing.assert_allclose(big_r[k - 1] / model.q[k - 1], coef[2], rtol=1e-10)
        np.testing.assert_allclose(1.0 / model.q[k - 1], cov[2, 2], rtol=1e-10)


def test_with_shot_noise_weights_too_it_is_that_gls_with_the_ramps_covariance():
    """A bright ramp's search (``rho`` > 0: read noise plus the charge's random walk) with
    the prior: the generalised least squares with the full covariance of the reads and
    the prior's observation of the slope, brute force."""
    rng = np.random.default_rng(4)
    times = np.sort(rng.uniform(0, 30, 9))
    tau = times - times[0]
    walk = np.minimum.outer(tau, tau)
    rho, kappa = 0.3, 7.0
    model = StepSearch(times, None, walk, rho=0.0, slope_precision=kappa).with_shot(rho)
    rho = model.rho  # (binned by RHO_BIN dex)
    y = rng.normal(0, 1, (9, 5))
    _, big_r, _ = model.step_sums(y)
    cov_y = np.eye(9) + rho * walk  # in read-noise variance
    for k in range(1, 9):
        x = np.column_stack([np.ones(9), tau, np.arange(9) >= k]).astype(float)
        # the reads and the prior's row (slope observed as 0, variance 1 / kappa)
        xa = np.vstack([x, [0.0, 1.0, 0.0]])
        ca = np.zeros((10, 10))
        ca[:9, :9], ca[9, 9] = cov_y, 1.0 / kappa
        wa = np.linalg.inv(ca)
        cov = np.linalg.inv(xa.T @ wa @ xa)
        coef = cov @ xa.T @ wa @ np.vstack([y, np.zeros((1, 5))])
        np.testing.assert_allclose(big_r[k - 1] / model.q[k - 1], coef[2], rtol=1e-9)
        np.testing.assert_allclose(1.0 / model.q[k - 1], cov[2, 2], rtol=1e-9)


def test_the_prior_finds_mid_ramp_steps_as_a_known_slope_does():
    rng = np.random.default_rng(5)
    s = schedule(128, 512)
    cube = white((NF, 128, 512), rng)
    # 12 e steps at mid-ramp in one pixel of 64 (1.2 read noise: 2.6 sigma against a free
    # slope, 5.2 against a known one); a few per cent would move the bulk's slope
    hit = np.zeros((128, 512), bool)
    hit[::8, ::8] = True
    k = rng.integers(NF // 3, 2 * NF // 3, hit.sum())
    cube[:, hit] += 12.0 * (np.arange(NF)[:, None] >= k[None, :])
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    free = flagged(detect_jumps(e, read_noise=RN, read_events=False, telegraph=False))
    prior = flagged(detect_jumps(e, read_noise=RN, read_events=False, telegraph=False,
                                 expected_rate=uniform(e)))
    expect = known_slope_z(cube[:, hit] - 6e4) >= 4.0  # the slope known (0), numpy
    assert expect.mean() > 0.6 and free[hit].mean() < 0.2
    # the prior's weight is finite (its floor) and the bulk measured: a few ramps differ
    assert abs(prior[hit].mean() - expect.mean()) < 0.08  # 0.863 against 0.911
    assert np.mean(prior[hit] == expect) > 0.9


def test_clean_darks_flag_what_the_known_slope_test_flags():
    rng = np.random.default_rng(6)
    s = schedule(128, 512)
    cube = white((NF, 128, 512), rng)
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    out = detect_jumps(e, read_noise=RN, read_events=False, telegraph=False,
                       expected_rate=uniform(e), scale_read_noise=False)
    got = int(flagged(out).sum())
    expect = int((known_slope_z(cube.reshape(NF, -1) - 6e4) >= 4.0).sum())
    # the same false alarms as the numpy test (~0.2 % of 65536), to 4 Poisson sigmas
    assert expect > 50
    assert abs(got - expect) <= 4 * np.sqrt(expect)


def test_hot_pixels_keep_the_free_slope():
    rng = np.random.default_rng(7)
    s = schedule(64, 256)
    cube = white((NF, 64, 256), rng)
    sig_b = RN / np.sqrt(np.sum((np.arange(NF) * DT - (NF - 1) * DT / 2) ** 2))
    hot = np.zeros((64, 256), bool)
    hot[1::8, 3::8] = True  # 1.6 % of the pixels, 50 slope sigmas above the others
    cube[:, hot] += 50 * sig_b * (np.arange(NF) * DT)[:, None]
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    free = flagged(detect_jumps(e, read_noise=RN, read_events=False, telegraph=False))
    prior = flagged(detect_jumps(e, read_noise=RN, read_events=False, telegraph=False,
                                 expected_rate=uniform(e)))
    # against the bulk's slope every hot ramp would look like a step
    np.testing.assert_array_equal(prior[hot], free[hot])
    assert prior[hot].mean() < 0.02


def test_bands_and_threads_give_the_whole_exposures_flags_with_the_prior():
    rng = np.random.default_rng(8)
    s = schedule(32, 64)
    cube = white((NF, 32, 64), rng)
    cube[30:, 5, 3] += 20.0
    cube[40:, 17, 9] += 16.0
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    step = DetectJumpsStep()
    params = step.validate({"read_noise": RN, "expected_rate": uniform(e)})
    whole = step(e, read_noise=RN, expected_rate=uniform(e)).dq
    assert (whole[:, 5, 3] & dq.JUMP).any() and (whole[:, 17, 9] & dq.JUMP).any()
    for rows, threads in ((1, 1), (5, 2)):
        kernel = step.kernel(MemorySource(e).context, **params)
        out, _ = execute(MemorySource(e), [kernel], options=RunOptions(threads=threads),
                         rows_per_band=rows)
        np.testing.assert_array_equal(out.dq, whole)


@pytest.mark.parametrize("value", [0.01, np.array(0.01),
                                   0.01 * u.electron / u.s, np.array([0.01])])
def test_a_number_is_refused_as_the_bulks_slope(value):
    s = schedule(8, 8)
    e = Exposure.from_arrays(white((NF, 8, 8), np.random.default_rng(9)).astype(np.float32), s)
    with pytest.raises(ConfigError, match="expected_rate: a map of each pixel's rate"):
        detect_jumps(e, read_noise=RN, expected_rate=value)
    # when the pipeline is made (``show-config`` validates), not only when it runs
    from spherex_reduce import Pipeline
    with pytest.raises(ConfigError, match="expected_rate: a map of each pixel's rate"):
        Pipeline({"steps": [{"detect_jumps": {"read_noise": RN, "expected_rate": value}}]})


def test_needs_the_read_noise():
    s = schedule(8, 8)
    e = Exposure.from_arrays(white((NF, 8, 8), np.random.default_rng(9)).astype(np.float32), s)
    with pytest.raises(ConfigError, match="expected_rate needs read_noise"):
        detect_jumps(e, expected_rate=uniform(e))


def slope_sigma(rn=RN):
    """A line's slope sigma over the reads for white read noise ``rn``."""
    t = np.arange(NF) * DT
    return rn / np.sqrt(np.sum((t - t.mean()) ** 2))


def test_warm_pixels_in_the_map_are_searched_as_a_known_slope_would():
    rng = np.random.default_rng(11)
    s = schedule(128, 512)
    cube = white((NF, 128, 512), rng)
    rate = np.zeros((128, 512))
    warm = rng.random((128, 512)) < 0.05  # 2-4 slope sigmas warmer than the others
    rate[warm] = rng.uniform(2.0, 4.0, warm.sum()) * slope_sigma()
    t = np.arange(NF) * DT
    cube += rate[None] * t[:, None, None]
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    kw = dict(read_noise=RN, read_events=False, telegraph=False, scale_read_noise=False)
    mapped = flagged(detect_jumps(e, expected_rate=rate, **kw))
    bulk = flagged(detect_jumps(e, expected_rate=uniform(e), **kw))
    # numpy: a step against a line of each pixel's known rate (the map), free intercept
    expect = known_slope_z(cube.reshape(NF, -1) - 6e4 - np.outer(t, rate.ravel())) >= 4.0
    expect = expect.reshape(128, 512)
    assert 50 < expect.sum() < 400  # ~0.15 % of 65536
    assert abs(int(mapped.sum()) - int(expect.sum())) <= 4 * np.sqrt(expect.sum())
    assert mapped[warm].mean() < 0.01
    # the same warm pixels against one rate for all look like steps
    assert bulk[warm].mean() > 0.05


def test_a_read_noise_map_weighs_each_pixels_prior_with_its_own_noise():
    rng = np.random.default_rng(12)
    s = schedule(128, 512)
    rn = np.where(np.arange(512) < 256, RN, 2.0 * RN)[None, :] * np.ones((128, 1))
    cube = 6e4 + rng.normal(0.0, 1.0, (NF, 128, 512)) * rn
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    got = flagged(detect_jumps(e, read_noise=rn, expected_rate=uniform(e), read_events=False,
                               telegraph=False, scale_read_noise=False))
    for cols, noise in ((slice(0, 256), RN), (slice(256, 512), 2.0 * RN)):
        z = known_slope_z((cube[:, :, cols].reshape(NF, -1) - 6e4) * (RN / noise))
        expect = int((z >= 4.0).sum())
        assert expect > 25
        assert abs(int(got[:, cols].sum()) - expect) <= 4 * np.sqrt(expect)


def test_a_read_event_keeps_the_prior():
    rng = np.random.default_rng(13)
    s = schedule(128, 512)
    cube = white((NF, 128, 512), rng)
    cube[0] -= 18.0  # the first read off for every pixel (a reset effect: a read event)
    hit = np.zeros((128, 512), bool)
    hit[::8, ::8] = True
    k = rng.integers(NF // 3, 2 * NF // 3, hit.sum())
    cube[:, hit] += 12.0 * (np.arange(NF)[:, None] >= k[None, :])
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    with pytest.warns(JumpWarning, match="read 0 is off in most pixels"):
        out = detect_jumps(e, read_noise=RN, telegraph=False, expected_rate=uniform(e))
    assert (out.dq[0] & dq.DO_NOT_USE).all()  # the event found and left out
    expect = known_slope_z(cube[1:, hit] - 6e4) >= 4.0  # the slope known, read 0 left out
    got = ((out.dq[1:] & dq.JUMP) != 0).any(axis=0)
    assert expect.mean() > 0.6
    assert abs(got[hit].mean() - expect.mean()) < 0.08


def test_pixels_the_map_holds_no_value_for_keep_the_free_slope():
    rng = np.random.default_rng(14)
    s = schedule(64, 512)
    cube = white((NF, 64, 512), rng)
    t = np.arange(NF) * DT
    rate = np.zeros((64, 512))
    rate[::4] = 3.0 * slope_sigma()  # warm rows: steps against a rate of 0
    cube += rate[None] * t[:, None, None]
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    kw = dict(read_noise=RN, read_events=False, telegraph=False, scale_read_noise=False)
    given = np.zeros((64, 512))
    given[::4] = np.nan  # the map has no value for the warm rows
    free = flagged(detect_jumps(e, **kw))
    got = flagged(detect_jumps(e, expected_rate=given, **kw))
    np.testing.assert_array_equal(got[::4], free[::4])
    assert got[::4].mean() < 0.01
    # the header says how many ramps were searched against the map and how many free
    h = detect_jumps(e, expected_rate=given, **kw).header
    assert h["NEXPRATE"] + h["NEXPFREE"] == 64 * 512
    assert 16 * 512 <= h["NEXPFREE"] < 16 * 512 + 100  # the NaN rows, and a few off it
    assert flagged(detect_jumps(e, expected_rate=uniform(e), **kw))[::4].mean() > 0.02  # 0.039
    with pytest.raises(ConfigError, match="expected_rate: array holds no value"):
        detect_jumps(e, expected_rate=np.full((64, 512), np.nan), **kw)
    with pytest.raises(ConfigError, match="expected_rate: array holds values that are not "):
        detect_jumps(e, expected_rate=np.full((64, 512), np.inf), **kw)


def test_a_master_dark_file_from_combine_is_the_map(tmp_path):
    """The user's route: darks reduced and combined (ccdproc), the master written as a FITS
    file, its path given in a YAML pipeline; the flags those of the same values given as
    an array, warm pixels (in the master) not flagged, and the parameter in the header."""
    from spherex_reduce import Pipeline, combine_darks
    from spherex_reduce.io import write

    rng = np.random.default_rng(15)
    s = schedule(64, 256)
    t = np.arange(NF) * DT
    rate = np.zeros((64, 256))
    warm = rng.random((64, 256)) < 0.05
    rate[warm] = 3.0 * slope_sigma()

    def dark():
        cube = white((NF, 64, 256), rng) + rate[None] * t[:, None, None]
        return Exposure.from_arrays(cube.astype(np.float32), s)

    reduce = Pipeline({"steps": [{"detect_jumps": {"read_noise": RN}},
                                 {"fit_ramp": {"read_noise": RN}}]})
    master = combine_darks([reduce.run(dark()) for _ in range(4)])
    path = write(master, tmp_path / "master.fits")
    e = dark()
    kw = {"read_noise": RN, "read_events": False, "telegraph": False}
    config = tmp_path / "jumps.yaml"
    config.write_text(f"steps:\n  - detect_jumps: {{read_noise: {RN}, read_events: false, "
                      f"telegraph: false, expected_rate: '{path}'}}\n")
    pipe = Pipeline.from_yaml(str(config))
    out = pipe.run(e)
    from_array = detect_jumps(e, expected_rate=np.asarray(master.data.data), **kw)
    np.testing.assert_array_equal(out.dq, from_array.dq)
    assert flagged(out)[warm].mean() < 0.01
    assert flagged(detect_jumps(e, expected_rate=uniform(e), **kw))[warm].mean() > 0.02
    # the configuration recorded (HISTORY, wrapped at 72 characters) names the file
    assert f'"expected_rate": "{path}"' in "".join(out.header["HISTORY"])


def test_clean_ramps_flagged_are_those_a_known_slope_flags_and_fit_as_its_segments():
    """Every clean ramp the search flags (at 3.2 sigma: ~3 %) is one numpy's known-slope
    test flags, at the same read, and its slope is the numpy least squares of its two
    segments (a common slope): no ramp is flagged by a free-slope search instead (a clean
    ramp whose noise looked like a step down used to be, with its two-segment slope taken
    for a bright pixel's, and then fitted ~4 line sigmas off)."""
    from spherex_reduce import Pipeline

    rng = np.random.default_rng(16)
    s = schedule(64, 512)
    rate = 0.01
    t = np.arange(NF) * DT
    cube = white((NF, 64, 512), rng) + rate * t[:, None, None]
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    search = {"read_noise": RN, "threshold": 3.2, "expected_rate": uniform(e, rate),
              "read_events": False, "telegraph": False, "scale_read_noise": False}
    out = Pipeline({"steps": [{"detect_jumps": search},
                              {"fit_ramp": {"read_noise": RN}}]}).run(e)
    jumps = ((detect_jumps(e, **search).dq & dq.JUMP) != 0).reshape(NF, -1)
    y = cube.reshape(NF, -1) - 6e4 - rate * t[:, None]
    z = np.abs(np.stack([known_step(y, k) for k in range(1, NF)]))  # (NF - 1, pixels)
    expect = z.max(axis=0) >= 3.2
    got = jumps.any(axis=0)
    assert 500 < expect.sum() < 1500  # ~3 % of 32768
    assert np.mean(expect[got]) > 0.97  # 0.76 with the free search's flags
    # the prior is not the exact slope (its spread measured, at least a tenth of the
    # line's sigma): a few of the known slope's flags are missed (766 of 920 here)
    assert 0.75 * expect.sum() < got.sum() <= expect.sum()
    both = np.flatnonzero(got & expect)
    read = np.argmax(jumps[:, both], axis=0)
    assert np.mean(read == 1 + np.argmax(z[:, both], axis=0)) > 0.97
    # the fit: numpy's least squares of the segments between the flags (own intercepts,
    # one slope), to a few hundredths of a line's sigma (fit_ramp weighs the reads with the
    # ramp's shot noise); ramps cut where they were not flagged would be ~a sigma off
    ref = np.empty(got.sum())
    for i, p in enumerate(np.flatnonzero(got)):
        seg = np.searchsorted(np.flatnonzero(jumps[:, p]), np.arange(NF), side="right")
        x = np.column_stack([t] + [seg == k for k in range(seg[-1] + 1)]).astype(float)
        ref[i] = np.linalg.lstsq(x, y[:, p], rcond=None)[0][0]
    diff = (out.data.data.reshape(-1)[got] - rate - ref) / slope_sigma()
    assert np.sqrt(np.mean(diff ** 2)) < 0.05  # 0.034 (one short segment 0.6 off)


def known_step(y, k):
    """z of a step at read ``k`` against a line of known slope 0 and free intercept, white
    read noise RN (numpy means of the reads before and after)."""
    n = y.shape[0]
    amp = y[k:].mean(axis=0) - y[:k].mean(axis=0)
    return amp / (RN * np.sqrt(1.0 / k + 1.0 / (n - k)))


@pytest.mark.parametrize("case", ["huge map", "tiny read noise"])
def test_a_prior_that_cannot_be_weighed_leaves_the_slope_free_without_a_warning(case):
    rng = np.random.default_rng(17)
    s = schedule(64, 256)
    cube = white((NF, 64, 256), rng)
    rate = np.zeros((64, 256))
    rn = RN
    if case == "huge map":
        rate[:, ::2] = 1e160  # squares overflow: no spread can be measured
    else:
        rn = 1e-200  # its square underflows: no weight
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    kw = dict(read_noise=rn, read_events=False, telegraph=False, scale_read_noise=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = detect_jumps(e, expected_rate=rate, **kw)
    np.testing.assert_array_equal(out.dq, detect_jumps(e, **kw).dq)
    assert out.header["NEXPRATE"] == 0 and out.header["NEXPFREE"] == 64 * 256


def test_pixels_bright_for_shot_weights_keep_the_free_slope_where_the_map_is_off():
    """Hot pixels (1-100 e/s: shot-noise weights) under a map 20 % off, as after a change
    of temperature, are searched as with the slope free (searched against a prior there,
    13-44 % of them were flagged), and the darker pixels keep the prior."""
    rng = np.random.default_rng(18)
    s = schedule(64, 512)
    rate = np.full((64, 512), 0.01)
    hot = rng.random((64, 512)) < 0.05
    rate[hot] = 10 ** rng.uniform(0.0, 2.0, hot.sum())
    charge = rng.poisson(rate[None] * DT, (NF, 64, 512)).cumsum(axis=0)  # shot noise
    e = Exposure.from_arrays((white((NF, 64, 512), rng) + charge).astype(np.float32), s)
    kw = dict(read_noise=RN, gain=1.0, read_events=False, telegraph=False,
              scale_read_noise=False)
    free = flagged(detect_jumps(e, **kw))
    out = detect_jumps(e, expected_rate=rate / 1.2, **kw)
    np.testing.assert_array_equal(flagged(out)[hot], free[hot])
    assert hot.sum() <= out.header["NEXPFREE"] < hot.sum() + 100
    assert out.header["NEXPRATE"] + out.header["NEXPFREE"] == 64 * 512


def test_a_sky_under_a_darks_map_is_searched_with_the_slope_free():
    """Rates that spread like a sky's (log-normal, median 0.2 e/s: below the shot-noise
    weights of most ramps) about a dark's map: no prior would help, and its centre (the
    set's median) would bias: the flags are the free search's."""
    rng = np.random.default_rng(20)
    s = schedule(64, 512)
    rate = np.exp(np.log(0.2) + 0.7 * rng.standard_normal((64, 512)))
    charge = rng.poisson(rate[None] * DT, (NF, 64, 512)).cumsum(axis=0)
    e = Exposure.from_arrays((white((NF, 64, 512), rng) + charge).astype(np.float32), s)
    kw = dict(read_noise=RN, gain=1.0, read_events=False, telegraph=False,
              scale_read_noise=False)
    out = detect_jumps(e, expected_rate=np.full((64, 512), 0.01), **kw)
    np.testing.assert_array_equal(out.dq, detect_jumps(e, **kw).dq)
    assert out.header["NEXPRATE"] == 0


def test_a_ramp_with_an_unflagged_nan_read_is_counted_once():
    rng = np.random.default_rng(19)
    s = schedule(32, 512)
    cube = white((NF, 32, 512), rng)
    cube[rng.integers(NF, size=200), rng.integers(32, size=200),
         rng.integers(512, size=200)] = np.nan  # one read not finite, no DQ flag
    e = Exposure.from_arrays(cube.astype(np.float32), s)
    h = detect_jumps(e, read_noise=RN, expected_rate=uniform(e), read_events=False,
                     telegraph=False).header
    assert h["NEXPRATE"] + h["NEXPFREE"] == 32 * 512
