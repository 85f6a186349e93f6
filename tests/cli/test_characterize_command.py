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


def test_check_on_held_out_darks_prints_writes_and_plots_them(tmp_path, capsys):
    darks = _darks(tmp_path, n=6, nframes=8)
    rep, png = tmp_path / "r.ecsv", tmp_path / "p.png"
    capsys.readouterr()
    assert run("characterize", *darks[:2], "-c", "spherex-default", "-o",
               tmp_path / "m.yaml", "--report", rep, "--plot", png, "--check",
               *darks[2:]) == 0
    out = capsys.readouterr().out
    assert "held-out darks: standard deviation over the light-sensitive pixels" in out
    lines = [ln for ln in out.splitlines() if ln.startswith("slope_scatter N=")]
    assert [ln.split()[1] for ln in (lines[0], lines[-1])] == ["N=2:", "N=8:"]
    t = Table.read(rep)
    assert t.meta["check"]["pairs"] == 2  # four held-out darks: two pairs
    measured = t[(t["kind"] == "slope_scatter") & (t["parameter"] == "measured")]
    assert measured["name"][0] == "N=2" and np.all(measured["value"] > 0)
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_check_with_a_config_that_gives_no_slope_image_is_marked(tmp_path, capsys):
    darks = _darks(tmp_path, n=2)
    capsys.readouterr()
    assert run("characterize", *darks, "-c", "unchop", "-o", tmp_path / "m.yaml") == 0
    assert ("slope scatter and P(k): not compared: slope scatter: the pipeline gives ramps"
            in capsys.readouterr().out)
    assert run("characterize", *darks, "-c", "unchop", "-o", tmp_path / "m2.yaml",
               "--check", tmp_path / "missing.fits") == 2
    one_line_error(capsys, "missing.fits")
    assert not (tmp_path / "m2.yaml").exists()
