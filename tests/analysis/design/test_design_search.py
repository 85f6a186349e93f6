"""design_readout: the families of row orders, the search's optimum against a brute force
over the public forecast, the frame-time budget, the report and the paired Monte Carlo."""

import re

import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable, Table

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.analysis import forecast
from spherex_reduce.analysis.design.file import load_design
from spherex_reduce.analysis.design.row_orders import (
    explicit_order,
    family_orders,
    golden_order,
    nested_order,
    radical_inverse_order,
)
from spherex_reduce.analysis.design.search import design_readout
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.simulation import load_scene

GEOMETRY = {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 4}
NOISE = {"components": [{"name": "f", "beta": 1e-2, "alpha": 1e-5},
                        {"name": "v", "beta": 4e-3, "visibility": "both"}]}
SCENE = {"geometry": GEOMETRY, "readout": {"nframes": 4}, "noise": NOISE}
BAND = {"kmin": 0.3, "kmax": 1.5}


def _design(**extra):
    search = {"families": ["skip"], "skips": [1, 2, 3, 4, 6, 8], "phantom_reads": [2],
              "ref_reads": [8], "ref_modes": ["distributed"], "iterations": 0,
              **extra.pop("search", {})}
    return {"scene": SCENE, "band": BAND, "baseline": {"skip": 4, "ref_reads": 8,
                                                       "phantom_reads": 2},
            "search": search, "realizations": 0, **extra}


def _band(scene, pipeline="spherex-default"):
    return forecast(scene, pipeline, {**BAND, "bins": 4}).meta["band_power"]


def test_orders_are_the_permutations_their_definitions_give():
    n = 16
    bits = [int(f"{i:04b}"[::-1], 2) for i in range(n)]  # bit reversal of 4-bit indices
    assert radical_inverse_order(n, 2).tolist() == bits
    assert nested_order(n, (2, 2, 2, 2)).tolist() == bits
    skip = [r for k in range(3) for r in range(k, n, 3)]
    assert nested_order(n, (3,)).tolist() == skip
    frac = [(i * (np.sqrt(5) - 1) / 2) % 1 for i in range(n)]
    assert golden_order(n).tolist() == sorted(range(n), key=frac.__getitem__)
    for _, _, p in family_orders(n):
        assert sorted(p.tolist()) == list(range(n))
    labels = [label for _, label, _ in family_orders(8, ["skip"], skips=[1, 8, 9, 7])]
    assert labels == ["S=1", "S=7"]  # S >= n is physical order again: dropped


def test_an_explicit_skip_order_is_the_schedule_of_that_skip():
    g = DetectorGeometry(40, 8, 1, ref_border={"top": 2, "bottom": 2})
    for mode in ("distributed", "repeated"):
        s = ReadoutSchedule(g, skip=5, ref_reads=7, ref_mode=mode)
        order = explicit_order(g, nested_order(g.n_active_rows, (5,)), 7, mode)
        assert order == s.rows.tolist()


def test_the_search_finds_the_best_skip_of_a_brute_force_over_every_skip():
    design = _design(search={"skips": list(range(1, 25))})
    res = design_readout(design)
    powers = {}
    for s in range(1, 25):
        scene = {**SCENE, "readout": {"nframes": 4, "skip": s, "ref_reads": 8,
                                      "phantom_reads": 2, "frame_time": res.report.meta[
                                          "frame_time"]}}
        powers[s] = _band(scene)
    best = min(powers, key=powers.get)
    assert res.best.label == f"S={best}"
    assert res.best.band_power == pytest.approx(powers[best], rel=1e-9)
    assert res.baseline.band_power == pytest.approx(powers[4], rel=1e-9)
    assert res.report.meta["gain"] == pytest.approx(1 - powers[best] / powers[4], rel=1e-9)
    assert load_scene(res.best_scene).schedule.skip == best  # written as a skip


def test_timing_respects_the_budget_and_the_local_search_only_improves():
    budget = 0.03  # s at 100 kHz: 3000 samples; 24 active rows of (c + 8 + 4) samples
    design = _design(budget={"frame_time": budget},
                     search={"phantom_reads": [0, 2, 40, 80], "ref_reads": [4, 8, 40, 100],
                             "ref_modes": ["distributed", "repeated"], "iterations": 15,
                             "finalists": 2})
    res = design_readout(design)
    for c in res.candidates:
        assert (24 + c.ref_reads) * (c.phantom_reads + 12) <= 3000
    tried = {(c.phantom_reads, c.ref_reads) for c in res.candidates}
    assert tried >= {(80, 4), (80, 8), (0, 100), (2, 100)} and (40, 100) not in tried
    sched = load_scene(res.best_scene).schedule
    assert sched.frame_time.to_value(u.s) == pytest.approx(budget)
    # every skip-order candidate (families and timing stages) forecast here from its S, c, r
    # and placement: its band power is that forecast, and the best is no worse than any
    powers = []
    for c in res.candidates:
        if c.skip is not None:
            readout = {"nframes": 4, "skip": c.skip, "ref_reads": c.ref_reads,
                       "ref_mode": c.ref_mode, "phantom_reads": c.phantom_reads,
                       "frame_time": budget}
            powers.append(_band({**SCENE, "readout": readout}))
            assert c.band_power == pytest.approx(powers[-1], rel=1e-9)
    assert len(powers) > 10 and res.best.band_power <= min(powers) * (1 + 1e-12)
    assert res.best.band_power == pytest.approx(_band(res.best_scene), rel=1e-9)
    assert sum(c.stage == "local" for c in res.candidates) >= 1


def _skip_scene(skip, noise=NOISE, frame_time=None):
    """SCENE read with skip S, r = 8 distributed, c = 2 (the frame time: the design's)."""
    readout = {"nframes": 4, "skip": skip, "ref_reads": 8, "phantom_reads": 2,
               **({} if frame_time is None else {"frame_time": frame_time})}
    return {**SCENE, "noise": noise, "readout": readout}


def _gain_design(**extra):
    """A search whose best (S = 3) is not its baseline (S = 1)."""
    return _design(search={"skips": [1, 3]}, baseline={"skip": 1, "ref_reads": 8,
                                                       "phantom_reads": 2}, **extra)


def test_the_report_splits_the_gain_by_component_and_by_k():
    res = design_readout(_gain_design(bins=4))
    rep, meta = res.report, res.report.meta
    ft = meta["frame_time"]
    a, b = _band(_skip_scene(1, frame_time=ft)), _band(_skip_scene(3, frame_time=ft))
    assert b < a and res.best.label == "S=3"
    assert meta["gain"] == pytest.approx(1 - b / a, rel=1e-9)
    assert (meta["band_power_baseline"], meta["band_power_best"]) == pytest.approx((a, b))
    pa, pb = (forecast(_skip_scene(s, frame_time=ft), "spherex-default", {**BAND, "bins": 4})
              for s in (1, 3))
    np.testing.assert_allclose(rep["power_baseline"].value, pa["power"].value, rtol=1e-12)
    np.testing.assert_allclose(rep["ratio"], pb["power"].value / pa["power"].value,
                               rtol=1e-12)
    # each component's band power: the forecast of a scene with that component alone
    parts = meta["band_power_components"]
    assert set(parts) == {c["name"] for c in NOISE["components"]}
    for comp in NOISE["components"]:
        alone = {"components": [comp]}
        ca = _band(_skip_scene(1, alone, ft))
        cb = _band(_skip_scene(3, alone, ft))
        part = parts[comp["name"]]
        assert (part["baseline"], part["best"]) == pytest.approx((ca, cb), rel=1e-9)
        assert part["share_of_gain"] == pytest.approx((ca - cb) / (a - b), rel=1e-9)
    assert sum(p["share_of_gain"] for p in parts.values()) == pytest.approx(1.0, rel=1e-9)


def test_the_paired_monte_carlo_uses_the_same_seeds_for_both_schedules():
    from spherex_reduce.analysis import run_case

    res = design_readout(_gain_design(realizations=3, seed=5))
    mc = res.report.meta["monte_carlo"]
    assert mc["seeds"] == [5, 7]
    ft = res.report.meta["frame_time"]
    a, b = (np.array([run_case(_skip_scene(s, frame_time=ft), "spherex-default", BAND,
                               seed=seed, mode="slopes").measurement["band_power"].value
                      for seed in (5, 6, 7)]) for s in (1, 3))
    assert (mc["band_power_baseline"], mc["band_power_best"]) == pytest.approx(
        (a.mean(), b.mean()), rel=1e-12)
    ratio = b.mean() / a.mean()
    assert mc["gain"] == pytest.approx(1 - ratio, rel=1e-12)
    # paired: the scatter of b - ratio a over the same seeds, not of b and a apart
    assert mc["gain_err"] == pytest.approx(
        np.std(b - ratio * a, ddof=1) / np.sqrt(3) / a.mean(), rel=1e-9)
    assert set(res.report.colnames) >= {"power_mc_baseline", "power_mc_best"}


@pytest.mark.parametrize("target", [0.13, 0.0])
def test_the_monte_carlo_stops_once_its_gain_is_known_to_the_error_asked(target):
    """The pairs run until the paired gain's standard error (numpy, from pairs measured one
    by one here) is at most ``gain_error``, never before MIN_PAIRS pairs; 0 runs them all."""
    from spherex_reduce.analysis import run_case
    from spherex_reduce.analysis.design.file import MIN_PAIRS

    res = design_readout(_gain_design(realizations=12, seed=3, gain_error=target))
    mc = res.report.meta["monte_carlo"]
    ft = res.report.meta["frame_time"]
    a, b = (np.array([run_case(_skip_scene(s, frame_time=ft), "spherex-default", BAND,
                               seed=seed, mode="slopes").measurement["band_power"].value
                      for seed in range(3, 15)]) for s in (1, 3))
    errors = {n: np.std(b[:n] - b[:n].mean() / a[:n].mean() * a[:n], ddof=1) / np.sqrt(n)
              / a[:n].mean() for n in range(2, 13)}
    n = next((n for n, e in errors.items() if n >= MIN_PAIRS and e <= target), 12)
    assert target == 0 or n < 12  # the case stops early: not a tautology
    assert (mc["realizations"], mc["most_realizations"], mc["seeds"]) == (n, 12, [3, 2 + n])
    assert mc["gain_err"] == pytest.approx(errors[n], rel=1e-9)
    assert mc["gain"] == pytest.approx(1 - b[:n].mean() / a[:n].mean(), rel=1e-12)


def test_a_noise_table_or_fit_noise_result_replaces_the_scenes_noise(tmp_path):
    table = tmp_path / "noise.ecsv"
    Table({"name": ["a"], "alpha": [1e-5], "beta": [3e-3], "gamma": [0.0]}).write(table)
    d = load_design({**_design(), "noise": str(table)})
    assert [c["name"] for c in d.scene["noise"]["components"]] == ["a"]
    fit = tmp_path / "fit.ecsv"
    Table({"stream": ["reference", "phantom"], "alpha": [1e-5, 2e-5], "beta": [1e-3, 0.0],
           "gamma": [0.0, 0.0], "exponent": [1.3, 1.3]}).write(fit)
    d = load_design({**_design(), "noise": str(fit)})
    assert [(c["name"], c["visibility"]) for c in d.scene["noise"]["components"]] == [
        ("reference", "pixels"), ("phantom", "phantom")]


@pytest.mark.parametrize(("design", "words"), [
    ({"bogus": 1}, "design: bogus: unknown parameter; valid: scene, noise"),
    ({"search": {"iterations": 10**9}}, "design: search.iterations: must be in [0, 10000], "
                                       "got 1000000000"),
    ({"search": {"families": ["skip", "random"]}},
     "search.families[1]: 'random' is not one of ['skip', 'nested'"),
    ({"search": {"skips": []}}, "search.skips: expected a list of 1 to 1000"),
    ({"band": {"kmin": 1.0, "kmax": 0.5}}, "band: kmin must be below kmax"),
    ({"budget": {"frame_time": -1}}, "budget.frame_time: must be in (0, 1e+06], got -1.0"),
    ({"realizations": 1.5}, "realizations: expected integer, got 1.5"),
    ({"noise": "nosuch.ecsv"}, "noise: 'nosuch.ecsv' is neither"),
    ({"baseline": {"ref_mode": "none"}},
     "baseline.ref_mode: 'none' is not one of ['distributed', 'repeated']"),
    ({"pipeline": "median"}, "design: pipeline: forecast: steps"),
    ({"pipeline": {"steps": [{"bogus": {}}]}}, "design: pipeline: steps"),
    ({"search": {"phantom_reads": list(range(100)), "ref_reads": list(range(100))}},
     "search: finalists x phantom_reads x ref_reads x ref_modes is 40000 schedules"),
])
def test_bad_designs_are_refused_naming_the_key(design, words):
    with pytest.raises(ConfigError, match=re.escape(words)):
        load_design(design)


def test_the_baselines_skip_is_below_the_number_of_active_rows():
    # 32 rows with a border of 4: 24 active rows; S = 24 would read them in physical order
    assert load_design(_design(baseline={"skip": 23})).baseline.skip == 23
    for skip in (24, 1_000_000):
        with pytest.raises(ConfigError, match=rf"baseline\.skip: must be in \[1, 23\], got {skip}"):
            load_design(_design(baseline={"skip": skip}))


@pytest.mark.parametrize(("key", "value"), [
    ("seed", -1), ("seed", 1.5), ("seed", True), ("realizations", -2), ("realizations", 2.5),
    ("realizations", 10**9)])
def test_seeds_and_realizations_are_refused_as_a_sweep_refuses_them(key, value):
    from spherex_reduce.analysis.sweep import load_sweep
    from spherex_reduce.core.errors import SpherexReduceError

    errors = []
    for load, kind in ((load_design, "design"), (load_sweep, "sweep")):
        with pytest.raises(SpherexReduceError) as info:
            load({"scene": SCENE, "grid": {"skip": [4]}, key: value} if kind == "sweep"
                 else {**_design(), key: value})
        errors.append((type(info.value), str(info.value).replace(f"{kind}: ", "", 1)))
    assert errors[0] == errors[1]
    assert errors[0][1].startswith(f"{key}: ") or errors[0][1].startswith(f"{key} must")


def test_search_seed_and_zero_realizations():
    d = load_design({**_design(), "realizations": 0, "search": {"seed": 2**70}})
    assert (d.realizations, d.search_seed) == (0, 2**70)
    with pytest.raises(ConfigError, match=r"design: search\.seed: must be >= 0, got -1"):
        load_design({"search": {"seed": -1}})


def test_a_budget_too_short_for_the_baseline_is_refused():
    with pytest.raises(ConfigError, match=r"budget\.frame_time: 0\.001 s is too short"):
        design_readout(_design(budget={"frame_time": 0.001}))


@pytest.mark.parametrize("noise", [{"components": []},
                                   {"components": [{"name": "f", "beta": 0.0}]}])
def test_a_baseline_without_noise_in_the_band_is_refused(noise):
    with pytest.raises(ConfigError, match=r"design: noise: the baseline's forecast band power "
                                          r"is 0 \(no noise in the band\): nothing to minimise"):
        design_readout(_design(scene={**SCENE, "noise": noise}))


def test_a_scene_read_at_uneven_times_is_designed_at_those_times():
    """White noise of per-sample variance sigma^2 = alpha fs / 2 read at times t_k, no
    reduction: the band power of every schedule is the least-squares slope variance
    sigma^2 / sum (t - tbar)^2 (written out here), the one the report's summary says it
    reads at, not that of evenly read frames."""
    times = [0.0, 1.0, 2.0, 5.0, 10.0, 20.0]
    scene = {"geometry": GEOMETRY, "readout": {"nframes": 6, "read_times": times},
             "noise": {"components": [{"name": "w", "alpha": 2e-3}]}}
    res = design_readout({**_design(scene=scene), "pipeline": "none"})
    t = np.array(times)
    expect = 2e-3 * load_scene(scene).schedule.geometry.pixel_rate / 2 / np.sum(
        (t - t.mean()) ** 2)
    meta = res.report.meta
    assert "read at 0 ... 20 s (6 times given)" in meta["best"]["summary"]
    assert meta["band_power_baseline"] == pytest.approx(expect, rel=1e-9)
    assert meta["band_power_best"] == pytest.approx(expect, rel=1e-9)
    assert [c.band_power for c in res.candidates] == pytest.approx([expect] * 6, rel=1e-9)
    np.testing.assert_allclose(res.report["power_best"].value, expect, rtol=1e-9)
    assert res.best_scene["readout"]["read_times"] == times


def test_a_scene_read_at_uneven_times_is_not_simulated_by_the_monte_carlo():
    """The simulator refuses read_times: refused before the search, not after it."""
    scene = {**SCENE, "readout": {"nframes": 4, "read_times": [0.0, 1.0, 3.0, 7.0]}}
    with pytest.raises(ConfigError, match=r"^design: realizations: the paired Monte Carlo "
                                          r"simulates the scene: readout\.read_times: .* or "
                                          r"set realizations: 0 \(the forecast alone\)$"):
        load_design({**_design(scene=scene), "realizations": 2})


def test_a_fit_noise_result_with_an_unknown_or_repeated_stream_is_refused(tmp_path):
    """A row fit-noise does not write would be left out of the model without a word."""
    for streams, words in ((["reference", "phantom", "referense"],
                            "row 2: stream 'referense' is not a stream fit-noise writes "
                            "(reference, phantom)"),
                           (["phantom", "phantom"], "row 1: stream 'phantom' twice")):
        fit = tmp_path / "fit.ecsv"
        n = len(streams)
        Table({"stream": streams, "alpha": [1e-5] * n, "beta": [1e-3] * n,
               "gamma": [0.0] * n, "exponent": [1.3] * n}).write(fit, overwrite=True)
        with pytest.raises(ConfigError, match=re.escape(f"design: noise: {fit}: {words}")):
            load_design({**_design(), "noise": str(fit)})


def test_a_fit_noise_result_of_data_in_adu_is_refused(tmp_path):
    """The scene, its sky and the band powers are in electrons: a model fitted to ADU darks
    was taken as electrons (its band powers off by the gain squared)."""
    fit = tmp_path / "fit.ecsv"
    rows = {"stream": ["reference", "phantom"], "beta": [1e-3, 0.0], "gamma": [0.0, 0.0],
            "exponent": [1.3, 1.3]}
    QTable({**rows, "alpha": [1e-5, 2e-5] * u.adu**2 / u.Hz}).write(fit)
    with pytest.raises(ConfigError, match=re.escape(
            f"design: noise: {fit} describes charge in adu, not electrons")):
        load_design({**_design(), "noise": str(fit)})
    QTable({**rows, "alpha": [1e-5, 2e-5] * u.electron**2 / u.Hz}).write(fit, overwrite=True)
    d = load_design({**_design(), "noise": str(fit)})
    assert [c["alpha"] for c in d.scene["noise"]["components"]] == [1e-5, 2e-5]
