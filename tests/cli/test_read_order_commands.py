"""Explicit read orders on the command line: ``readout`` prints, saves and draws them;
``readout`` and ``reduce`` refuse a bad one in one line with exit status 2."""

import numpy as np
import pytest
from _cli_helpers import digest, one_line_error, run
from astropy.io import fits
from astropy.table import Table

from spherex_reduce.simulation import simulate_to_fits

GEOMETRY = "geometry: {nrows: 16, ncols: 16, nchannels: 2, ref_border: {top: 2, bottom: 2}}\n"
ORDER = [0, 2, 10, 6, 13, 4, 8, 15, 1, 12, 3, 11, 7, 5, 9, 14, 0]  # rows 0 1 14 15: reference


def test_readout_prints_saves_and_draws_an_explicit_order(tmp_path, capsys):
    cfg = tmp_path / "scene.yaml"
    cfg.write_text(GEOMETRY + f"readout: {{order: {ORDER}, frame_time: 0.5}}\n")
    out, png = tmp_path / "s.ecsv", tmp_path / "order.png"
    assert run("readout", "--config", cfg, "-o", out, "--plot", png) == 0
    text = capsys.readouterr().out
    assert "explicit order, c=4: 17 reads/frame (5 reference)" in text
    t = Table.read(out)
    assert t["row"].tolist() == ORDER
    assert [i for i, k in enumerate(t["kind"]) if k == "reference"] == [0, 7, 8, 15, 16]
    assert png.read_bytes()[:4] == b"\x89PNG"
    rows = tmp_path / "rows.ecsv"  # the same order as a file, given on the command line
    Table({"row": ORDER}).write(rows, format="ascii.ecsv")
    bare = tmp_path / "bare.yaml"
    bare.write_text(GEOMETRY + "readout: {frame_time: 0.5}\n")
    assert run("readout", "--config", bare, "--order", rows, "-o", out, "--overwrite") == 0
    assert Table.read(out)["row"].tolist() == ORDER


@pytest.mark.parametrize(("readout", "words"), [
    ("{order: [0, 2, 3]}", ["geometry/readout: order misses 10 active row(s), the first 4"]),
    ("{order: [2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 13]}",
     ["order reads active row 13 twice (entries 11 and 12)"]),
    ("{order: [16]}", ["order entry 0 is row 16, outside the array's rows 0 to 15"]),
    ("{order: [1.5]}", ["order entry 0 must be an integer row index, got 1.5"]),
    ("{order: []}", ["order is empty"]),
    ("{order: nosuch.ecsv}", ["order file 'nosuch.ecsv'", "No such file"]),
    (f"{{order: {ORDER}, skip: 24}}", ["readout: order gives the read order, so skip cannot"]),
])
def test_bad_orders_are_refused_in_one_line(tmp_path, capsys, monkeypatch, readout, words):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "scene.yaml"
    cfg.write_text(GEOMETRY + f"readout: {readout}\n")
    assert run("readout", "--config", cfg) == 2
    assert one_line_error(capsys, "spherex-reduce readout: error:", *words)


def test_reduce_refuses_a_bad_order_in_one_line_and_keeps_its_input(tmp_path, capsys):
    scene = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 2,
                          "ref_border": {"top": 2, "bottom": 2}},
             "readout": {"order": ORDER, "frame_time": 0.5, "nframes": 3},
             "noise": {"components": []}, "output": {"mode": "ramps"}}
    good = simulate_to_fits(scene, tmp_path / "good.fits", seed=1)
    assert run("reduce", good, "-c", "unchop", "-o", tmp_path / "out.fits") == 0
    capsys.readouterr()
    with fits.open(good) as hdul:  # the READOUT table reads an active row twice
        rows = np.array(hdul["READOUT"].data["row"])
        rows[2] = rows[1]
        hdul["READOUT"].data["row"] = rows
        hdul.writeto(tmp_path / "bad.fits", checksum=True)
    bad = tmp_path / "bad.fits"
    before = digest(bad)
    assert run("reduce", bad, "-c", "unchop", "-o", tmp_path / "bad-out.fits") == 2
    one_line_error(capsys, "spherex-reduce reduce: error:", "order reads active row 2 twice")
    assert digest(bad) == before and not (tmp_path / "bad-out.fits").exists()
    lab = tmp_path / "lab.fits"  # no readout keywords: the config's order, a bad one
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.zeros((3, 17, 16)), name="SCI")]
                 ).writeto(lab)
    cfg = tmp_path / "pipe.yaml"
    cfg.write_text("input: {unit: adu}\n" + GEOMETRY.replace("}\n", ", pixel_rate: 100000.0}\n")
                   + "readout: {order: [0, 2], frame_time: "
                   "0.5, nframes: 3, phantom_reads: 0}\nsteps: [unchop]\n")
    assert run("reduce", lab, "-c", cfg, "-o", tmp_path / "lab-out.fits") == 2
    one_line_error(capsys, "spherex-reduce reduce: error:",
                   "order misses 11 active row(s), the first 3")
