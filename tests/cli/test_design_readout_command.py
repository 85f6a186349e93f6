"""``spherex-reduce design-readout``: BEST.yaml is a scene simulate, forecast and reduce take;
the report and plot are written; bad designs exit 2 in one line and write nothing."""

import re

import pytest
import yaml
from _cli_helpers import one_line_error, run
from astropy.table import Table

from spherex_reduce.analysis import forecast

DESIGN = """\
scene:
  geometry: {nrows: 32, ncols: 16, nchannels: 2, ref_border: 4}
  readout: {nframes: 4}
  noise: {components: [{name: f, beta: 0.01, alpha: 1.0e-5}]}
band: {kmin: 0.3, kmax: 1.5}
bins: 4
baseline: {skip: 1, ref_reads: 8, phantom_reads: 2}
search: {families: [golden, radical_inverse], phantom_reads: [2], ref_reads: [8],
         ref_modes: [distributed], iterations: 3}
realizations: 2
"""


def test_design_writes_a_scene_that_simulate_forecast_and_reduce_accept(tmp_path, capsys):
    design = tmp_path / "design.yaml"
    design.write_text(DESIGN)
    best, report, png = tmp_path / "best.yaml", tmp_path / "report.ecsv", tmp_path / "d.png"
    assert run("design-readout", design, "-o", best, "--report", report, "--plot", png) == 0
    out = capsys.readouterr().out
    assert "gain" in out and "Monte Carlo (2 paired realisations)" in out
    rep = Table.read(report)
    scene = yaml.safe_load(best.read_text())
    assert len(scene["readout"]["order"]) == 32  # an explicit order: 24 active + 8 reference
    assert forecast(scene, "spherex-default", {"kmin": 0.3, "kmax": 1.5, "bins": 4}).meta[
        "band_power"] == pytest.approx(rep.meta["band_power_best"], rel=1e-9)
    assert png.read_bytes()[:4] == b"\x89PNG"
    raw, red = tmp_path / "raw.fits", tmp_path / "red.fits"
    assert run("simulate", best, "-o", raw, "--mode", "ramps") == 0
    assert run("reduce", raw, "-c", "spherex-default", "-o", red) == 0
    assert red.is_file()


@pytest.mark.parametrize(("text", "words"), [
    ("search: {iterations: -3}\n",
     ["design.yaml: search.iterations: must be in [0, 10000], got -3"]),
    ("pipeline: median\n", ["design.yaml: pipeline: forecast:", "median"]),
    ("pipeline: no-such\n", ["design.yaml: pipeline: no pipeline config file 'no-such'"]),
    ("nonsense: 1\n", ["design.yaml: nonsense: unknown parameter; valid: scene"]),
    ("budget: {frame_time: 0.5}\n", ["budget.frame_time: 0.5 s is too short"]),
    ("scene: {geometry: {nrows: 32, ncols: 16, nchannels: 2, ref_border: 4}, noise: "
     "{components: []}}\nband: {kmin: 0.3, kmax: 1.5}\nbaseline: {skip: 4, ref_reads: 8}\n",
     ["design.yaml: noise:", "nothing to minimise"]),
])
def test_bad_designs_exit_2_in_one_line_and_write_nothing(tmp_path, capsys, text, words):
    design = tmp_path / "design.yaml"
    design.write_text(text)
    best = tmp_path / "best.yaml"
    assert run("design-readout", design, "-o", best) == 2
    assert one_line_error(capsys, "spherex-reduce design-readout: error:", *words)
    assert not best.exists()


def test_best_yaml_keeps_every_component_of_the_fit_noise_model(tmp_path, capsys):
    """BEST.yaml, read back, holds the model the design was made with: each row of the
    fit-noise result (its coefficients, the reference stream seen by the pixels, the phantom
    stream by the phantom reads), none left out."""
    from astropy import units as u

    fit = tmp_path / "fit.ecsv"
    rows = Table({"stream": ["reference", "phantom"],
                  "alpha": [1e-5, 2e-5] * u.electron**2 / u.Hz,
                  "beta": [1e-3, 4e-3] * u.electron**2,
                  "gamma": [2e-2, 0.0] * u.electron**2 * u.Hz**0.3, "exponent": [1.3, 1.3]})
    rows.write(fit)
    design = tmp_path / "design.yaml"
    design.write_text(DESIGN.replace("realizations: 2", "realizations: 0")
                      + "noise: fit.ecsv\n")
    best = tmp_path / "best.yaml"
    assert run("design-readout", design, "-o", best) == 0
    comps = yaml.safe_load(best.read_text())["noise"]["components"]
    assert [(c["name"], c["visibility"]) for c in comps] == [("reference", "pixels"),
                                                            ("phantom", "phantom")]
    for c, row in zip(comps, rows, strict=True):
        for key in ("alpha", "beta", "gamma", "exponent"):
            assert c[key] == pytest.approx(float(row[key]), rel=1e-12), (c["name"], key)
    bad = Table(rows)
    bad.add_row(["referenc", 3e-5, 1e-3, 0.0, 1.3])
    bad.write(fit, overwrite=True)
    assert run("design-readout", design, "-o", best, "--overwrite") == 2
    assert one_line_error(capsys, "spherex-reduce design-readout: error:",
                          "row 2: stream 'referenc' is not a stream fit-noise writes")


def test_each_stage_prints_its_expected_duration_before_the_results(tmp_path, capsys):
    """Without -q, each stage of the search prints ``about T for N <steps> (t each)`` once its
    first step is done, as sweep and compare-strategies do: 3 skips, 2 finalists x 1 timing,
    3 moves, 2 paired realisations (counted from the design by hand)."""
    design = tmp_path / "design.yaml"
    design.write_text(DESIGN.replace(
        "search: {families: [golden, radical_inverse], phantom_reads: [2], ref_reads: [8],",
        "search: {families: [skip], skips: [1, 2, 3], phantom_reads: [2], ref_reads: [8],"))
    assert run("design-readout", design, "-o", tmp_path / "best.yaml") == 0
    out = capsys.readouterr().out.splitlines()
    expected = ["3 row orders", "2 timings", "3 local-search moves", "2 paired realisations"]
    about = [line for line in out if line.startswith("about ")]
    assert len(about) == 4, out
    for line, what in zip(about, expected, strict=True):
        assert re.fullmatch(rf"about [0-9.]+ (s|min)( [0-9]+ s)? for {what} \([0-9.]+ s each\)",
                            line), line
    assert out.index(about[-1]) < next(i for i, line in enumerate(out)
                                       if "schedules forecast in" in line)


def test_a_monte_carlo_that_stops_early_says_so(tmp_path, capsys):
    """gain_error far above this case's error (~0.1 at 8 pairs): the Monte Carlo stops at the
    8 pairs it runs at least, announces up to 12 and says why it ran fewer."""
    design = tmp_path / "design.yaml"
    design.write_text(DESIGN.replace("realizations: 2", "realizations: 12\ngain_error: 0.9"))
    assert run("design-readout", design, "-o", tmp_path / "best.yaml") == 0
    out = capsys.readouterr().out.splitlines()
    assert any(re.fullmatch(r"up to about [0-9.]+ (s|min)( [0-9]+ s)? for up to 12 paired "
                            r"realisations \([0-9.]+ s each; stopping once the gain's standard "
                            r"error is <= 0.9, after 8 at least\)", line) for line in out), out
    assert any(line.startswith("Monte Carlo (8 paired realisations of 12: the gain's error "
                               "reached gain_error): gain ") for line in out), out


#: Every scene term the forecast does not model, as a MODEL.yaml of characterize holds them:
#: hot pixels with a current spread, a spread of the dark current and two telegraph
#: populations (one of the reference pixels), one detector (population_seed).
POPULATIONS = {"dark_current": 1.0, "dark_current_spread": 0.25, "hot_pixel_fraction": 0.2,
               "hot_pixel_current": 400.0, "hot_pixel_current_spread": 40.0,
               "population_seed": 7,
               "rtn": [{"fraction": 0.05, "amplitude": 30.0, "rate": 0.5},
                       {"fraction": 0.1, "amplitude": 10.0, "rate": 2.0,
                        "pixels": "reference"}]}


def _design_with(tmp_path, terms):
    design = tmp_path / "design.yaml"
    text = DESIGN.replace("realizations: 2", "realizations: 0")
    design.write_text(text.replace("  readout: {nframes: 4}\n",
                                   "  readout: {nframes: 4}\n  scene: "
                                   + yaml.safe_dump(terms, default_flow_style=True)))
    return design


def test_terms_the_forecast_does_not_model_are_noted_and_carried_into_best(tmp_path, capsys):
    """Hot pixels, their spread, the dark-current spread and telegraph populations: the search
    leaves each out with its own note line and BEST.yaml holds every one as the scene gave it
    (they were dropped from it), so simulating the designed readout still has the hot pixels:
    ~20 % of the light-sensitive pixels at ~400 e-/s."""
    import numpy as np
    from astropy.io import fits

    best = tmp_path / "best.yaml"
    assert run("design-readout", _design_with(tmp_path, POPULATIONS), "-o", best) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note:")]
    assert [n.split(":")[1].strip() for n in notes] == [
        "scene.hot_pixel_fraction", "scene.hot_pixel_current_spread",
        "scene.dark_current_spread", "scene.rtn"]
    for note, what in zip(notes, ["hot pixels", "the hot pixels' current spread",
                                  "the pixels' dark-current spread",
                                  "telegraph pixels (2 populations)"], strict=True):
        assert f": {what} left out of the search" in note, note
        assert "written unchanged into the best scene" in note, note
    assert yaml.safe_load(best.read_text())["scene"] == POPULATIONS
    slopes = tmp_path / "slopes.fits"
    assert run("-q", "simulate", best, "-o", slopes, "--mode", "slopes") == 0
    with fits.open(slopes) as hdul:
        image = np.asarray(hdul["SCI"].data, dtype=float)
    active = image[4:-4, 4:-4]  # ref_border 4; every other pixel near 1 e-/s
    hot = np.mean(active > 100.0)
    assert 0.1 < hot < 0.3, hot


@pytest.mark.parametrize(("terms", "message"), [
    ({"hot_pixel_fraction": 2}, "scene.hot_pixel_fraction: must be in [0, 1], got 2"),
    ({"hot_pixel_current_spread": -1.0},
     "scene.hot_pixel_current_spread: must be in [0, 1e+09], got -1.0"),
    ({"dark_current_spread": 0.5},
     "scene.dark_current_spread: a spread about a dark_current of 0; give dark_current > 0 "
     "or no spread"),
    ({"rtn": [{"fraction": 0.1, "amplitude": 5.0}, {"fraction": -0.1}]},
     "scene.rtn[1].fraction: must be in [0, 1], got -0.1"),
    ({"rtn": []}, "scene.rtn: a list of 1 to 16 telegraph populations, got 0"),
    ({"rtn": {"fraction": 0.1, "pixels": "some"}},
     "scene.rtn.pixels: 'some' is not one of ['active', 'reference', 'all']"),
])
def test_bad_terms_the_forecast_does_not_model_are_refused_as_simulate_refuses_them(
        tmp_path, capsys, terms, message):
    """They were dropped before the scene was validated: a design took them, exit 0 and a
    note.  Now the line simulate prints for the scene, exit 2, nothing written."""
    design = _design_with(tmp_path, terms)
    best = tmp_path / "best.yaml"
    assert run("design-readout", design, "-o", best) == 2
    one_line_error(capsys, "spherex-reduce design-readout: error:",
                   "design.yaml: scene: " + message)
    assert not best.exists()
    scene = yaml.safe_load(design.read_text())["scene"]
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump(scene))
    assert run("simulate", tmp_path / "scene.yaml", "-o", tmp_path / "s.fits") == 2
    one_line_error(capsys, "spherex-reduce simulate: error: " + message)
