"""Telegraph pixels too faint to be found jump by jump, fitted as a population
(`spherex_reduce.analysis.faint_telegraph` through `fit_pixel_terms`, issue 33).

The ramps are drawn here with numpy: white reads, a drift common to the pixels of each row
and column parity (what the common-drift removal must take out), and a two-state
telegraph of steps near the jumps' threshold in a known fraction of the pixels.
"""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import DetectorGeometry
from spherex_reduce.analysis.pixel_terms import fit_pixel_terms

SIGMA, DT, NREADS, SIZE, NDARKS = 4.0, 1.5, 30, 64, 8  # 4 darks: the step's error 1.4x low
FRACTION, STEP, RATE = 0.1, 30.0, 0.3  # steps of ~5 sd of a difference: most never found


def _darks(seed, hot=(), drift=3.0, nreads=NREADS, rate=RATE):
    """``NDARKS`` darks of one detector (its telegraph pixels fixed by ``seed``) and which
    pixels are telegraph; ``hot``: pixels given a 5 e/s current; ``drift``: the common
    drift's step per read (e); ``rate``: the telegraph's per state (Hz)."""
    rng = np.random.default_rng(seed)
    tel = rng.random((SIZE, SIZE)) < FRACTION
    p = -np.expm1(-2 * rate * DT) / 2  # flip chance per interval, rate per state
    t = np.arange(nreads) * DT
    darks = []
    for _ in range(NDARKS):
        x = rng.normal(0.0, SIGMA, (nreads, SIZE, SIZE))
        # a random-walk drift common to each row's even and odd columns
        x += np.cumsum(rng.normal(0.0, drift, (nreads, SIZE, 1, 2)), axis=0).repeat(
            SIZE // 2, axis=2).reshape(nreads, SIZE, SIZE)
        state = rng.random((SIZE, SIZE)) < 0.5
        for k in range(nreads):
            if k:
                state ^= rng.random((SIZE, SIZE)) < p
            x[k] += STEP * (state & tel)
        for i, j in hot:
            x[:, i, j] += 5.0 * t
        darks.append(x * u.electron)
    return darks, tel, t * u.s


def test_faint_telegraph_pulls_over_twenty_detectors_are_standard_normal():
    """Power (fraction x mean squared step), rate, fraction and step within their stated
    errors of the injected population over 20 detectors (the pixels' own sampling is in
    the jackknife, so the truth is the population's, not the draw's)."""
    truth = {"power": FRACTION * STEP ** 2, "rate": RATE, "fraction": FRACTION,
             "amplitude": STEP}
    pulls = {k: [] for k in truth}
    for seed in range(20):
        darks, _, t = _darks(seed)
        res = fit_pixel_terms(darks, t)
        for key, value in truth.items():
            row = res.row(f"faint_telegraph_{key}", "active")
            assert row["status"] == "fitted", (key, row["note"])
            pulls[key].append((row["value"] - value) / row["error"])
    for key, z in pulls.items():
        z = np.asarray(z)
        # 20 pulls of N(0, 1): mean within 3/sqrt(20), sd within [0.6, 1.5]
        assert abs(z.mean()) < 3 / np.sqrt(z.size), (key, z)
        assert 0.6 < z.std(ddof=1) < 1.5, (key, z)


def test_white_reads_with_a_common_drift_have_no_faint_telegraph():
    """Without telegraph pixels the drift common to the pixels read together is not
    taken for one: the power is ruled out and the white read noise is the reads'."""
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, SIGMA, (NDARKS, NREADS, SIZE, SIZE))
    x += np.cumsum(rng.normal(0.0, 3.0, (NDARKS, NREADS, SIZE, 1)), axis=1)
    res = fit_pixel_terms([d * u.electron for d in x], np.arange(NREADS) * DT * u.s)
    assert res.row("faint_telegraph_power", "active")["status"] == "ruled out"
    white = res.row("white_read_noise", "active")
    assert abs(white["value"] - SIGMA) < 4 * white["error"] + 0.01 * SIGMA


def test_telegraph_pixels_are_not_taken_for_hot_ones():
    """A telegraph pixel's slope crosses the hot threshold in one dark and not the next: it
    is not hot; pixels of a steady 5 e/s current are (36 % of these telegraph pixels were
    hot before)."""
    hot = [(3, 5), (40, 17), (60, 60)]
    darks, tel, t = _darks(11, hot=hot, drift=0.0, nreads=74)
    res = fit_pixel_terms(darks, t)
    expect = np.zeros((SIZE, SIZE), bool)
    expect[tuple(np.array(hot).T)] = True
    assert tel.sum() > 300
    np.testing.assert_array_equal(res.maps["hot"], expect)


def test_common_labels_are_rows_of_a_channel_and_a_column_parity():
    from spherex_reduce.analysis.faint_telegraph import common_labels

    g = DetectorGeometry(8, 16, 2, ref_border=2)
    lab = common_labels(g)
    ref = g.reference_pixel_mask()
    assert (lab[ref] == -1).all()
    rows, cols = np.nonzero(~ref)
    expect = rows * 4 + (cols // 8) * 2 + cols % 2  # 2 channels of 8 columns
    np.testing.assert_array_equal(lab[rows, cols], expect)


@pytest.mark.parametrize("layout", [{"channels": "quadrants"}, {"channels": "rows"},
                                    {"channels": "quadrants", "fast_axis": "columns"}])
def test_common_labels_of_a_readout_frame_are_in_the_frame(layout):
    """A reader's schedule holds the readout frame (quadrants side by side, or rows turned
    to columns): its labels are in the frame, one row of one channel and one parity each
    there (they were mapped to the stored image: a quadrant frame raised a ValueError out
    of characterize, a rows frame grouped pixels read at other times), and the stored
    image's labels are the same pixels' groups."""
    from spherex_reduce.analysis.faint_telegraph import common_labels

    g = DetectorGeometry(64, 64, 4, ref_border=4, **layout)
    f = g.frame
    assert f is not g
    lab = common_labels(f)
    ref = f.reference_pixel_mask()
    assert lab.shape == (f.nrows, f.ncols) and (lab[ref] == -1).all()
    rows, cols = np.nonzero(~ref)
    chan = f.channel_of_column()[cols]
    expect = rows * (2 * f.nchannels) + chan * 2 + cols % 2
    np.testing.assert_array_equal(lab[rows, cols], expect)
    stored = np.asarray(g.layout.to_stored(lab))
    np.testing.assert_array_equal(stored, common_labels(g))


def test_lag_design_traces_against_numpy():
    """The white and shot traces of the structure function's forms, against a brute
    force: the mean of the forms over many numpy ramps."""
    from spherex_reduce.analysis.faint_telegraph import lag_design

    t = np.arange(12) * 1.5
    d = lag_design(t)
    rng = np.random.default_rng(0)
    n = 200000
    for cov, trace in ((np.eye(t.size), d["a"]),
                       (np.minimum.outer(t - t[0], t - t[0]), d["s"])):
        x = rng.multivariate_normal(np.zeros(t.size), cov + 1e-12 * np.eye(t.size), n)
        resid = x - x[:, :1] - np.outer(x[:, -1] - x[:, 0], (t - t[0]) / (t[-1] - t[0]))
        for lag, expect in zip(d["lags"], trace, strict=True):
            q = np.sum((resid[:, lag:] - resid[:, :-lag]) ** 2, axis=1)
            assert abs(q.mean() - expect) < 4 * q.std() / np.sqrt(n), (lag, q.mean(), expect)


def test_a_mean_slope_without_shot_noise_is_not_a_negative_population_ruled_out():
    """A telegraph population (10 %, 30 e, 0.3 Hz) on a noiseless ramp of 5 e/s in every
    pixel: the fit takes the mean slope for Poisson charge and takes its shot noise (5 e^2/s
    of a random walk) out of the structure function, more than is there.  The population
    is then not constrained, saying why, never "ruled out" nor fitted with a negative
    power (before: -23785 e^2 "ruled out" on such darks of characterize's tests)."""
    darks, _, t = _darks(3, drift=0.0)
    ramp = 5.0 * t.to_value(u.s)[:, None, None] * u.electron
    res = fit_pixel_terms([d + ramp for d in darks], t)
    for key in ("power", "rate", "fraction", "amplitude"):
        row = res.row(f"faint_telegraph_{key}", "active")
        assert row["status"] == "not constrained", (key, row)
        assert "below 0" in row["note"] and "Poisson" in row["note"]
    # the same darks without the ramp: the population is fitted
    clean = fit_pixel_terms(darks, t).row("faint_telegraph_power", "active")
    assert clean["status"] == "fitted"
    assert abs(clean["value"] - FRACTION * STEP ** 2) < 3 * clean["error"]


def test_a_population_slower_than_the_ramps_shows_only_its_power_times_its_rate():
    """Steps switching at 0.003 Hz (a flip in 1 of 7 pixel-darks of 45 s): the structure
    function grows linearly with the lag, so only ``P r`` (0.27 e^2/s) is seen; the power
    is not constrained and the note gives ``P r`` within 3 of its errors (before: a power
    "fitted" as ``P r`` over the end of the rate's search range)."""
    import re

    darks, _, t = _darks(3, drift=0.0, rate=0.003)
    row = fit_pixel_terms(darks, t).row("faint_telegraph_power", "active")
    assert row["status"] == "not constrained", row
    value, error = map(float, re.search(r"P r = (\S+) \+- (\S+) electron2 / s",
                                        row["note"]).groups())
    assert abs(value - FRACTION * STEP ** 2 * 0.003) < 3 * error, row["note"]


def test_lag_sums_against_the_structure_functions_written_out(monkeypatch):
    """`lag_sums`, taken a few pixels at a time (``LAG_PIXELS`` 7: chunks and a remainder),
    against its definition in float64: each group's mean at every read (members: not
    jumped) taken out, ``Q_L`` = the sum over k of the squared steps of the cumulative
    residual ``L`` reads apart, less the mean's own share, over (n - 2) / n; a group too
    small keeps its ``Q_L``; reference pixels 0."""
    from spherex_reduce.analysis import faint_telegraph as ft

    rng = np.random.default_rng(5)
    m, rows, nx = 11, 3, 12
    e = rng.normal(0.0, 1.0, (m, rows, nx)).astype(np.float32)
    labels = np.repeat(np.arange(rows * 2)[:, None], nx // 2, axis=1).reshape(rows, nx)
    labels[0, :3] = -1  # reference pixels
    labels[2, 8:] = 99  # a group of 4, one of them jumped: 3 members, too few
    jumped = np.zeros((rows, nx), bool)
    jumped[1, 4] = jumped[2, 9] = True
    lags = np.array([1, 2, 5])
    monkeypatch.setattr(ft, "LAG_PIXELS", 7)
    got = ft.lag_sums(e, labels, jumped, lags)

    want = np.zeros((lags.size, rows, nx))
    x64 = e.astype(np.float64)
    for lab in np.unique(labels[labels >= 0]):
        where = labels == lab
        member = where & ~jumped
        n = member.sum()
        small = n < ft.MIN_GROUP
        mean = 0.0 if small else x64[:, member].mean(axis=1)[:, None]
        res = x64[:, where] - mean
        cum = np.concatenate([np.zeros((1, res.shape[1])), np.cumsum(res, axis=0)])
        for i, lag in enumerate(lags):
            q = np.sum((cum[lag:] - cum[:-lag]) ** 2, axis=0)
            if not small:
                own = q[member[where]].sum() / (n * (n - 1.0))
                factor = np.where(member[where], (n - 2) / n, 1.0)
                q = (q - own) / factor
            want[i][where] = q
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-5)
    assert np.all(got[:, 0, :3] == 0)
    for bad in ([0, 2], [1, m + 1]):  # no lag outside the differences
        with pytest.raises(ValueError, match="lags must be 1 to 11"):
            ft.lag_sums(e, labels, jumped, np.array(bad))
