"""A detector's pixel populations fixed by ``scene.population_seed`` across simulation seeds,
their spreads, and a scene in adu (``unit:``, ``gain:``) (issue 33).

The hot and telegraph pixels are found here from the ramps with numpy (a hot pixel's
differences are its current times the frame time, a telegraph pixel's jump by its step),
never from the simulator's own record.
"""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import simulate
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.simulation import load_scene

HOT, STEP = 1000.0, 200.0  # e/s, e


def _scene(terms, nframes=20, **top):
    return {"geometry": {"nrows": 32, "ncols": 32, "nchannels": 2, "ref_border": 4},
            "readout": {"skip": 4, "ref_reads": 8, "phantom_reads": 0, "nframes": nframes,
                        "frame_time": 1.5},
            "noise": {"components": [{"name": "white", "alpha": 2e-5}]},  # 1 e per read
            "output": {"mode": "ramps"}, "scene": terms, **top}


POPULATIONS = {"hot_pixel_fraction": 0.05, "hot_pixel_current": HOT, "poisson": False,
               "rtn": {"fraction": 0.05, "amplitude": STEP, "rate": 5.0, "pixels": "all"}}


def _found(e):
    """Hot pixels (mean difference above half a hot pixel's) and telegraph reads (a
    difference more than half a step from the pixel's median), from the ramps."""
    d = np.diff(np.asarray(e.data.data, dtype=np.float64), axis=0)  # (N - 1, reads, cols)
    hot = d.mean(axis=0) > HOT * 1.5 / 2
    telegraph = np.any(np.abs(d - np.median(d, axis=0)) > STEP / 2, axis=0)
    return hot, telegraph, d


def test_the_same_population_seed_gives_one_detector_whatever_the_seed():
    """Two seeds, one population seed: the same hot and telegraph pixels (active and
    reference: rate 5 Hz flips every pixel within 20 frames), and independent noise (the
    quiet pixels' differences uncorrelated); without it each seed is another detector."""
    sc = _scene({**POPULATIONS, "population_seed": 7})
    (h1, t1, d1), (h2, t2, d2) = (_found(simulate(sc, seed=s)) for s in (1, 2))
    assert h1.sum() > 10 and t1.sum() > 10
    np.testing.assert_array_equal(h1, h2)
    np.testing.assert_array_equal(t1, t2)
    quiet = ~(h1 | t1)
    r = np.corrcoef(d1[:, quiet].ravel(), d2[:, quiet].ravel())[0, 1]
    assert abs(r) < 0.03, r  # ~ 17000 pairs: 4 standard deviations of a correlation
    assert np.std(d1[:, quiet]) == pytest.approx(np.sqrt(2), rel=0.05)
    # another population seed, or none (the default: the simulation's seed), another detector
    h3, t3, _ = _found(simulate(_scene({**POPULATIONS, "population_seed": 8}), seed=1))
    h4, _, _ = _found(simulate(_scene(POPULATIONS), seed=2))
    h5, _, _ = _found(simulate(_scene(POPULATIONS), seed=1))
    assert not np.array_equal(h1, h3) and not np.array_equal(t1, t3)
    assert not np.array_equal(h4, h5)


def test_spreads_of_the_populations_against_numpy():
    """Gamma-distributed dark current (mean 40, sd 10 e/s), hot currents (mean 1000, sd 100)
    and telegraph steps (mean 400, sd 50 e): the pixels' values, measured from the ramps
    with numpy, have those means and spreads."""
    terms = {"dark_current": 40.0, "dark_current_spread": 10.0, "hot_pixel_fraction": 0.2,
             "hot_pixel_current": HOT, "hot_pixel_current_spread": 100.0, "poisson": False,
             "rtn": {"fraction": 0.3, "amplitude": 400.0, "amplitude_spread": 50.0,
                     "rate": 5.0, "pixels": "reference"}, "population_seed": 3}
    sc = _scene(terms, nframes=6)
    sc["geometry"].update(nrows=128, ncols=128, nchannels=4)
    e = simulate(sc, seed=1)
    s = e.schedule
    d = np.diff(np.asarray(e.data.data, dtype=np.float64), axis=0) / 1.5  # e/s
    active = ~s.geometry.reference_pixel_mask()[s.rows]
    rate = np.median(d, axis=0)[active]
    hot = rate > 40 + HOT / 2
    dark, excess = rate[~hot], rate[hot] - 40.0
    assert dark.mean() == pytest.approx(40.0, abs=4 * 10 / np.sqrt(dark.size))
    assert dark.std() == pytest.approx(10.0, rel=0.06)
    assert excess.mean() == pytest.approx(HOT, abs=4 * 100 / np.sqrt(excess.size))
    assert excess.std() == pytest.approx(100.0, rel=0.08)
    ref = s.geometry.reference_pixel_mask()[s.rows]
    steps = np.abs(d[:, ref] * 1.5)
    steps = steps[steps > 100]  # the jumps of the reference telegraph pixels
    assert steps.mean() == pytest.approx(400.0, rel=0.03)
    assert steps.std() == pytest.approx(50.0, rel=0.15)


def test_two_telegraph_populations_are_each_simulated():
    """``rtn:`` a list: the active pixels' steps of 200 e and the reference pixels' of
    600 e, each in its own pixels."""
    terms = {"rtn": [{"fraction": 0.1, "amplitude": STEP, "rate": 5.0},
                     {"fraction": 0.1, "amplitude": 3 * STEP, "rate": 5.0,
                      "pixels": "reference"}]}
    e = simulate(_scene(terms), seed=4)
    s = e.schedule
    d = np.abs(np.diff(np.asarray(e.data.data, dtype=np.float64), axis=0))
    ref = s.geometry.reference_pixel_mask()[s.rows]
    for sel, step in ((~ref, STEP), (ref, 3 * STEP)):
        jumps = d[:, sel][d[:, sel] > STEP / 2]
        assert jumps.size > 20 and np.allclose(jumps, step, atol=8), (step, jumps[:5])


def test_a_scene_in_adu_is_simulated_in_adu_with_the_shot_noise_of_its_gain():
    """``unit: adu, gain: 4``: white noise alpha (adu²/Hz) gives alpha fs / 2 adu² per read,
    and a current I adu/s a difference variance I dt / gain adu² (I g dt electrons of
    Poisson noise, over g²); in slopes mode e/s becomes adu/s."""
    g, current, dt = 4.0, 50.0, 1.5
    sc = _scene({"dark_current": current}, nframes=30, unit="adu", gain=g)
    sc["noise"]["components"][0]["alpha"] = 2e-3  # 100 adu² per read
    e = simulate(sc, seed=5)
    assert e.unit == u.adu
    s = e.schedule
    x = np.asarray(e.data.data, dtype=np.float64)
    ref = s.geometry.reference_pixel_mask()[s.rows]
    assert np.var(x[:, ref]) == pytest.approx(100.0, rel=0.05)  # no current, white only
    d = np.diff(x, axis=0)[:, ~ref]
    assert d.mean() == pytest.approx(current * dt, rel=0.01)
    assert np.var(d) == pytest.approx(2 * 100.0 + current * dt / g, rel=0.04)  # not + I dt
    assert simulate(sc, seed=5, mode="slopes").unit == u.adu / u.s


def test_a_scene_in_adu_in_electrons_for_the_forecast():
    """The forecast of a scene in adu with gain g is that of the same scene written in
    electrons by hand (coefficients times g², currents times g)."""
    from spherex_reduce.analysis.forecast.engine import forecast

    g = 2.5
    base = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
            "readout": {"nframes": 8, "phantom_reads": 0}}
    adu = {**base, "unit": "adu", "gain": g, "scene": {"dark_current": 2.0},
           "noise": {"components": [{"name": "w", "alpha": 1e-3, "beta": 1e-4}]}}
    electrons = {**base, "scene": {"dark_current": 2.0 * g},
                 "noise": {"components": [{"name": "w", "alpha": 1e-3 * g * g,
                                           "beta": 1e-4 * g * g}]}}
    a, b = forecast(adu, None, {"bins": 4}), forecast(electrons, None, {"bins": 4})
    np.testing.assert_allclose(np.asarray(a["power"]), np.asarray(b["power"]), rtol=1e-12)
    with pytest.raises(ConfigError, match="gain"):
        forecast({**adu, "gain": None, "scene": {}}, None, {"bins": 4})


@pytest.mark.parametrize("top, match", [
    ({"unit": "furlong"}, "unit: expected electron or adu"),
    ({"unit": "adu/s"}, "unit: expected electron or adu"),
    ({"unit": 3}, "unit: expected electron or adu"),
    ({"unit": "adu", "gain": 0}, "gain: expected a number"),
    ({"unit": "adu", "gain": ".nan"}, "gain: expected a number"),
    ({"unit": "adu", "gain": True}, "gain: expected a number"),
    ({"gain": 2.0}, "gain: the scene is in electrons"),
    ({"unit": "adu"}, "needs its gain"),
    ({"unit": "adu", "gain": 2, "noise": {"components": ["roic"]}}, "inline"),
    ({"scene": {"population_seed": -1}}, "population_seed"),
    ({"scene": {"population_seed": 1.5}}, "population_seed"),
    ({"scene": {"dark_current": 0, "dark_current_spread": 1.0}}, "dark_current_spread"),
    ({"scene": {"rtn": []}}, "scene.rtn"),
    ({"scene": {"rtn": [{"fraction": 2}]}}, r"scene.rtn\[0\].fraction"),
])
def test_bad_units_gains_and_populations_are_refused_in_one_line(top, match):
    sc = _scene({"dark_current": 1.0})
    for key, value in top.items():
        sc[key] = {**sc[key], **value} if key == "scene" else value
    with pytest.raises(ConfigError, match=match) as exc:
        load_scene(sc)
    assert "\n" not in str(exc.value)
