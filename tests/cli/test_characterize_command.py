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


def _darks(tmp_path, n=4, truth=SCENE, **readout):
    scene = tmp_path / "truth.yaml"
    scene.write_text(yaml.safe_dump({**truth, "readout": {**truth["readout"], **readout}}))
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


# A lab's dark stored one plain 2-D FITS file per read (as PRIME's H4RG-10 test reads are):
# float32 whole numbers of ADU, a minimal header, one 128-column output of a 4096² array.
LAB = {"input": {"unit": "adu"},
       "geometry": {"preset": "H4RG-10", "nrows": 64, "ncols": 128, "pixel_rate": 1.0e5},
       "window": {"first_row": 0, "first_column": 0},
       "readout": {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0,
                   "row_overhead": 0, "nframes": 3, "frame_time": 2.0},
       "steps": [{"fit_ramp": {}}]}


def _lab_dark(tmp_path, name, seed):
    """Three reads of white noise (8 adu) on a bias pattern, one file each; the cube too."""
    from astropy.io import fits

    rng = np.random.default_rng(seed)
    bias = rng.normal(-1800.0, 50.0, (64, 128))
    reads = np.rint(bias + rng.normal(0.0, 8.0, (3, 64, 128))).astype(np.float32)
    folder = tmp_path / name
    folder.mkdir()
    for k, read in enumerate(reads, start=1):
        fits.PrimaryHDU(read).writeto(folder / f"{name}N{k}-0.fit.ref")
    fits.PrimaryHDU(reads).writeto(tmp_path / f"{name}.fits")
    return reads, str(folder / f"{name}N*-0.fit.ref")


def _lab_config(tmp_path):
    path = tmp_path / "lab.yaml"
    path.write_text(yaml.safe_dump(LAB))
    return path


def test_one_lab_dark_of_three_read_files_is_refused_naming_why(tmp_path, capsys):
    config, model = _lab_config(tmp_path), tmp_path / "m.yaml"
    _, pattern = _lab_dark(tmp_path, "dark", 0)
    files = sorted((tmp_path / "dark").iterdir())
    # the read files given as darks: each is one read, and the error says how to give them
    assert run("characterize", *files, "-c", config, "-o", model) == 2
    one_line_error(capsys, "single reads", "--reads 'DIR/read_*.fits'")
    # given as one dark: no second dark to see a scatter in, refused in one line naming it
    assert run("characterize", "--reads", pattern, "-c", config, "-o", model) == 2
    one_line_error(capsys, "uncertainties: one dark of 3 reads gives no scatter")
    assert not model.exists()
    assert run("characterize", "-c", config, "-o", model) == 2
    one_line_error(capsys, "--reads GLOB")


def test_lab_darks_as_read_files_give_the_model_of_their_cubes(tmp_path, capsys):
    config = _lab_config(tmp_path)
    darks = [_lab_dark(tmp_path, f"d{k}", k) for k in range(4)]
    by_reads, by_cube = tmp_path / "reads.yaml", tmp_path / "cube.yaml"
    args = ["-c", config, "--segments", "1"]
    globs = [a for _, pattern in darks for a in ("--reads", pattern)]
    assert run("-q", "characterize", *globs, *args, "-o", by_reads,
               "--report", tmp_path / "reads.ecsv") == 0
    cubes = [tmp_path / f"d{k}.fits" for k in range(4)]
    assert run("-q", "characterize", *cubes, *args, "-o", by_cube,
               "--report", tmp_path / "cube.ecsv") == 0
    a, b = Table.read(tmp_path / "reads.ecsv"), Table.read(tmp_path / "cube.ecsv")
    assert len(a.meta["darks"]) == 4
    np.testing.assert_array_equal(a["value"], b["value"])
    np.testing.assert_array_equal(a["error"], b["error"])
    # the light-sensitive pixels' white level against numpy: each pixel's straight line
    # across 3 reads leaves x0 - 2 x1 + x2 (variance 6 sigma^2); one-sided 2 sigma^2 / rate
    x = np.stack([reads for reads, _ in darks]).astype(np.float64)[..., 4:]  # left border 4
    white = 2 * np.mean((x[:, 0] - 2 * x[:, 1] + x[:, 2]) ** 2) / 6 / LAB["geometry"][
        "pixel_rate"]
    (row,) = a[(a["name"] == "pixels[0]") & (a["parameter"] == "alpha")]
    assert abs(row["value"] - white) < 3 * row["error"]
    # the per-pixel terms need the gain (ADU darks): marked in one line, not fitted
    assert any(m.startswith("per-pixel terms: not fitted") for m in a.meta["marks"])
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
    per term that the pixel populations are left out of the search (the forecast refused
    them); BEST.yaml carries them."""
    truth = {**SCENE, "readout": {**SCENE["readout"], "nframes": 12},
             "scene": {"dark_current": 5.0, "hot_pixel_fraction": 0.03,
                       "hot_pixel_current": 500.0, "population_seed": 4,
                       "rtn": {"fraction": 0.05, "amplitude": 300.0, "rate": 2.0}}}
    darks = _darks(tmp_path, 3, truth)
    model = tmp_path / "model.yaml"
    assert run("-q", "characterize", *darks, "-c", "unchop", "-o", model) == 0
    fitted = yaml.safe_load(model.read_text())
    assert fitted["unit"] == "electron"
    assert fitted["scene"]["hot_pixel_fraction"] > 0.01 and "rtn" in fitted["scene"]
    capsys.readouterr()
    assert run("design-readout", _design(tmp_path, model), "-o", tmp_path / "best.yaml") == 0
    out = capsys.readouterr().out
    assert "note: scene.hot_pixel_fraction: hot pixels left out of the search" in out
    assert "note: scene.rtn: telegraph pixels left out of the search" in out
    best = yaml.safe_load((tmp_path / "best.yaml").read_text())["scene"]
    assert best == fitted["scene"]  # carried into BEST.yaml as MODEL.yaml has them


def test_design_readout_from_a_model_in_adu_needs_its_gain(tmp_path, capsys):
    """ADU darks (simulated from a scene in adu) without a gain: MODEL.yaml says unit: adu;
    design-readout, which works in electrons, refuses it in one line naming the gain, and
    takes it once gain: is added (simulate takes it as it is, in adu)."""
    truth = {**SCENE, "unit": "adu", "gain": 2.0}
    darks = _darks(tmp_path, 3, truth)
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


def test_check_refuses_darks_in_another_unit_or_already_fitted(tmp_path, capsys):
    """Held-out darks in adu against a model of darks in electrons were compared as they
    were (slope-scatter ratios exactly half); a dark the model was fitted to was taken as
    held out.  Both exit 2 in one line."""
    from astropy.io import fits

    truth = {**SCENE, "readout": {**SCENE["readout"], "nframes": 6}}
    darks = _darks(tmp_path, 3, truth)
    adu = tmp_path / "dark_adu.fits"
    with fits.open(darks[2]) as hdul:
        for hdu in hdul:
            if hdu.header.get("BUNIT") == "electron":
                hdu.header["BUNIT"] = "adu"
        hdul.writeto(adu, checksum=True)
    model = tmp_path / "model.yaml"
    capsys.readouterr()
    assert run("-q", "characterize", *darks[:2], "-c", "unchop", "-o", model, "--check",
               adu, "--no-scatter") == 2
    one_line_error(capsys, "in adu, the model's darks in electron")
    assert run("-q", "characterize", *darks[:2], "-c", "unchop", "-o", model, "--check",
               darks[0], "--no-scatter", "--overwrite") == 2
    one_line_error(capsys, "a dark the model was fitted to")
