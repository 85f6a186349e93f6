"""Per-pixel terms learnt from darks (`spherex_reduce.analysis.pixel_terms`, issue 33).

Round trip on our simulator (known dark current, hot pixels, telegraph pixels among the
active and the reference pixels), the read-noise map against numpy on a cube with a known
sigma per pixel, the first read's offset, and what too few reads cannot constrain.
"""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import simulate
from spherex_reduce.analysis.pixel_terms import dark_ramps, fit_pixel_terms
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.simulation import load_scene

SIGMA = 5.0  # e: white noise of alpha 5e-4 e^2/Hz at 100 kHz, sqrt(alpha fs / 2)
DARK, HOT_FRACTION, HOT_CURRENT = 0.5, 0.02, 20.0
RTN = {"fraction": 0.03, "amplitude": 80.0, "rate": 0.05, "pixels": "all"}


def _scene(nframes=40):
    return {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2, "ref_border": 4},
            "readout": {"skip": 4, "ref_reads": 8, "phantom_reads": 0, "nframes": nframes,
                        "frame_time": 1.5},
            "noise": {"components": [{"name": "white", "alpha": 2 * SIGMA ** 2 / 1e5}]},
            "output": {"mode": "ramps"},
            "scene": {"dark_current": DARK, "hot_pixel_fraction": HOT_FRACTION,
                      "hot_pixel_current": HOT_CURRENT, "rtn": dict(RTN)}}


TRUTH = [("read_noise", "active", SIGMA), ("read_noise", "reference", SIGMA),
         ("dark_current", "active", DARK), ("hot_pixel_fraction", "active", HOT_FRACTION),
         ("hot_pixel_current", "active", HOT_CURRENT)]
for _pixels in ("active", "reference"):
    TRUTH += [("telegraph_fraction", _pixels, RTN["fraction"]),
              ("telegraph_amplitude", _pixels, RTN["amplitude"]),
              ("telegraph_rate", _pixels, RTN["rate"])]


def test_round_trip_on_the_simulator_gives_pulls_like_a_unit_normal():
    """Ten seeds of a 64 x 64 x 40 dark: every term within 4.5 of its error, and the 130
    pulls' mean and rms those of N(0, 1) (rms in [0.75, 1.3]: errors half or twice the
    truth give 2 or 0.5); the spreads of a population without one are ruled out or small."""
    pulls = []
    for seed in range(10):
        ramps, times, ref = dark_ramps(simulate(_scene(), seed=seed))
        res = fit_pixel_terms(ramps, times, reference=ref)
        for term, pixels, truth in TRUTH:
            row = res.row(term, pixels)
            assert row["status"] == "fitted", (seed, term, pixels, row)
            pull = (row["value"] - truth) / row["error"]
            assert abs(pull) < 4.5, (seed, term, pixels, row, truth)
            pulls.append(pull)
        for term in ("dark_current_spread", "hot_pixel_current_spread"):
            row = res.row(term, "active")
            assert row["status"] == "ruled out" or row["value"] < 4 * row["error"], row
        assert res.row("first_read_offset")["status"] == "ruled out" or abs(
            res.row("first_read_offset")["value"]) < 4 * res.row("first_read_offset")["error"]
    pulls = np.array(pulls)
    assert abs(pulls.mean()) < 0.35, pulls.round(2)
    assert 0.75 < np.sqrt(np.mean(pulls ** 2)) < 1.3, pulls.round(2)


def test_scene_mapping_is_a_scene_the_simulator_takes():
    """`PixelTerms.to_scene` gives the scene terms (one telegraph population, ``pixels:
    all``, as simulated) and `load_scene` validates them."""
    ramps, times, ref = dark_ramps(simulate(_scene(), seed=3))
    scene = fit_pixel_terms(ramps, times, reference=ref).to_scene()
    assert set(scene) == {"dark_current", "hot_pixel_fraction", "hot_pixel_current", "rtn"}
    assert scene["rtn"]["pixels"] == "all"
    assert scene["rtn"]["amplitude"] == pytest.approx(RTN["amplitude"], rel=0.05)
    terms = load_scene({"scene": scene}).terms
    assert terms.rtn.on and terms.dark_current == pytest.approx(DARK, rel=0.05)


def test_telegraph_in_the_active_pixels_only_maps_to_pixels_active():
    """``rtn: pixels: active``: no reference telegraph is found (ruled out), and the scene's
    population is the active one."""
    sc = _scene()
    sc["scene"]["rtn"]["pixels"] = "active"
    ramps, times, ref = dark_ramps(simulate(sc, seed=4))
    res = fit_pixel_terms(ramps, times, reference=ref)
    assert res.row("telegraph_fraction", "reference")["status"] == "ruled out"
    assert res.to_scene()["rtn"]["pixels"] == "active"


def test_pixels_with_a_nan_read_are_left_out_and_the_input_is_unchanged():
    """A NaN read (a flagged pixel) makes that pixel's maps NaN and leaves the terms of the
    others as they were; the darks given are not modified."""
    rng = np.random.default_rng(3)
    t = np.arange(20) * 1.5 * u.s
    x = (rng.normal(0, 5.0, (20, 32, 32)) + 2.0 * t.value[:, None, None]).astype(np.float32)
    clean = fit_pixel_terms(x * u.electron, t)
    flagged = x.copy()
    flagged[7, 3, 4] = np.nan
    before = flagged.copy()
    res = fit_pixel_terms(u.Quantity(flagged, u.electron, copy=False), t)
    np.testing.assert_array_equal(flagged, before)
    assert res.table.meta["unusable_pixels"] == 1
    assert np.isnan(res.maps["read_noise"][3, 4]) and not res.maps["hot"][3, 4]
    keep = np.ones((32, 32), bool)
    keep[3, 4] = False
    expected = clean.maps["dark_current"].value[keep].mean()
    assert res.row("dark_current", "active")["value"] == pytest.approx(expected, rel=1e-5)


def test_several_darks_of_the_same_pixels_are_pooled():
    """A 60-frame dark cut into two 30-frame darks (the same pixels): fitted together, the
    terms agree with the truth as one dark's do (the telegraph detection is corrected
    with the intervals of both)."""
    ramps, times, ref = dark_ramps(simulate(_scene(60), seed=11))
    res = fit_pixel_terms([ramps[:30], ramps[30:]], times[:30], reference=ref)
    assert res.table.meta["ndarks"] == 2
    for term, pixels, truth in TRUTH:
        row = res.row(term, pixels)
        assert abs(row["value"] - truth) < 4.5 * row["error"], (term, pixels, row)


def _cube(sigma, current, nreads=40, dt=1.5, seed=0):
    """Reads ``(nreads, ny, nx)`` (e) of pixels with read noise ``sigma`` and Poisson dark
    current ``current`` (e/s), both ``(ny, nx)``."""
    rng = np.random.default_rng(seed)
    charge = np.cumsum(rng.poisson(current * dt, (nreads, *sigma.shape)), axis=0)
    return charge + rng.normal(0.0, 1.0, charge.shape) * sigma


def test_read_noise_map_against_numpy_with_a_known_sigma_per_pixel():
    """Read noise 3-8 e per pixel, no current: the map agrees with numpy's
    ``sqrt(var(diff) / 2)`` of each pixel, its square is unbiased and its errors are the
    scatter about the truth; with 40 e/s of Poisson current on top, the shot noise is removed
    (numpy's closed form ``(var(diff) - I dt) / 2``)."""
    rng = np.random.default_rng(5)
    sigma = rng.uniform(3.0, 8.0, (48, 48))
    t = np.arange(40) * 1.5
    x = _cube(sigma, np.zeros_like(sigma))
    res = fit_pixel_terms(x * u.electron, t * u.s)
    got = res.maps["read_noise"].to_value(u.electron)
    err = res.maps["read_noise_error"].to_value(u.electron)
    numpy_estimate = np.sqrt(np.var(np.diff(x[1:], axis=0), axis=0, ddof=1) / 2)
    assert np.median(np.abs(got - numpy_estimate)) < 0.1 * np.median(err)
    excess = got ** 2 - sigma ** 2  # the variance is unbiased, its root a little low
    assert abs(excess.mean()) < 3 * excess.std() / np.sqrt(excess.size)
    assert np.std(got - sigma) / np.sqrt(np.mean(err ** 2)) == pytest.approx(1.0, abs=0.1)
    sigma = sigma + 3.0  # 6-11 e: the variance of a difference is 72-242 e^2 + 60 of shot noise
    x = _cube(sigma, np.full_like(sigma, 40.0), seed=1)
    res = fit_pixel_terms(x * u.electron, t * u.s)
    closed = (np.var(np.diff(x[1:], axis=0), axis=0, ddof=1) - 40.0 * 1.5) / 2
    got = res.maps["read_noise"].to_value(u.electron) ** 2
    for variance in (got, closed):
        excess = variance - sigma ** 2
        assert abs(excess.mean()) < 3 * excess.std() / np.sqrt(excess.size)
    assert np.median(np.abs(got - closed)) < 0.1 * np.std(got - sigma ** 2)


def test_first_read_offset_found_in_adu_and_ruled_out_without_one():
    """Read 0 shifted by -18 adu (gain 1.5 e/adu): found, within 3 errors; the same cube
    without the shift: ruled out."""
    rng = np.random.default_rng(8)
    t = np.arange(30) * 1.5
    x = _cube(np.full((40, 40), 6.0), np.full((40, 40), 2.0), nreads=30) / 1.5
    shifted = x.copy()
    shifted[0] -= 18.0
    res = fit_pixel_terms(shifted * u.adu, t * u.s, gain=1.5 * u.electron / u.adu)
    row = res.row("first_read_offset")
    assert row["status"] == "fitted" and row["unit"] == "adu"
    assert abs(row["value"] + 18.0) < 3 * row["error"] < 1.0
    row = fit_pixel_terms(x * u.adu, t * u.s, gain=1.5).row("first_read_offset")
    assert row["status"] == "ruled out" and abs(row["value"]) < 3 * row["error"]
    del rng


def test_what_the_darks_cannot_constrain_is_refused_with_its_reason():
    """One dark of 3 reads: no first-read offset and no telegraph terms; no reference mask:
    no reference terms.  Every NaN comes with ``not constrained`` and a reason."""
    rng = np.random.default_rng(2)
    x = rng.normal(0, 5.0, (3, 16, 16)) * u.electron
    res = fit_pixel_terms(x, [0, 1.5, 3.0] * u.s)
    assert "read 0" in res.row("first_read_offset")["note"]
    assert "differences per dark" in res.row("telegraph_rate", "active")["note"]
    assert "no reference pixels" in res.row("telegraph_fraction", "reference")["note"]
    assert res.row("read_noise", "active")["status"] == "fitted"
    t = res.table
    nan = ~np.isfinite(t["value"])
    assert np.all(t["status"][nan] == "not constrained")
    assert all(len(note) > 10 for note in t["note"][nan])


@pytest.mark.parametrize("kwargs, match", [
    ({"ramps": np.zeros((5, 4, 4)) * u.adu}, "gain"),
    ({"ramps": np.zeros((2, 4, 4)) * u.electron}, "at least 3"),
    ({"ramps": np.zeros((5, 4, 4)) * u.m}, "electron or adu"),
    ({"times": [0, 1, 1, 2, 3] * u.s}, "increasing"),
    ({"times": np.arange(5.0)}, "time Quantity"),
    ({"ramps": np.zeros((5, 4, 4))}, "electron or adu"),
    ({"groups": 1}, "groups"),
    ({"reference": np.zeros((3, 4), bool)}, "reference mask"),
])
def test_bad_inputs_are_refused_in_one_line(kwargs, match):
    args = {"ramps": np.zeros((5, 4, 4)) * u.electron, "times": np.arange(5) * u.s, **kwargs}
    with pytest.raises(SpherexReduceError, match=match):
        fit_pixel_terms(args.pop("ramps"), args.pop("times"), **args)


@pytest.mark.parametrize("nreads, ndarks", [(3, 1), (3, 2), (12, 1)])
def test_read_noise_of_few_reads_is_unbiased(nreads, ndarks):
    """White noise, no current, few reads (PRIME's one dark of 3): each pixel's variance has
    few degrees of freedom, so it is skewed; the mean read noise was 16 % low at 3 reads
    (a clip for symmetric populations, and the shot noise of slopes clipped at 0) and 0.45 %
    (5 sigma) at 12.  Against numpy: x0 - 2 x1 + x2 has variance 6 sigma^2 at 3 reads."""
    rng = np.random.default_rng(7)
    darks = [rng.normal(0.0, SIGMA, (nreads, 192, 192)).astype(np.float32)
             for _ in range(ndarks)]
    res = fit_pixel_terms([d * u.electron for d in darks], np.arange(nreads) * 1.5 * u.s)
    row = res.row("read_noise", "active")
    assert abs(row["value"] - SIGMA) < 3 * row["error"]
    if nreads == 3:
        x = np.stack(darks).astype(np.float64)
        numpy = np.sqrt(np.mean((x[:, 0] - 2 * x[:, 1] + x[:, 2]) ** 2) / 6)
        assert abs(row["value"] - numpy) < 0.2 * row["error"]
    spread = res.row("read_noise_spread", "active")
    if ndarks * (nreads - 2) < 2:  # one value per pixel: no spread to see beside its error
        assert spread["status"] == "not constrained" and "degree of freedom" in spread["note"]
    else:
        assert spread["status"] == "ruled out"


def test_a_scene_from_the_fit_simulates_the_fitted_terms_again():
    """A detector whose active and reference telegraph populations differ, with spreads of
    dark current and telegraph steps: the fit's scene keeps both populations (one was
    dropped) and the spreads (left out), and darks simulated from it give the same terms
    back, within 4.5 standard errors of the two fits (the first's within 4.5 of the truth)."""
    truth = {"dark_current": 2.0, "dark_current_spread": 0.5,
             "rtn": [{"fraction": 0.04, "amplitude": 80.0, "amplitude_spread": 20.0,
                      "rate": 0.05},
                     {"fraction": 0.15, "amplitude": 200.0, "rate": 0.1,
                      "pixels": "reference"}]}

    def fit(terms, seed):
        sc = _scene()
        sc["scene"] = {**terms, "poisson": True}
        ramps, times, ref = dark_ramps(simulate(sc, seed=seed))
        return fit_pixel_terms(ramps, times, reference=ref)

    first = fit(truth, 21)
    scene = first.to_scene()
    assert [r["pixels"] for r in scene["rtn"]] == ["active", "reference"]
    assert "dark_current_spread" in scene and "amplitude_spread" in scene["rtn"][0]
    again = fit(scene, 22)
    checks = [("dark_current", "active", 2.0), ("dark_current_spread", "active", 0.5)]
    for pixels, pop in zip(("active", "reference"), truth["rtn"], strict=True):
        checks += [(f"telegraph_{k}", pixels, pop[k]) for k in ("fraction", "amplitude",
                                                               "rate")]
    checks.append(("telegraph_amplitude_spread", "active", 20.0))
    for term, pixels, value in checks:
        a, b = first.row(term, pixels), again.row(term, pixels)
        assert b["status"] == "fitted", (term, pixels, b)
        assert abs(a["value"] - b["value"]) < 4.5 * np.hypot(a["error"], b["error"]), (
            term, pixels, a, b)
        assert abs(a["value"] - value) < 4.5 * a["error"], (term, pixels, a, value)


def _sidecar(seed, rate):
    """A JWST-like SIDECAR detector (4 outputs, no phantom reads): 10 e white, 1/f per
    output with ACN and common to them, 5 e/s, 2 % telegraph pixels of 150 e; its
    populations fixed by ``population_seed``; frames of 0.15 s (the simulation's cost)."""
    return {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
            "readout": {"skip": 1, "ref_reads": 8, "phantom_reads": 0, "nframes": 10,
                        "frame_time": 0.15},
            "noise": {"components": [{"name": "outputs", "alpha": 2e-3, "beta": 2e-2},
                                     {"name": "common", "beta": 1e-2, "scope": "common"}],
                      "acn": True},
            "output": {"mode": "ramps"},
            "scene": {"dark_current": 5.0, "population_seed": seed,
                      "rtn": {"fraction": 0.02, "amplitude": 150.0, "rate": rate}}}


def test_pulls_over_twenty_sidecar_detectors_are_standard_normal():
    """20 detectors, each read 4 times (10 reads): the telegraph fraction, step and rate and
    the dark current against the truth; per term the pulls' mean within 0.75 of 0 (about
    3 standard errors of a mean of 20) and their standard deviation in [0.6, 1.6], none
    beyond 5.  The rate came out 17 standard errors low (a fast telegraph's jumps, a third
    of a dark's ten differences, raised the pixel's own scale above them), and the dark
    current's error left out the 1/f drift common to a dark's pixels (pulls' sd 1.9)."""
    truth = {"telegraph_fraction": 0.02, "telegraph_amplitude": 150.0,
             "telegraph_rate": 2.0, "dark_current": 5.0}
    pulls = {term: [] for term in truth}
    for seed in range(20):
        darks = [dark_ramps(simulate(_sidecar(seed, 2.0), seed=100 * seed + k))
                 for k in range(4)]
        res = fit_pixel_terms([d for d, _, _ in darks], darks[0][1], reference=darks[0][2])
        for term, value in truth.items():
            row = res.row(term, "active")
            assert row["status"] == "fitted", (seed, row)
            pulls[term].append((row["value"] - value) / row["error"])
    for term, x in pulls.items():
        x = np.array(x)
        assert abs(x.mean()) < 0.75 and 0.6 < x.std(ddof=1) < 1.6, (term, x.round(2))
        assert np.all(np.abs(x) < 5), (term, x.round(2))


def test_pixel_sums_fit_again_after_more_darks_is_the_fit_of_them_all():
    """`PixelSums.fit` leaves the sums as they were: a second fit gives the same terms and
    maps (it raised KeyError: the first had taken the sums apart, and it divided the
    first-read offsets in place), and a fit after one more dark is that of
    `fit_pixel_terms` on the three darks at once, bit for bit, on darks with hot,
    telegraph and reference pixels."""
    from spherex_reduce.analysis.pixel_terms import PixelSums

    ramps, times, ref = dark_ramps(simulate(_scene(60), seed=12))
    darks = [ramps[:20], ramps[20:40], ramps[40:]]
    sums = PixelSums(times[:20], reference=ref)
    for d in darks[:2]:
        sums.add(d)

    def same(a, b):
        assert a.table.pformat(max_lines=-1, max_width=-1) == \
            b.table.pformat(max_lines=-1, max_width=-1)
        np.testing.assert_array_equal(np.asarray(a.table["value"]), np.asarray(b.table["value"]))
        assert a.maps.keys() == b.maps.keys()
        for name in a.maps:
            np.testing.assert_array_equal(np.asarray(a.maps[name]), np.asarray(b.maps[name]))

    same(sums.fit(), sums.fit())
    sums.add(darks[2])
    same(sums.fit(), fit_pixel_terms(darks, times[:20], reference=ref))


def _flipping_darks(seed, step, p, shape=(192, 192), nreads=12, ndarks=4):
    """``ndarks`` darks of ``nreads`` reads (e) of 10 e white noise in which a fifth of the
    pixels switch ``step`` e with probability ``p`` per interval, by numpy: the darks, the
    telegraph pixels and each one's flips after read 0 (read 0 is set aside)."""
    rng = np.random.default_rng(seed)
    tel = rng.random(shape) < 0.2
    darks, flips = [], np.zeros(shape, int)
    for _ in range(ndarks):
        switch = (rng.random((nreads - 1, *shape)) < p) & tel
        state = np.concatenate([np.zeros((1, *shape), int), np.cumsum(switch, axis=0)
                                % 2]) ^ (rng.random(shape) < 0.5)
        flips += switch[1:].sum(axis=0)
        darks.append((step * state + rng.normal(0, 10.0, state.shape)) * u.electron)
    return darks, tel, flips


def test_a_fast_clear_telegraph_is_found_whatever_each_pixels_noise_estimate():
    """4 darks of 12 reads, 10 e white noise, a fifth of the pixels switching 150 e steps
    with a flip probability 0.3 per interval (by numpy): the steps clear the threshold by
    more than 3 sigma (5 sigma + 3 sigma of a difference is 113 e), so every pixel that flips
    twice or more after read 0 is found jump by jump.  Each pixel's own noise, from the ~28
    differences its jumps leave, scatters; taken in the 'clear' test, its upward scatter
    handed 3.5 % of them to the faint population here (found 96.5 %, the fraction 3.5
    sigma low; 2 sigma on 512² SIDECAR darks, 7.5 sigma at full size); now 99 % or more."""
    nreads = 12
    darks, tel, flips = _flipping_darks(4, 150.0, 0.3, nreads=nreads)
    res = fit_pixel_terms(darks, np.arange(nreads) * u.s, gain=1.0)
    found = np.asarray(res.maps["telegraph"], bool)
    seen = tel & (flips >= 2)
    assert (found & seen).sum() >= 0.99 * seen.sum()
    assert not (found & ~tel).any()
    row = res.row("telegraph_fraction", "active")
    assert abs(row["value"] - tel.mean()) < 3 * row["error"], (row["value"], tel.mean())


def test_the_step_of_telegraph_pixels_near_the_clearance_is_not_biased_by_it():
    """4 darks of 12 reads, 10 e white noise, a fifth of the pixels switching 125 e steps with
    probability 0.05 per interval (by numpy): nearly every flip is found (5 sigma of a
    difference is ~71 e), but a pixel found jump by jump must have its mean jump clear of
    ~113 e (5 + 3 sigma), which one pixel of two or three flips in five or so misses by
    its noise alone.
    The population's step was the mean over the pixels that cleared it, so over those whose
    jumps measured high: +2.6 e, ~20 errors.  Now each half of a pixel's intervals is
    measured where the other half clears: jumps not selected on their own noise.  The step
    within 3 errors of the truth on 3 seeds."""
    nreads, step = 12, 125.0
    for seed in range(3):
        darks, _, _ = _flipping_darks(seed, step, 0.05, shape=(256, 256), nreads=nreads)
        res = fit_pixel_terms(darks, np.arange(nreads) * u.s, gain=1.0)
        row = res.row("telegraph_amplitude", "active")
        assert abs(row["value"] - step) < 3 * row["error"], (seed, row["value"], row["error"])
        assert row["error"] < 0.4, row["error"]


def test_the_step_is_still_fitted_when_few_pixels_jump_in_both_halves():
    """One dark in which every telegraph pixel makes one excursion of two intervals within
    one half of the dark but one pixel (by numpy): the halves measure one pixel, too few
    for an error, and the step falls back to the mean of the pixels found (it was "not
    constrained" with 656 found), which says so."""
    nreads, shape, step = 12, (64, 64), 125.0
    rng = np.random.default_rng(0)
    state = np.zeros((nreads, *shape))
    tel = rng.random(shape) < 0.2
    for j, (a, b) in enumerate(zip(*np.nonzero(tel), strict=True)):
        k = 4 if j == 0 else rng.choice([1, 2, 6, 7])  # only the first straddles the middle
        state[k + 2:k + 4, a, b] = 1
    dark = (step * state + rng.normal(0, 10.0, state.shape)) * u.electron
    row = fit_pixel_terms([dark], np.arange(nreads) * u.s, gain=1.0).row(
        "telegraph_amplitude", "active")
    assert row["status"] == "fitted" and "too few" in row["note"], row
    assert abs(row["value"] - step) < 5 * row["error"] and row["error"] < 1.0, row


def test_a_telegraph_flipping_at_most_intervals_is_sought_about_its_mean_rate():
    """4 darks of 12 reads, 10 e white noise, a fifth of the pixels switching 150 e steps
    with probability 0.4 per interval (by numpy): in a dark where a pixel flips at most of
    its intervals its median rate sits near a flip, and jumps sought about it lost a flip
    (98.96 % of the pixels that flipped twice or more found, the fraction 1 error low);
    about the mean rate, which such a pixel keeps, 99.8 %, and the fraction and rate
    within 2 errors of the truth."""
    nreads, p = 12, 0.4
    darks, tel, flips = _flipping_darks(5, 150.0, p, nreads=nreads)
    res = fit_pixel_terms(darks, np.arange(nreads) * u.s, gain=1.0)
    found = np.asarray(res.maps["telegraph"], bool)
    seen = tel & (flips >= 2)
    assert (found & seen).sum() >= 0.995 * seen.sum() and not (found & ~tel).any()
    rate = -np.log(1 - 2 * p) / 2  # per second: reads 1 s apart
    for term, truth in (("telegraph_fraction", tel.mean()), ("telegraph_rate", rate)):
        row = res.row(term, "active")
        assert abs(row["value"] - truth) < 2 * row["error"], (term, row["value"], truth)


def test_darks_without_light_sensitive_pixels_are_refused_term_by_term():
    """Every pixel a reference pixel: the active terms are refused with the reason, the
    reference read noise is fitted (the faint telegraph's sums crashed on the empty set
    with a numpy casting error)."""
    rng = np.random.default_rng(0)
    darks = [rng.normal(0, 10, (12, 4, 4)) * u.electron for _ in range(3)]
    res = fit_pixel_terms(darks, np.arange(12) * u.s, gain=1.0, reference=np.ones((4, 4), bool))
    row = res.row("dark_current", "active")
    assert row["status"] == "not constrained" and "no light-sensitive" in row["note"]
    assert abs(res.row("read_noise", "reference")["value"] - 10) < 2
