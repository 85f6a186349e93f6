"""``characterize``: darks drawn from a known model give every term back within its stated
uncertainty, and the pulls over seeds are consistent with N(0, 1).

The darks are drawn sample by sample here (``_darks.py``, independently of the
package's simulator), from the paper's Table 2 components with their 1/f and
1/f^1.3 coefficients scaled up 100 times: a 256 x 128 array of 4 channels
sees 29 Hz to 1.2 kHz, where Table 2's white ROIC noise would hide them.
What each component of the model holds (`LAYOUT`) follows from Table 2 alone:
white noise is independent from sample to sample, so Video8's white level (seen by
both) appears in the pixels-only and phantom-only components.
"""

import numpy as np
import pytest
from _darks import dark, schedule
from astropy.table import Table

from spherex_reduce.analysis.characterize import characterize
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.simulation import simulate

SCALE = 100.0
#: Table 2: alpha, beta, gamma, scope, visibility
TABLE2 = {"video8": (3.71e-5, 8.4e-3, 0.0, "channel", "both"),
          "roic": (1.97e-3, 0.0, 0.1, "channel", "pixels"),
          "bias_correlated": (0.0, 8.8e-5, 0.0, "common", "both"),
          "bias_phantom_only": (0.0, 3.64e-6, 0.0, "common", "phantom"),
          "bias_pixels_only": (2.91e-6, 3.07e-7, 0.0, "common", "pixels")}


def table2(acn):
    return [{"name": n, "alpha": a, "beta": b * SCALE, "gamma": g * SCALE, "scope": sc,
             "visibility": v, "acn": acn and sc == "channel"}
            for n, (a, b, g, sc, v) in TABLE2.items()]


def truth():
    """Each component of the model, from Table 2 by hand."""
    t = {k: np.array(v[:3]) * [1, SCALE, SCALE] for k, v in TABLE2.items()}
    return {"channel": t["roic"] + [t["video8"][0], 0, 0],
            "channel_both": t["video8"] * [0, 1, 1],
            "channel_phantom": t["video8"] * [1, 0, 0],
            "common": t["bias_pixels_only"],
            "common_both": t["bias_correlated"],
            "common_phantom": t["bias_phantom_only"]}


def pulls(model):
    want = truth()
    out = {}
    for name, est in model.components.items():
        for i, p in enumerate(("alpha", "beta", "gamma")):
            if est.errors[i] > 0:  # a structural zero (white in a cross-spectrum) has none
                out[f"{name}.{p}"] = (est.values[i] - want[name][i]) / est.errors[i]
    return out


def darks(seed, acn, n=12, nframes=5, nrows=256):
    s = schedule(nrows=nrows, nframes=nframes)
    return [dark(s, table2(acn), 100 * seed + k) for k in range(n)]


@pytest.mark.parametrize("acn", [True, False])
def test_every_term_comes_back_within_its_uncertainty(acn):
    """12 darks: the jackknife's pulls follow Student's t with 11 degrees of freedom, which
    exceeds 4.5 in 16 draws with probability 1.4 %."""
    model = characterize(darks(1, acn), segments=1)
    assert model.ngroups == 12 and model.acn["found"] is acn
    got = pulls(model)
    assert len(got) == 16  # 6 components x 3 terms, less the white of the two 'both'
    assert max(abs(v) for v in got.values()) < 4.5, got
    scene = model.scene()["noise"]["components"]
    assert all(c["acn"] is acn for c in scene if c["scope"] == "channel")


@pytest.mark.slow
def test_pulls_over_seeds_are_standard_normal():
    """8 seeds (half with ACN) x 16 terms, on 128 rows: the pulls' mean and spread are
    those of N(0, 1) within their sampling error (the jackknife over 12 darks has 11
    degrees of freedom: its pulls follow Student's t, standard deviation 1.1)."""
    every = []
    for seed in range(8):
        model = characterize(darks(10 + seed, seed % 2 == 0, nrows=128), segments=1)
        every.extend(pulls(model).values())
    x = np.array(every)
    assert x.size == 128
    assert abs(np.mean(x)) < 0.25, np.mean(x)
    assert 0.8 < np.std(x) < 1.5, np.std(x)
    assert np.mean(np.abs(x) > 3) < 0.05


def test_acn_power_is_the_even_odd_difference():
    """Without phantom reads and on one channel's worth of terms: the ACN test compares the
    even-odd difference's correlated power with its error, and the scene says ACN."""
    s = schedule(nframes=5, phantom_reads=0)
    comps = [{"name": "x", "alpha": 2e-3, "beta": 1.0, "scope": "channel", "acn": True}]
    model = characterize([dark(s, comps, k) for k in range(6)], segments=1)
    assert model.acn["found"] and model.acn["z"] > 10
    scene = {c["name"]: c for c in model.scene()["noise"]["components"]}
    assert scene["acn"]["acn"] is True and scene["acn"]["visibility"] == "pixels"
    assert scene["channel"]["acn"] is False  # ACN alone: its own component holds it
    assert any(m.startswith("channel_both, channel_phantom") for m in model.marks)


def test_our_simulator_round_trip_without_phantom():
    """Our simulator's darks (Table 2 scaled, ACN, c = 0): the pixel-visible terms come
    back (with phantom reads: `test_our_simulator_round_trip_with_phantom_reads`)."""
    comps = [{"name": n, "alpha": a, "beta": b * SCALE, "gamma": g * SCALE}
             for n, (a, b, g, _, _) in TABLE2.items()]
    scene = {"geometry": {"nrows": 256, "ncols": 128, "nchannels": 4, "ref_border": 4},
             "readout": {"skip": 1, "ref_reads": 8, "phantom_reads": 0, "nframes": 5,
                         "frame_overhead": 200},
             "noise": {"components": comps}, "output": {"mode": "ramps"}}
    model = characterize([simulate(scene, seed=k) for k in range(8)], segments=1)
    t = {k: np.array(v[:3]) * [1, SCALE, SCALE] for k, v in TABLE2.items()}
    # every channel term of our simulator's scene is ACN: the model's acn component holds
    # their correlated terms, the channel component their white level alone
    chan = t["video8"] + t["roic"]
    want = {"channel": chan * [1, 0, 0], "acn": chan * [0, 1, 1],
            "common": t["bias_correlated"] + t["bias_pixels_only"]}
    assert set(model.components) == set(want)
    assert model.acn["found"]
    for name, est in model.components.items():
        has = est.errors > 0  # the acn component's white is zero by construction
        z = (est.values[has] - want[name][has]) / est.errors[has]
        assert np.all(np.abs(z) < 3.5), (name, est, want[name])


def test_reference_white_level_differs_and_is_marked():
    """Reference pixels noisier than the light-sensitive ones: the model holds the
    light-sensitive level and says the reference one in one line."""
    s = schedule(nframes=5, phantom_reads=0)
    comps = [{"name": "x", "alpha": 2e-3, "scope": "channel"}]
    ds = []
    for k in range(4):
        d = dark(s, comps, k)
        data = np.array(d.data.data)
        ref = s.geometry.reference_pixel_mask()[s.rows]
        extra = np.random.default_rng(k).normal(0, 20.0, data.shape)  # 2 * 400 / 1e5 more
        data[:, ref] += extra[:, ref]
        ds.append(d.replace(data=type(d.data)(data)))
    model = characterize(ds, segments=1)
    pix, ref = model.spectra["pixels"], model.spectra["reference"]
    assert pix.values[0] == pytest.approx(2e-3, abs=4 * pix.errors[0])
    assert ref.values[0] == pytest.approx(2e-3 + 2 * 400 / 1e5, abs=4 * ref.errors[0])
    assert any(m.startswith("reference: white level") for m in model.marks)


def test_what_the_darks_cannot_constrain():
    s = schedule(nrows=64, ncols=64, nchannels=1, nframes=3, phantom_reads=0)
    one = dark(s, [{"name": "x", "alpha": 1e-3}], 0)
    with pytest.raises(SpherexReduceError, match="uncertainties: one dark of 3 reads"):
        characterize(one)
    s = schedule(nrows=64, ncols=64, nchannels=1, nframes=4, phantom_reads=0)
    model = characterize([dark(s, [{"name": "x", "alpha": 1e-3}], k) for k in range(3)])
    assert any(m.startswith("common: not constrained: one channel") for m in model.marks)
    assert any(m.startswith("uncertainties: from the scatter of 3") for m in model.marks)
    report = model.report()
    assert isinstance(report, Table) and "marks" in report.meta


def test_darks_in_adu_without_a_gain_say_the_unit():
    from astropy import units as u

    s = schedule(nrows=64, ncols=64, nchannels=2, nframes=4, phantom_reads=0)
    adu = [dark(s, [{"name": "x", "alpha": 1e-3}], k) for k in range(3)]
    adu = [d.replace(data=type(d.data)(np.asarray(d.data.data), unit=u.adu)) for d in adu]
    model = characterize(adu)
    assert model.unit == u.adu and "unit: adu" in model.to_yaml()
    assert any(m.startswith("unit: the darks are in adu") for m in model.marks)
    scene = model.scene()
    assert scene["unit"] == "adu" and "gain" not in scene  # the scene says its unit
    assert simulate({**scene, "output": {"mode": "ramps"}}, seed=1).unit == u.adu


def test_darks_in_adu_with_a_gain_give_a_scene_in_adu_with_its_gain():
    """ADU darks in memory, the config's gain 2 e-/adu (not applied to an exposure already
    read): the scene is in adu with that gain, its per-pixel terms in adu; loaded, it is
    the same scene in electrons with every charge times the gain (numpy: alpha x 4)."""
    import yaml

    from spherex_reduce.reduce.pipeline import as_pipeline
    from spherex_reduce.simulation import load_scene

    raws = [simulate(PIXEL_SCENE, seed=seed) for seed in (1, 2)]
    adu = [e.replace(data=np.asarray(e.data.data) / 2.0, unit="adu") for e in raws]
    model = characterize(adu, as_pipeline({"input": {"gain": 2.0}, "steps": ["unchop"]}))
    scene = yaml.safe_load(model.to_yaml())
    assert scene["unit"] == "adu" and scene["gain"] == 2.0
    assert not any(m.startswith("unit:") for m in model.marks)
    assert scene["scene"]["dark_current"] == pytest.approx(0.5 / 2.0, rel=0.1)
    sc = load_scene(scene)
    electrons = sc.in_electrons()
    alpha = [c.alpha for c in sc.components]
    np.testing.assert_allclose([c.alpha for c in electrons.components], np.multiply(alpha, 4))
    assert electrons.terms.dark_current == pytest.approx(2.0 * sc.terms.dark_current)


def test_one_dark_alone_is_split_into_runs_of_frames_and_says_so():
    s = schedule(nrows=64, ncols=64, nchannels=2, nframes=20, phantom_reads=0)
    model = characterize(dark(s, [{"name": "x", "alpha": 1e-3}], 0))
    assert model.ngroups == 4  # 20 frames: 4 runs of 5
    assert any(m.startswith("uncertainties: from 4 runs of frames of 1 dark")
               for m in model.marks)
    two = characterize([dark(s, [{"name": "x", "alpha": 1e-3}], k) for k in range(2)])
    assert two.ngroups == 2 and not any("runs of frames" in m for m in two.marks)


def test_phantom_reads_without_noise_are_marked_not_fitted():
    """Phantom reads that see no component (every value the same) constrain no phantom or
    both term: marked, and the pixels' terms are still fitted."""
    s = schedule(nrows=64, ncols=64, nchannels=2, nframes=4, phantom_reads=2)
    model = characterize([dark(s, [{"name": "x", "alpha": 1e-3}], k) for k in range(3)])
    assert "phantom" not in model.spectra and set(model.components) == {"channel", "common"}
    assert any("phantom reads are constant" in m for m in model.marks)


def test_a_strong_common_part_comes_back():
    """Noise common to all 4 channels as strong as each channel's: the common part (the
    mean cross-spectrum of different channels) and the channel part both come back.  The
    pairs' mean was 4 times too large (C times, a factor C/(C - 1) instead of 1/(C - 1)),
    hidden while the truth's common terms were small."""
    s = schedule(nframes=5, phantom_reads=0)
    comps = [{"name": "ch", "alpha": 2e-3, "gamma": 5.0, "scope": "channel"},
             {"name": "co", "alpha": 5e-4, "beta": 0.5, "scope": "common"}]
    model = characterize([dark(s, comps, 500 + k) for k in range(12)])
    want = {"channel": [2e-3, 0.0, 5.0], "common": [5e-4, 0.5, 0.0]}
    for name, est in model.components.items():
        z = (est.values - want[name]) / est.errors
        assert np.all(np.abs(z) < 4.5), (name, est, want[name])
    common = model.components["common"]
    assert common.values[1] == pytest.approx(0.5, rel=0.3)  # beta: 4x before



def test_a_term_fitted_below_zero_moves_into_the_term_it_is_constrained_with():
    """Issue 33: no common white noise under a strong common 1/f: the common white level
    comes out below zero (within its error; seed 0 of a few), and the common 1/f^1.3 and
    the channel's 1/f below zero beside positive terms of their shape.  The scene set each
    to 0 and kept the positive terms, raising each pixel's white level (channel.alpha +
    common.alpha) and its 1/f band power.  Now the scene keeps the fitted sum and the
    fitted band power of the pixels (numpy, from the model's table), and the marks say
    what was moved."""
    s = schedule(nrows=64, ncols=64, nframes=10, phantom_reads=0)
    comps = [{"name": "w", "alpha": 2e-3, "scope": "channel"},
             {"name": "c", "beta": 2.0, "scope": "common"}]
    model = characterize([dark(s, comps, k) for k in range(4)], pixels=False)
    t = model.report()
    fitted = {(r["name"], r["parameter"]): r["value"] for r in t if r["kind"] == "component"}
    assert fitted[("common", "alpha")] < 0 < fitted[("channel", "alpha")]
    assert fitted[("common", "gamma")] < 0 < fitted[("common", "beta")]
    scene = {c["name"]: c for c in model.scene()["noise"]["components"]}
    assert all(v >= 0 for c in scene.values() for v in (c["alpha"], c["beta"], c["gamma"]))
    assert scene["common"]["alpha"] == 0.0
    assert scene["channel"]["alpha"] + scene["common"]["alpha"] == pytest.approx(
        fitted[("channel", "alpha")] + fitted[("common", "alpha")], rel=1e-12)
    f = np.asarray(model.bins["pixels"]["frequency"])  # the pixels' fitted frequencies
    lo, hi, e = f.min(), f.max(), model.exponent

    def band(b, g):  # the 1/f and 1/f^e power over the band
        return b * np.log(hi / lo) + g * (hi ** (1 - e) - lo ** (1 - e)) / (1 - e)

    want = sum(band(fitted[(n, "beta")], fitted[(n, "gamma")]) for n in ("channel", "common"))
    got = sum(band(scene[n]["beta"], scene[n]["gamma"]) for n in ("channel", "common"))
    assert want > 0 and got == pytest.approx(want, rel=1e-9)
    mark = [m for m in model.marks if m.startswith("common.alpha = ")]
    assert len(mark) == 1 and "moved into channel.alpha" in mark[0], model.marks
    assert any(m.startswith("common.gamma = ") and "kept by common.beta" in m
               for m in model.marks), model.marks


def test_scene_values_keep_a_visibilitys_sum_and_clip_what_sums_below_zero():
    """`scene_values` on numbers written here: a negative common term moves into the
    channel one (their sum kept); a sum below zero is 0 with both terms; a negative beta
    whose component's band power is below zero takes its gamma to 0."""
    from spherex_reduce.analysis.characterize.model import scene_values

    fitted = {"channel_phantom": [3e-3, 2.0, 0.0], "common_phantom": [-1e-3, -3.0, 0.0],
              "acn": [0.0, -1.0, 1.0]}
    band = (10.0, 1000.0)
    vals, notes = scene_values(fitted, 1.3, {"acn": band})
    np.testing.assert_allclose(vals["channel_phantom"], [2e-3, 0.0, 0.0], rtol=1e-12)
    np.testing.assert_array_equal(vals["common_phantom"], [0.0, 0.0, 0.0])
    # acn: -ln(100) + (1000^-0.3 - 10^-0.3)/(-0.3) = -4.6 + 1.67 < 0
    np.testing.assert_array_equal(vals["acn"], [0.0, 0.0, 0.0])
    assert set(notes) == {("common_phantom", "alpha"), ("common_phantom", "beta"),
                          ("channel_phantom", "beta"), ("acn", "beta")}
    assert notes[("channel_phantom", "beta")].endswith("below zero; 0 in the scene")

# -- the per-pixel terms, summed dark by dark -------------------------------------------
PIXEL_SCENE = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2, "ref_border": 4},
               "readout": {"skip": 4, "ref_reads": 8, "phantom_reads": 0, "nframes": 30,
                           "frame_time": 1.5},
               "noise": {"components": [{"name": "white", "alpha": 5e-4}]},
               "output": {"mode": "ramps"},
               "scene": {"dark_current": 0.5, "hot_pixel_fraction": 0.02,
                         "hot_pixel_current": 20.0}}


def test_the_per_pixel_terms_of_darks_read_one_by_one_are_those_of_the_darks_together():
    """Two simulated darks (readout order): characterize sums their per-pixel terms as it
    reads them, each dark's rows taken in place; the same numbers as fit_pixel_terms on
    both darks copied to physical order, and within 4.5 errors of the scene's truth; the
    model's scene holds them."""
    from astropy import units as u

    from spherex_reduce.analysis.faint_telegraph import common_labels
    from spherex_reduce.analysis.pixel_terms import dark_ramps, fit_pixel_terms

    raws = [simulate(PIXEL_SCENE, seed=seed) for seed in (1, 2)]
    assert raws[0].order == "readout"
    together = [dark_ramps(e) for e in raws]
    for darks in (raws[:1], raws):
        model = characterize(darks)
        expect = fit_pixel_terms([r for r, _, _ in together[:len(darks)]], together[0][1],
                                 reference=together[0][2],
                                 labels=common_labels(raws[0].geometry))
        np.testing.assert_array_equal(np.asarray(model.pixel_terms.table["value"]),
                                      np.asarray(expect.table["value"]))
    # the truth, from one dark (the simulator draws its hot pixels anew for each seed: two
    # seeds are two detectors' populations, which the sums over darks take as one)
    model = characterize(raws[0])
    for term, truth in (("dark_current", 0.5), ("hot_pixel_fraction", 0.02),
                        ("hot_pixel_current", 20.0)):
        row = model.pixel_terms.row(term, "active")
        assert abs(row["value"] - truth) < 4.5 * row["error"], (term, row)
    scene = model.scene()["scene"]
    assert scene["dark_current"] == pytest.approx(model.pixel_terms.row(
        "dark_current", "active")["value"])
    report = model.report()
    assert {"read_noise", "dark_current"} <= set(report["parameter"][report["kind"] == "pixel"])
    assert u.Unit(report["unit"][report["parameter"] == "dark_current"][0]) == u.electron / u.s


def test_darks_in_adu_without_a_gain_keep_the_stream_model_and_mark_the_pixels():
    raws = [simulate(PIXEL_SCENE, seed=seed) for seed in (1, 2)]
    adu = [e.replace(data=e.data.data, unit="adu") if hasattr(e, "replace") else e
           for e in raws]
    model = characterize(adu)
    assert model.pixel_terms is None and "scene" not in model.scene()
    assert any(m.startswith("per-pixel terms: not fitted: ") and "gain" in m
               for m in model.marks), model.marks


def _pixel_darks(s, n, fraction=0.0, amplitude=150.0, flip=0.3, current=0.0, hot=0.0,
                 hot_current=0.0, light_only=False):
    """Darks of white noise alone (2e-3 e^2/Hz: 10 e per sample) with per-pixel terms, the
    same pixels in every dark: a telegraph population (``fraction`` of all pixels, two
    states ``amplitude`` apart flipping at a frame with probability ``flip``), a dark
    current of ``current`` e per frame in the light-sensitive pixels and ``hot_current`` in
    a ``hot`` fraction of them, with its shot noise (Poisson counts, frame by frame);
    ``light_only``: the telegraph pixels among the light-sensitive ones alone."""
    from astropy import units as u

    from spherex_reduce import Exposure

    g = s.geometry
    rng = np.random.default_rng(99)
    tele = rng.random((g.nrows, g.ncols)) < fraction
    light = ~g.reference_pixel_mask()
    rows, cols = np.nonzero(tele & light if light_only else tele)
    mean = np.where(light, current, 0.0)
    mean[light & (rng.random(light.shape) < hot)] = hot_current
    out = []
    for k in range(n):
        # no noiseless dark ramp: the per-pixel terms take a mean slope for Poisson charge
        data = np.array(dark(s, [{"name": "x", "alpha": 2e-3}], 500 + k,
                             dark_current=0.0).data.data)
        flips = rng.random((rows.size, s.nframes)) < flip
        state = amplitude * (np.cumsum(flips, axis=1) % 2)  # (pixels, frames)
        for p, (r, c) in enumerate(zip(rows, cols, strict=True)):
            data[:, s.rows == r, c] += state[p][:, None]  # every read of its row
        if current or hot:  # each read of a row: the charge its pixels hold then
            charge = np.cumsum(rng.poisson(mean, (s.nframes, *mean.shape)), axis=0)
            data += charge[:, s.rows]
        out.append(Exposure.from_arrays(data, s, unit=u.electron))
    return out


def test_telegraph_pixels_stay_out_of_the_stream_white_level():
    """Issue 33: a telegraph population (5 % of the pixels, steps of 150 e against 10 e of
    white noise) is the per-pixel terms' (``scene.rtn``); the streams leave those pixels
    out, so the channel and reference white levels are the injected 2e-3 e^2/Hz of one
    sample (the row means average fewer pixels: their white level is larger, the fit
    says it per sample), not raised by the steps (before: about 3.5 times the truth)."""
    s = schedule(nrows=128, ncols=128, nframes=12, phantom_reads=0)
    model = characterize(_pixel_darks(s, 4, fraction=0.05), segments=1)
    assert model.pixel_terms.row("telegraph_fraction", "active")["status"] == "fitted"
    assert model.pixel_terms.row("telegraph_fraction", "reference")["status"] == "fitted"
    pix, ref = model.spectra["pixels"], model.spectra["reference"]
    for est in (pix, ref):
        assert est.values[0] == pytest.approx(2e-3, abs=max(3 * est.errors[0], 0.03 * 2e-3))


def test_dark_current_shot_noise_and_hot_pixels_stay_out_of_the_stream_white_level():
    """Issue 33: the dark current's shot noise (20 e per frame: a random walk of each pixel,
    about 19 e^2 per value about its line against 100 e^2 of white noise) and 0.5 % hot
    pixels (3000 e per frame) are the per-pixel terms' (``scene.dark_current``, hot
    pixels): the channel white level is the injected 2e-3 e^2/Hz (before: about 1.35 times
    it)."""
    s = schedule(nrows=128, ncols=128, nframes=12, phantom_reads=0)
    model = characterize(_pixel_darks(s, 4, current=20.0, hot=0.005, hot_current=3000.0),
                         segments=1)
    assert model.pixel_terms.row("hot_pixel_fraction", "active")["value"] > 0.003
    pix = model.spectra["pixels"]
    assert pix.values[0] == pytest.approx(2e-3, abs=max(3 * pix.errors[0], 0.03 * 2e-3))



@pytest.mark.parametrize("nframes, flip", [(12, 0.3), (24, 0.05)])
def test_faint_telegraph_population_matches_the_truth(nframes, flip):
    """Issue 33: 10 % of the pixels with 30 e steps (3 sd of a difference: never found jump
    by jump) flipping at a frame with probability ``flip`` (rate per state
    ``-ln(1 - 2 flip) / (2 dt)``: 9.5 and 1.1 Hz) are the faint population, each term
    within 3 of its errors of the truth, its fraction times its step squared its power
    (the scene's population has the fitted variance).  Before: the darks' noiseless ramp
    (5 e a frame) was taken for a Poisson current whose shot noise was taken out of the
    structure function: 49.5 e steps at 20 Hz and a fraction times step squared twice the
    power (12 frames), a power of -23785 e^2 "ruled out" (24 frames).

    The population is held once: the scene's white level is the injected 2e-3 e^2/Hz
    within 3 errors of the pixels' white read noise, not the streams', which hold part of
    the steps too (they came out 17 % and 7 % high: 5-6 of their errors)."""
    s = schedule(nrows=128, ncols=128, nframes=nframes, phantom_reads=0)
    model = characterize(_pixel_darks(s, 8, fraction=0.1, amplitude=30.0, flip=flip),
                         segments=1)
    dt = float(np.median(np.diff(s.frame_starts.value)))
    truth = {"fraction": 0.1, "amplitude": 30.0, "power": 0.1 * 30.0 ** 2,
             "rate": -np.log1p(-2 * flip) / (2 * dt)}
    rows = {k: model.pixel_terms.row(f"faint_telegraph_{k}", "active") for k in truth}
    for key, value in truth.items():
        assert rows[key]["status"] == "fitted", (key, rows[key]["note"])
        assert abs(rows[key]["value"] - value) < 3 * rows[key]["error"], (key, rows[key])
    faint = model.scene()["scene"]["rtn"]
    assert faint["fraction"] * faint["amplitude"] ** 2 == pytest.approx(
        rows["power"]["value"], rel=1e-9)
    white = model.pixel_terms.row("white_read_noise", "active")
    rate = s.geometry.pixel_rate
    err = 4 * white["value"] * white["error"] / rate  # of 2 sigma^2 / rate
    seen = sum(c["alpha"] for c in model.scene()["noise"]["components"])
    assert seen == pytest.approx(2e-3, abs=3 * err)
    assert any(m.startswith("channel.alpha: the streams' ") for m in model.marks), model.marks


def test_a_faint_population_of_light_sensitive_pixels_is_not_taken_for_quieter_references():
    """10 % of the light-sensitive pixels with faint steps (30 e), reference and
    light-sensitive pixels with the same white noise: the streams' white level holds part of
    the steps and stands above the reference pixels' by many errors, but the scene holds the
    pixels' own white read noise (`faint_white`), which is the reference level within its
    errors: no ``active_read_noise`` and no line saying the levels differ (review: the split
    was decided on the streams' gap, and the line said "holds both" where the scene held
    nothing)."""
    s = schedule(nrows=128, ncols=128, nframes=12, phantom_reads=0)
    model = characterize(_pixel_darks(s, 8, fraction=0.1, amplitude=30.0, light_only=True),
                         segments=1)
    pix, ref = model.spectra["pixels"], model.spectra["reference"]
    assert pix.values[0] - ref.values[0] > 3 * np.hypot(pix.errors[0], ref.errors[0])
    assert model.faint_white() is not None
    assert "active_read_noise" not in model.scene()["scene"]
    assert not any(m.startswith("reference:") for m in model.marks), model.marks


def _faint_terms(fraction_status, white):
    """Per-pixel terms with a faint population's power, rate and step fitted, its fraction
    fitted or not, and the white read noise ``white`` (every other term not constrained)."""
    from spherex_reduce.analysis.pixel_terms import PixelTerms

    rows = [(t, "active", np.nan, np.nan, "", "not constrained", "") for t in (
        "dark_current", "hot_pixel_fraction", "hot_pixel_current", "dark_current_spread",
        "hot_pixel_current_spread")]
    rows += [(f"telegraph_{k}", p, np.nan, np.nan, "", "not constrained", "")
             for p in ("active", "reference")
             for k in ("fraction", "amplitude", "rate", "amplitude_spread", "rate_spread")]
    for term, value, status in (
            ("faint_telegraph_power", 90.0, "fitted"), ("faint_telegraph_rate", 0.3, "fitted"),
            ("faint_telegraph_amplitude", 30.0, "fitted"),
            ("faint_telegraph_fraction", 0.1, fraction_status),
            ("white_read_noise", white, "fitted")):
        fitted = status == "fitted"
        rows.append((term, "active", value if fitted else np.nan,
                     0.01 * value if fitted else np.nan, "", status, ""))
    return PixelTerms(Table(rows=rows, names=("term", "pixels", "value", "error", "unit",
                                              "status", "note")), {})


def _seen(scene):
    """The white level the light-sensitive pixels see, and the channel component's."""
    comps = scene["noise"]["components"]
    return (sum(c["alpha"] for c in comps if c.get("visibility", "pixels") in ("pixels", "both")),
            next(c["alpha"] for c in comps if c["name"] == "channel"))


@pytest.mark.parametrize("fraction_status", ["fitted", "not constrained"])
def test_the_white_level_is_the_pixels_only_where_the_scene_holds_the_faint_population(
        fraction_status):
    """The channel white level is taken from the pixels' white read noise only where the
    scene's ``rtn`` holds the faint population (fraction, step and rate fitted): otherwise
    the population would be held nowhere (review of issue 33's change)."""
    from spherex_reduce.io.examples import example_raw_exposure

    model = characterize(example_raw_exposure(), segments=2, pixels=False)
    seen, channel = _seen(model.scene())
    rate = model.schedule.geometry.pixel_rate
    target = seen - channel / 2  # the pixels' white level, below the streams'
    model.pixel_terms = _faint_terms(fraction_status, np.sqrt(target * rate / 2))
    scene = model.scene()
    held = "rtn" in scene.get("scene", {})
    assert held == (fraction_status == "fitted")
    if held:  # less the drift about the pixels read together (tested apart), which the
        # fit's white read noise holds and the components hold too
        from spherex_reduce.analysis.characterize.result import group_drift

        drift = group_drift(scene["noise"]["components"], model.schedule)
        assert 0 < drift < 0.1 * target * rate / 2
        assert model.faint_white() == pytest.approx(target * rate / 2 - drift, rel=1e-12)
        assert _seen(scene)[0] == pytest.approx(target - 2 * drift / rate, rel=1e-12)
    else:
        assert model.faint_white() is None
        assert _seen(scene) == pytest.approx((seen, channel), rel=1e-12)


# -- memory: one dark's streams at a time ------------------------------------------------
def _old_path(exposures, cuts):
    """The model as characterize made it before its streams were reduced dark by dark: every
    dark's streams (runs ``cuts``) taken first and held, then their spectra, then the fits
    of all and of all but each (the jackknife), as `Characterization.build` takes them."""
    from astropy import units as u

    from spherex_reduce.analysis.characterize.result import Characterization
    from spherex_reduce.analysis.characterize.spectra import dark_spectra, fit_spectra, pool
    from spherex_reduce.analysis.characterize.streams import channel_streams

    s = exposures[0].schedule
    streams = [channel_streams(e, frames=cut) for e in exposures for cut in cuts]
    spectra = [dark_spectra(st, s) for st in streams]

    def fits(keep):
        return fit_spectra(pool([spectra[i] for i in keep]), streams[0].boxes, s, 1.3, 30)

    every = range(len(spectra))
    return Characterization.build(fits(every), [fits([j for j in every if j != i])
                                                for i in every],
                                  streams[0].boxes, s, u.one, ["d"] * len(exposures))


def test_darks_streams_are_held_one_at_a_time_and_the_model_is_unchanged(monkeypatch):
    """A full-size dark's streams are ~160 MB: characterize held every dark's until the end,
    and the first dark's runs of frames too (in case it stayed alone), which took two
    1.28 GB darks to 2.28 GB of peak memory.  Now each dark's streams are reduced to their
    spectra once the dark is released (none is alive when the next dark's are taken) and a
    list of several darks takes no runs; the model is the old path's, number for number
    (built in the test)."""
    import weakref

    from spherex_reduce.analysis.characterize import run as run_module

    s = schedule(nrows=64, ncols=64, nchannels=2, nframes=20, phantom_reads=2)
    comps = [{"name": "x", "alpha": 1e-3, "beta": 0.5, "scope": "channel", "visibility": "both"},
             {"name": "c", "alpha": 2e-4, "scope": "common"}]
    exposures = [dark(s, comps, 40 + k) for k in range(3)]
    taken, others = [], []  # (the dark, its streams' largest array); earlier darks' alive
    original = run_module.dark_streams

    def counted(source, cuts, leave_out=None):
        exposure = source.exposure()  # the one in memory: not a copy
        alive = sum(e is not exposure and r() is not None for e, r in taken)
        got = original(source, cuts, leave_out=leave_out)
        others.extend([alive] * len(got))
        taken.extend((exposure, weakref.ref(st.sum)) for st in got)
        return got

    monkeypatch.setattr(run_module, "dark_streams", counted)
    whole = [slice(0, 20)]
    runs = [slice(5 * k, 5 * k + 5) for k in range(4)]  # one dark alone: 4 runs of 5 frames
    # streams taken: one per dark; an iterator's first dark also its 4 runs; one dark alone
    # its 4 runs and the whole dark
    for given, old, calls in ((exposures, _old_path(exposures, whole), 3),
                              (iter(exposures), _old_path(exposures, whole), 3 + 4),
                              (exposures[0], _old_path(exposures[:1], runs), 4 + 1)):
        taken.clear(), others.clear()
        model = characterize(given, pixels=False)
        assert len(taken) == calls and others == [0] * calls, (calls, others)
        assert model.ngroups == old.ngroups and set(model.components) == set(old.components)
        for name, est in old.components.items():
            np.testing.assert_array_equal(model.components[name].values, est.values)
            np.testing.assert_array_equal(model.components[name].errors, est.errors)
        assert model.acn == old.acn


def test_our_simulator_round_trip_with_phantom_reads():
    """The paper's case on our simulator (Table 2 scaled, ACN, c = 4, 12 darks): every term
    of the three-way split comes back within its uncertainty, as on the darks drawn here.
    Before the simulator drew a both-visible component as one realisation for the pixels
    and the phantom reads above f_B/2 too, Video8's 1/f came back as pixels-only and
    phantom-only (pulls of channel_both.beta -10 and -19 on two sets of seeds)."""
    scene = {"geometry": {"nrows": 256, "ncols": 128, "nchannels": 4, "ref_border": 4},
             "readout": {"skip": 1, "ref_reads": 8, "phantom_reads": 4, "nframes": 5,
                         "frame_overhead": 200},
             "noise": {"components": table2(True)}, "output": {"mode": "ramps"}}
    model = characterize([simulate(scene, seed=k) for k in range(12)], segments=1)
    assert model.acn["found"]
    got = pulls(model)
    assert len(got) == 16
    assert max(abs(v) for v in got.values()) < 4.5, got


@pytest.mark.parametrize("column", [13, 14])
def test_a_left_out_pixel_leaves_the_stream_whatever_group_its_column_is_in(column):
    """Channels of 15 columns: 7 of each parity and one more (column 14). A pixel with a
    1000 e step is left out of its channel's stream, in a parity's columns (13) or the
    odd one over (14): the stream is the clean dark's within a pixel's share of its
    noise (each row mean 1/15 of a pixel's, about 0.07 e here), where the step left in
    moved it by 1000/15. Before, a group of one column kept its pixel, as if every
    pixel of the channel were left out."""
    from astropy import units as u

    from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    from spherex_reduce.analysis.characterize.streams import channel_streams

    g = DetectorGeometry(16, 30, 2, ref_border={"top": 2, "bottom": 2})
    s = ReadoutSchedule(g, skip=1, ref_reads=4, phantom_reads=0, nframes=5, frame_overhead=20)
    clean = np.random.default_rng(1).normal(0, 1, (5, s.n_reads, 30))
    stepped = clean.copy()
    stepped[2:, s.rows == 8, column] += 1000.0
    drop = np.zeros((16, 30), bool)
    drop[8, column] = True
    got = channel_streams(Exposure.from_arrays(stepped, s, unit=u.electron), leave_out=drop)
    ref = channel_streams(Exposure.from_arrays(clean, s, unit=u.electron))
    assert np.abs(got.sum - ref.sum).max() < 0.5
    assert got.boxes["sum"].whites[0] == pytest.approx(np.mean(
        [15 / 14 if read_row == 8 else 1.0 for read_row in s.rows[~s.is_reference]]
        + [1.0] * int(np.sum(s.is_reference))))


# -- memory: a dark read band by band (issue 33, speed item) -------------------------------
def _files(tmp_path, nframes, n=2, nrows=256, ncols=256):
    from spherex_reduce.io import write

    scene = {"geometry": {"nrows": nrows, "ncols": ncols, "nchannels": ncols // 64,
                          "ref_border": 4},
             "readout": {"skip": 1, "ref_reads": 8, "phantom_reads": 2, "nframes": nframes,
                         "frame_overhead": 200},
             "output": {"mode": "ramps"}}
    paths = []
    for k in range(n):
        e = simulate(scene, seed=k)
        paths.append(tmp_path / f"dark{k}.fits")
        write(e, paths[-1])
    return paths, e.data.data.size * 4  # float32 in the file


def test_a_dark_file_is_never_in_memory_whole(tmp_path):
    """Two full-size darks (2048² × 74) took characterize to 2.36 GB: each was read whole
    (1.27 GB of float32, converted from the file's big-endian values) beside the per-pixel
    sums.  Read band by band of reads, the peak of numpy's arrays (tracemalloc sees them)
    over the whole run stays below 1.6 times one dark's float32 cube at 512 × 256 × 100
    (1.11 times now, two bands of 32 rows in flight; 2.13 times with each dark read
    whole)."""
    import tracemalloc

    paths, cube = _files(tmp_path, 100, nrows=512)
    tracemalloc.start()
    try:
        characterize(paths)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1.6 * cube, peak / cube


def test_darks_read_from_files_give_the_model_of_the_darks_in_memory(tmp_path, monkeypatch):
    """The model of two raw files, read band by band (the file is never read whole: a whole
    read is refused here), is the model of the same darks read whole into memory, number
    for number: the streams' terms, the per-pixel terms and ACN."""
    from spherex_reduce.io import FrameReader, read

    paths, _ = _files(tmp_path, 12, nrows=128, ncols=128)
    exposures = [read(p) for p in paths]
    memory = characterize(exposures)

    def whole(self):
        raise AssertionError("a raw file read whole")

    monkeypatch.setattr(FrameReader, "exposure", whole)
    banded = characterize(paths)
    for name, est in memory.components.items():
        np.testing.assert_array_equal(banded.components[name].values, est.values)
        np.testing.assert_array_equal(banded.components[name].errors, est.errors)
    assert banded.acn == memory.acn
    for a, b in zip(memory.pixel_terms.table, banded.pixel_terms.table, strict=True):
        np.testing.assert_array_equal([a["value"], a["error"]], [b["value"], b["error"]])


def test_the_slope_scatter_of_dark_files_is_that_of_the_darks_in_memory(tmp_path,
                                                                        monkeypatch):
    """With the slope scatter, each dark is reduced at its first N reads for every N of the
    grid: from a file, band by band of rows (a whole read is refused here; it held each
    full-size dark whole: 3.26 GB for two), the measured scatter, P(k) and band power are
    those of the darks read whole into memory, number for number.  (Against numpy's own
    fits: `test_measured_scatter_is_numpys_lstsq_of_the_ramps_differenced_and_clipped`.)"""
    from spherex_reduce.io import FrameReader, read

    paths, _ = _files(tmp_path, 12, nrows=128, ncols=128)
    memory = characterize([read(p) for p in paths], "spherex-default", pixels=False,
                          scatter=True)

    def whole(self):
        raise AssertionError("a raw file read whole")

    monkeypatch.setattr(FrameReader, "exposure", whole)
    banded = characterize(paths, "spherex-default", pixels=False, scatter=True)
    assert memory.check is not None and len(memory.check) > 10, memory.marks
    for name in ("measured", "error", "predicted"):
        np.testing.assert_array_equal(banded.check[name], memory.check[name])


def test_the_streams_of_bands_are_the_channel_means_numpy_takes(tmp_path):
    """`dark_streams` reads a raw file 7 reads at a time (bands that split the reference
    rows' reads): each channel's stream is the mean of its light-sensitive columns at every
    read (the reference pixels of those columns in reference-row reads), a line across
    frames removed at each read and scaled by sqrt(N / (N - 2)), as numpy computes it here
    from the whole file; the phantom stream likewise; and a column with a value that is
    not finite in one read is left out (its channel's stream read again without it)."""
    from astropy.io import fits

    from spherex_reduce.analysis.characterize.streams import dark_streams
    from spherex_reduce.io import open_input

    paths, _ = _files(tmp_path, 6, n=1, nrows=64, ncols=128)
    with fits.open(paths[0]) as hdul:
        data = hdul["SCI"].data.astype(np.float64)
        phantom = hdul["PHANTOM"].data.astype(np.float64)
    bad = data.copy()
    bad[3, 1, 70] = np.nan  # read 1 of frame 3, column 70 (channel 1)
    bad_path = tmp_path / "bad.fits"
    with fits.open(paths[0]) as hdul:
        hdul["SCI"].data = bad.astype(np.float32)
        hdul.writeto(bad_path, checksum=True)

    def detrended(v):  # (..., frames, reads): a line per read position, by least squares
        n = v.shape[-2]
        x = np.vander(np.arange(n, dtype=float), 2)
        flat = np.moveaxis(v, -2, 0).reshape(n, -1)
        res = flat - x @ np.linalg.lstsq(x, flat, rcond=None)[0]
        return np.moveaxis(res.reshape(np.moveaxis(v, -2, 0).shape), 0, -2) * np.sqrt(n / (n - 2))

    for path, values, gone in ((paths[0], data, ()), (bad_path, bad, (70,))):
        with open_input(path) as inp:
            source = inp.source()
            g = source.context.schedule.geometry
            st = dark_streams(source, [slice(None)], band_reads=7)[0]
        light = ~g.reference_column_mask()
        chan = g.channel_of_column()
        keep = [np.flatnonzero(light & (chan == c) & ~np.isin(np.arange(g.ncols), gone))
                for c in range(g.nchannels)]
        n = min(k.size for k in keep)  # every channel as many columns, in scan order
        offs = g.column_offsets()
        want = np.stack([values[:, :, k[np.argsort(offs[k])][:n]].mean(axis=-1) for k in keep])
        np.testing.assert_allclose(st.sum, detrended(want), rtol=0, atol=1e-9)
        np.testing.assert_allclose(st.phantom, detrended(np.moveaxis(phantom, -1, 0)),
                                   rtol=0, atol=1e-9)


def test_the_integrations_of_a_4d_file_are_darks_and_none_is_split(tmp_path, monkeypatch):
    """Every integration of a 4-D file is a dark, as when the same ramps are given as a
    list, number for number; the first integration, which has others after it, is not also
    split into its runs of frames (streams and spectra taken for nothing: only a dark alone
    is split)."""
    from astropy.io import fits

    from spherex_reduce.analysis.characterize import run
    from spherex_reduce.io import read

    paths, _ = _files(tmp_path, 12, nrows=128, ncols=128)
    four = tmp_path / "darks4d.fits"
    with fits.open(paths[0]) as hdul:
        copies = fits.HDUList([h.copy() for h in hdul])
        for name in ("SCI", "PHANTOM"):  # one per integration
            copies[name].data = np.stack([fits.getdata(p, name) for p in paths])
        copies.writeto(four, checksum=True)
    cuts = []
    streams = run.dark_streams
    monkeypatch.setattr(run, "dark_streams",
                        lambda source, c, **kw: (cuts.append(len(c)), streams(source, c,
                                                                              **kw))[1])
    integrations = characterize(four, pixels=False)
    assert cuts == [1, 1]  # one run (the whole dark) each: no runs of frames
    listed = characterize([read(p) for p in paths], pixels=False)
    assert integrations.darks == [f"{four}[0]", f"{four}[1]"]
    for name, est in listed.components.items():
        np.testing.assert_array_equal(integrations.components[name].values, est.values)
        np.testing.assert_array_equal(integrations.components[name].errors, est.errors)


def test_dark_files_one_gzipped_file_per_read_give_the_model_of_the_darks_in_memory(
        tmp_path):
    """Reads stored one gzipped file each are read through astropy's HDU, which one thread
    at a time may read: the per-pixel sums' bands (two at once) and the scatter's reductions
    (the executor's threads) read them without a crash or a wrong number (two bands read
    at once failed every time), the model number for number that of the darks in memory."""
    from astropy.io import fits

    from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule

    g = DetectorGeometry(128, 128, 2, ref_border=4, pixel_rate=1e5)
    s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, nframes=12)
    rng = np.random.default_rng(0)
    darks, exposures = [], []
    for d in range(2):
        ramps = rng.normal(100, 5, (12, 128, 128)).astype(np.float32)
        exposures.append(Exposure.from_arrays(ramps, s))
        header = s.to_header()
        darks.append([])
        for k in range(12):
            path = tmp_path / f"d{d}_read_{k + 1:02d}.fits.gz"
            fits.PrimaryHDU(ramps[k], header).writeto(path)
            darks[-1].append(str(path))
    files = characterize(darks, scatter=True)
    memory = characterize(exposures, scatter=True)
    for name, est in memory.components.items():
        np.testing.assert_array_equal(files.components[name].values, est.values)
    for a, b in zip(memory.pixel_terms.table, files.pixel_terms.table, strict=True):
        np.testing.assert_array_equal([a["value"], a["error"]], [b["value"], b["error"]])
    np.testing.assert_array_equal(files.check["measured"], memory.check["measured"])


@pytest.mark.parametrize("listed", [True, False])
def test_the_per_pixel_sums_are_released_before_the_last_darks_scatter(monkeypatch, listed):
    """The per-pixel sums (~0.6 GB for a full-size dark) were alive until the end, through
    the last dark's reductions (the peak) and the prediction (two frame counts at a time:
    2.17 GB for two full-size darks).  Once the last dark of a list is summed they are
    fitted and let go, before its scatter; darks from an iterator (the last not known) are
    fitted after the loop, before the prediction.  The per-pixel terms are those of the
    sums fitted at the end (`PixelSums.fit`, in the test)."""
    import gc
    import weakref

    from spherex_reduce.analysis.characterize import run as run_module
    from spherex_reduce.analysis.faint_telegraph import common_labels
    from spherex_reduce.analysis.pixel_terms import PixelSums, dark_ramps, fit_pixel_terms

    s = schedule(nrows=64, ncols=64, nchannels=2, nframes=12, phantom_reads=2)
    comps = [{"name": "x", "alpha": 1e-3, "beta": 0.5, "scope": "channel"}]
    exposures = [dark(s, comps, 70 + k) for k in range(2)]
    made, alive = [], {"scatter": [], "compare": []}

    class Recorded(PixelSums):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(weakref.ref(self))

    def when(name, original):
        def counted(*args, **kwargs):
            gc.collect()
            alive[name].append(sum(r() is not None for r in made))
            return original(*args, **kwargs)
        return counted

    monkeypatch.setattr(run_module, "PixelSums", Recorded)
    monkeypatch.setattr(run_module, "_add_scatter", when("scatter", run_module._add_scatter))
    monkeypatch.setattr(run_module, "compare", when("compare", run_module.compare))
    model = characterize(exposures if listed else iter(exposures), scatter=True)
    assert len(made) == 1
    assert alive == {"scatter": [1, 0] if listed else [1, 1], "compare": [0]}
    together = [dark_ramps(e) for e in exposures]
    expect = fit_pixel_terms([r for r, _, _ in together], together[0][1],
                             reference=together[0][2], labels=common_labels(s.geometry))
    np.testing.assert_array_equal(np.asarray(model.pixel_terms.table["value"]),
                                  np.asarray(expect.table["value"]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64, ">f4", ">f8"])
def test_a_channels_column_sums_are_numpys_sums_of_its_columns(dtype):
    """The streams sum a channel's even or odd columns as a strided view (no copy) when
    they are evenly spaced: the numbers of numpy's sum over those columns taken as a
    list, bit for bit (float64 data keep the list); uneven, unsorted and dropped columns
    too."""
    from spherex_reduce.analysis.characterize.streams import _kept_sum

    rng = np.random.default_rng(5)
    data = (rng.normal(0, 1, (3, 7, 96)) * 1e4).astype(dtype)
    drop = np.zeros((7, 16), bool)
    drop[2, 3] = True
    for cols in (np.arange(4, 36, 2), np.arange(5, 37, 2), np.arange(64, 96),
                 np.array([1, 2, 4, 8]), np.array([9, 3, 5]), np.arange(80, 96)):
        want = np.sum(np.asarray(data, np.float64)[:, :, cols], axis=-1)
        exact = np.sum(data[:, :, cols], axis=-1, dtype=np.float64)
        np.testing.assert_array_equal(_kept_sum(data, cols, None), exact)
        np.testing.assert_allclose(exact, want, rtol=1e-12, atol=1e-9)
        if cols.size == 16:
            got = _kept_sum(data, cols, drop)
            exact[:, 2] -= data[:, 2, cols[3]]
            np.testing.assert_array_equal(got, exact)


def test_darks_read_in_quadrants_are_characterised_with_their_per_pixel_terms():
    """Four quadrants read side by side (WFC3-IR's layout): the per-pixel terms' groups of
    pixels read together are taken in the readout frame the darks are read in (they were
    mapped to the stored image and raised a ValueError out of characterize)."""
    scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4,
                          "channels": "quadrants"},
             "readout": {"nframes": 8, "phantom_reads": 0},
             "noise": {"components": [{"name": "w", "alpha": 2e-3}]},
             "output": {"mode": "ramps"}}
    model = characterize([simulate(scene, seed=k) for k in range(4)], segments=1)
    assert model.pixel_terms is not None
    row = model.pixel_terms.row("read_noise", "active")
    assert row["status"] == "fitted"
    assert row["value"] == pytest.approx(10.0, rel=0.05)  # 2e-3 e^2/Hz at 100 kHz: 10 e
