"""``spherex-reduce characterize``: MODEL.yaml is a scene that simulate, forecast, sweep and
design-readout take as it is; the report and plot are written; darks that cannot give a
model exit 2 in one line and write nothing."""

import numpy as np
import yaml
from _cli_helpers import digest, one_line_error, run
from astropy.table import Table

SCENE = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2, "ref_border": 4},
         "readout": {"skip": 1, "ref_reads": 8, "phantom_reads": 2, "nframes": 6,
                     "frame_overhead": 100},
         "noise": {"components": [{"name": "roic", "gamma": 10.0},
                                  {"name": "video8", "beta": 0.8}], "acn": False},
         "output": {"mode": "ramps"}}


def _darks(tmp_path, n=4, **readout):
    scene = tmp_path / "truth.yaml"
    scene.write_text(yaml.safe_dump({**SCENE, "readout": {**SCENE["readout"], **readout}}))
    paths = [tmp_path / f"dark{k}.fits" for k in range(n)]
    for k, p in enumerate(paths):
        assert run("-q", "simulate", scene, "-o", p, "--seed", k) == 0
    return paths


def test_model_is_a_scene_every_command_takes(tmp_path, capsys):
    darks = _darks(tmp_path)
    before = [digest(p) for p in darks]
    model, report, png = tmp_path / "model.yaml", tmp_path / "r.ecsv", tmp_path / "p.png"
    assert run("characterize", *darks, "-c", "unchop", "-o", model, "--report", report,
               "--plot", png) == 0
    out = capsys.readouterr().out
    assert "ACN ruled out" in out and f"wrote {model}" in out
    assert [digest(p) for p in darks] == before
    scene = yaml.safe_load(model.read_text())
    assert scene["geometry"]["nrows"] == 64 and scene["readout"]["phantom_reads"] == 2
    names = {c["name"] for c in scene["noise"]["components"]}
    assert "channel" in names and all(c["acn"] is False for c in scene["noise"]["components"]
                                      if c["scope"] == "channel")
    assert model.read_text().startswith("# noise model fitted by spherex-reduce characterize")
    rep = Table.read(report)
    assert rep.meta["segments"] == 4 and set(rep["kind"]) >= {"component", "spectrum",
                                                              "channel", "acn", "exponent"}
    assert np.all(rep["error"][rep["kind"] == "spectrum"] >= 0)
    assert png.read_bytes()[:4] == b"\x89PNG"
    # simulate, forecast, sweep and design-readout on MODEL.yaml as it is
    assert run("-q", "simulate", model, "-o", tmp_path / "sim.fits") == 0
    assert run("-q", "forecast", model, "-c", "spherex-default", "-o",
               tmp_path / "f.ecsv") == 0
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(yaml.safe_dump({"scene": str(model), "pipeline": "unchop",
                                     "grid": {"skip": [1, 4]}, "realizations": 0}))
    assert run("-q", "sweep", sweep, "-o", tmp_path / "s.ecsv", "--forecast") == 0
    design = tmp_path / "design.yaml"
    design.write_text(yaml.safe_dump({
        "scene": "model.yaml", "band": {"kmin": 0.3, "kmax": 1.5}, "bins": 4,
        "baseline": {"skip": 1, "ref_reads": 8, "phantom_reads": 2},
        "search": {"families": ["golden"], "phantom_reads": [2], "ref_reads": [8],
                   "ref_modes": ["distributed"], "iterations": 2},
        "realizations": 0}))
    assert run("-q", "design-readout", design, "-o", tmp_path / "best.yaml") == 0


def test_fitted_exponent_is_reported(tmp_path, capsys):
    darks = _darks(tmp_path, n=3)
    rep = tmp_path / "r.ecsv"
    assert run("-q", "characterize", *darks, "-c", "unchop", "-o", tmp_path / "m.yaml",
               "--report", rep, "--fit-exponent") == 0
    t = Table.read(rep)
    (row,) = t[t["kind"] == "exponent"]
    assert 0.5 <= row["value"] <= 3.0 and row["error"] > 0


def test_one_dark_of_three_reads_is_refused(tmp_path, capsys):
    (dark,) = _darks(tmp_path, n=1, nframes=3)
    model = tmp_path / "m.yaml"
    capsys.readouterr()
    assert run("characterize", dark, "-c", "unchop", "-o", model) == 2
    one_line_error(capsys, "uncertainties: one dark of 3 reads")
    assert not model.exists()


def test_untrusted_input_exits_2_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.fits"
    bad.write_text("not a FITS file\n")
    model = tmp_path / "m.yaml"
    assert run("characterize", bad, "-c", "unchop", "-o", model) == 2
    one_line_error(capsys, "bad.fits")
    assert not model.exists()
    darks = _darks(tmp_path, n=2)
    assert run("characterize", *darks, "-c", "unchop", "-o", model, "--segments", "0") == 2
    assert "--segments" in capsys.readouterr().err
    assert run("characterize", *darks, "-c", "unchop", "-o", model, "--segments", "3") == 2
    one_line_error(capsys, "segments: 3 segments of a dark of 6 reads")


def _design(tmp_path, model):
    design = tmp_path / "design.yaml"
    design.write_text(yaml.safe_dump({
        "scene": model.name, "band": {"kmin": 0.3, "kmax": 1.5}, "bins": 4,
        "baseline": {"skip": 1, "ref_reads": 8, "phantom_reads": 2},
        "search": {"families": ["golden"], "phantom_reads": [2], "ref_reads": [8],
                   "ref_modes": ["distributed"], "iterations": 2},
        "realizations": 0}))
    return design


def test_design_readout_runs_from_a_model_with_pixel_populations(tmp_path, capsys):
    """Darks of a detector with hot and telegraph pixels (one population_seed): MODEL.yaml
    holds them, and design-readout designs the readout from it as it is, saying in one line
    per term that the pixel populations are left out (the forecast refused them)."""
    truth = {**SCENE, "readout": {**SCENE["readout"], "nframes": 12},
             "scene": {"dark_current": 5.0, "hot_pixel_fraction": 0.03,
                       "hot_pixel_current": 500.0, "population_seed": 4,
                       "rtn": {"fraction": 0.05, "amplitude": 300.0, "rate": 2.0}}}
    scene = tmp_path / "truth.yaml"
    scene.write_text(yaml.safe_dump(truth))
    darks = [tmp_path / f"dark{k}.fits" for k in range(3)]
    for k, p in enumerate(darks):
        assert run("-q", "simulate", scene, "-o", p, "--seed", k) == 0
    model = tmp_path / "model.yaml"
    assert run("-q", "characterize", *darks, "-c", "unchop", "-o", model) == 0
    fitted = yaml.safe_load(model.read_text())
    assert fitted["unit"] == "electron"
    assert fitted["scene"]["hot_pixel_fraction"] > 0.01 and "rtn" in fitted["scene"]
    capsys.readouterr()
    assert run("design-readout", _design(tmp_path, model), "-o", tmp_path / "best.yaml") == 0
    out = capsys.readouterr().out
    assert "note: scene.hot_pixel_fraction: left out" in out
    assert "note: scene.rtn: left out" in out


def test_design_readout_from_a_model_in_adu_needs_its_gain(tmp_path, capsys):
    """ADU darks (simulated from a scene in adu) without a gain: MODEL.yaml says unit: adu;
    design-readout, which works in electrons, refuses it in one line naming the gain, and
    takes it once gain: is added (simulate takes it as it is, in adu)."""
    truth = {**SCENE, "unit": "adu", "gain": 2.0}
    scene = tmp_path / "truth.yaml"
    scene.write_text(yaml.safe_dump(truth))
    darks = [tmp_path / f"dark{k}.fits" for k in range(3)]
    for k, p in enumerate(darks):
        assert run("-q", "simulate", scene, "-o", p, "--seed", k) == 0
    model = tmp_path / "model.yaml"
    assert run("-q", "characterize", *darks, "-c", "unchop", "-o", model) == 0
    fitted = yaml.safe_load(model.read_text())
    assert fitted["unit"] == "adu" and "gain" not in fitted
    assert run("-q", "simulate", model, "-o", tmp_path / "sim.fits") == 0
    capsys.readouterr()
    design = _design(tmp_path, model)
    assert run("design-readout", design, "-o", tmp_path / "best.yaml") == 2
    one_line_error(capsys, "design.yaml: scene:", "gain")
    model.write_text(model.read_text() + "gain: 2.0\n")
    assert run("-q", "design-readout", design, "-o", tmp_path / "best.yaml") == 0
