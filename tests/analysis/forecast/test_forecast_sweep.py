"""Sweeps with the forecast: each point's columns against the forecast of the point's scene
built by hand and against the analytic pixel variance; the forecast alone in seconds; the
columns beside the Monte Carlo rows, through a resume; the plot's lines and points."""

import time

import numpy as np
import pytest
from astropy.table import Table

from spherex_reduce import expected_slope_variance
from spherex_reduce.analysis import forecast
from spherex_reduce.analysis.sweep import plot_sweep, run_sweep
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.simulation import load_scene

GEOMETRY = {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4}
READOUT = {"nframes": 6, "phantom_reads": 0, "ref_mode": "none"}
PINK = {"name": "pink", "alpha": 2e-3, "beta": 4e-3}
COMMON = {"name": "common", "beta": 2e-4, "scope": "common"}
MEASURE = {"kmin": 0.1, "kmax": 1.0, "bins": 6}
SWEEP = {"scene": {"geometry": GEOMETRY, "readout": READOUT,
                   "noise": {"components": [PINK, COMMON]}},
         "pipeline": ["unchop", {"name": "raw", "steps": [{"unchop": {}}]}],
         "grid": {"skip": [1, 8], "nframes": [4, 6]}, "realizations": 0, "seed": 5,
         "measure": MEASURE}


def test_forecast_columns_are_the_forecast_of_each_points_scene():
    t0 = time.perf_counter()
    res = run_sweep(SWEEP, forecast=True)
    seconds = time.perf_counter() - t0
    t = res.table
    assert res.computed == 0 and not res.failed and seconds < 5
    assert len(t) == 8 and "band_power" not in t.colnames  # 2 skips x 2 N x 2 pipelines
    for row in t:
        scene = {"geometry": GEOMETRY, "noise": {"components": [PINK, COMMON]},
                 "readout": {**READOUT, "skip": int(row["skip"]), "nframes": int(row["nframes"])}}
        expect = forecast(scene, {"steps": [{"unchop": {}}]}, MEASURE)
        assert row["band_power_forecast"] == pytest.approx(expect.meta["band_power"], rel=1e-12)
        power = np.asarray(row["power_forecast"])
        kept = np.isfinite(power)
        assert np.allclose(power[kept], expect["power"].value, rtol=1e-12)
        assert np.allclose(np.asarray(row["k"])[kept], expect["k"].value, rtol=1e-12)
    # skip and N change the forecast; the two (identical) pipelines do not
    bp = {(r["skip"], r["nframes"], r["pipeline"]): r["band_power_forecast"] for r in t}
    assert bp[(1, 4, "unchop")] == bp[(1, 4, "raw")]
    assert bp[(1, 4, "unchop")] != bp[(8, 4, "unchop")] != bp[(8, 6, "unchop")]


def test_forecast_of_white_noise_is_the_analytic_pixel_variance():
    """White noise has a flat P(k) equal to the pixel variance (Parseval), at any skip."""
    white = {"name": "white", "alpha": 3e-3}
    sw = dict(SWEEP, scene={"geometry": GEOMETRY, "readout": READOUT,
                            "noise": {"components": [white]}},
              pipeline="unchop", grid={"skip": [1, 4, 16]})
    t = run_sweep(sw, forecast=True).table
    scene = load_scene(sw["scene"])
    var = expected_slope_variance(scene.components, scene.schedule).value
    assert np.allclose(t["band_power_forecast"].value, var, rtol=1e-9)
    power = np.asarray(t["power_forecast"])
    assert np.allclose(power[np.isfinite(power)], var, rtol=1e-9)


def test_forecast_beside_monte_carlo_rows_and_through_a_resume(tmp_path):
    out = tmp_path / "r.ecsv"
    sw = dict(SWEEP, grid={"skip": [1, 8]}, pipeline="unchop", realizations=2)
    first = run_sweep(sw, out, scheduler="serial", forecast=True).table
    assert len(first) == 4
    # every realisation of a point carries the point's forecast, in the bins of power
    for skip in (1, 8):
        rows = first[first["skip"] == skip]
        assert len(set(rows["band_power_forecast"])) == 1
        assert np.array_equal(np.isnan(rows["power"]), np.isnan(rows["power_forecast"]))
    # one more realisation: the resumed table's new rows have the forecast too
    second = run_sweep(dict(sw, realizations=3), out, scheduler="serial", forecast=True)
    t = Table.read(out)
    assert second.computed == 2 and len(t) == 6
    assert np.all(np.isfinite(t["band_power_forecast"]))
    assert t["band_power_forecast"].description
    # the forecast alone over a results file keeps its Monte Carlo rows
    t0 = run_sweep(sw | {"realizations": 0}, out, forecast=True).table
    assert len(t0) == 6 and "band_power" in t0.colnames
    # without the forecast the columns go (they would not cover new rows)
    assert "band_power_forecast" not in run_sweep(sw, out, scheduler="serial").table.colnames
    fig = plot_sweep(first)
    ax = fig.axes[0]
    assert [ln.get_label() for ln in ax.get_lines() if not ln.get_label().startswith("_")] \
        == ["forecast"]
    assert [c.get_label() for c in ax.containers] == ["Monte Carlo"]
    (line,) = [ln for ln in ax.get_lines() if ln.get_label() == "forecast"]
    assert list(line.get_xdata()) == [1, 8]
    assert np.allclose(line.get_ydata(), [first["band_power_forecast"][first["skip"] == s][0]
                                          for s in (1, 8)])


def test_forecast_only_table_is_replaced_not_extended(tmp_path):
    out = tmp_path / "r.ecsv"
    run_sweep(SWEEP, out, forecast=True)
    res = run_sweep(dict(SWEEP, grid={"skip": [1]}, pipeline="unchop", realizations=1), out,
                    scheduler="serial")
    assert res.computed == 1 and len(Table.read(out)) == 1


def test_what_the_forecast_refuses_is_refused_before_any_cell():
    with pytest.raises(ConfigError, match="realizations: 0 runs no Monte Carlo"):
        run_sweep(SWEEP)
    with pytest.raises(ConfigError, match="mask_sources"):
        run_sweep(SWEEP | {"measure": {"mask_sources": True}}, forecast=True)
    with pytest.raises(ConfigError, match=r"pipeline p: .*fit_ramp\.weighting"):
        run_sweep(SWEEP | {"pipeline": {"name": "p", "steps": [
            {"unchop": {}}, {"fit_ramp": {"weighting": "optimal"}}]}, "mode": "ramps",
            "realizations": 1}, forecast=True)
    with pytest.raises(ConfigError, match="realizations: expected integer, got False"):
        run_sweep(SWEEP | {"realizations": False}, forecast=True)
