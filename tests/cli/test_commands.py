"""The command line: subcommands, outputs, exit codes and messages."""

import subprocess
import sys

import numpy as np
import pytest
from _cli_helpers import run
from astropy.table import Table

import spherex_reduce
from spherex_reduce import read, write
from spherex_reduce.io.examples import example_raw_exposure


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as info:
        run("--version")
    assert info.value.code == 0
    assert spherex_reduce.__version__ in capsys.readouterr().out
    with pytest.raises(SystemExit):
        run("--help")
    out = capsys.readouterr().out
    for command in ("demo", "readout", "reduce", "plugins", "show-config"):
        assert command in out


def test_readout_summary_table_and_plot(tmp_path, capsys):
    out, png = tmp_path / "s.ecsv", tmp_path / "order.png"
    assert run("readout", "-o", out, "--plot", png) == 0
    text = capsys.readouterr().out
    assert "2072 reads/frame" in text and "frame time 1.51 s" in text
    t = Table.read(out)
    assert t.colnames == ["read", "row", "kind", "start", "time"] and len(t) == 2072
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert run("readout", "-o", out) == 2  # exists: refused
    assert "exists" in capsys.readouterr().err
    assert run("readout", "--nrows", 16, "--ncols", 16, "--nchannels", 2, "--ref-border", 2,
               "--skip", 4, "--ref-mode", "none", "-o", out, "--overwrite") == 0
    assert Table.read(out)["row"].tolist() == [0, 1, 2, 6, 10, 3, 7, 11, 4, 8, 12, 5, 9, 13,
                                               14, 15]


def test_readout_from_config(tmp_path, capsys):
    cfg = tmp_path / "scene.yaml"
    cfg.write_text("geometry: {nrows: 64, ncols: 64, nchannels: 4}\nreadout: {skip: 8}\n")
    assert run("readout", "--config", cfg, "--ref-reads", 4) == 0
    assert "S=8, r=4" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["readout", "--skip", "0"], "argument --skip: must be a whole number from 1 to"),
        (["readout", "--ref-mode", "sometimes"], "readout.ref_mode: 'sometimes' is not one of"),
        (["readout", "--ncols", "100"], "nchannels x channel width must equal ncols"),
        (["show-config", "nosuch"], "no pipeline config file 'nosuch'"),
        (["reduce", "missing.fits", "-c", "unchop", "-o", "x.fits"], "no such file"),
    ],
)
def test_input_errors_exit_2_with_one_line(args, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert run(*args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_reduce_and_show_config(tmp_path, capsys, small_schedule):
    raw = example_raw_exposure(small_schedule, seed=2)
    write(raw, tmp_path / "raw.fits")
    cfg = tmp_path / "p.yaml"
    cfg.write_text("steps:\n  - unchop: {}\n")
    assert run("reduce", tmp_path / "raw.fits", "-c", cfg, "-o", tmp_path / "out.fits") == 0
    out = read(tmp_path / "out.fits")
    assert out.order == "physical" and out.header["S_UNCHOP"] == "COMPLETE"
    np.testing.assert_array_equal(out.data.data, spherex_reduce.unchop(raw).data.data)
    assert run("reduce", tmp_path / "raw.fits", "-c", cfg, "-o", tmp_path / "out.fits") == 2
    capsys.readouterr()
    assert run("show-config", cfg) == 0
    text = capsys.readouterr().out
    assert "config hash" in text and "unchop: {}" in text
    assert run("show-config", "--list") == 0
    assert "unchop" in capsys.readouterr().out.split()


@pytest.mark.parametrize("threads", ["1", "3"])
def test_reduce_threads_give_the_same_numbers(tmp_path, capsys, small_schedule, threads,
                                              monkeypatch):
    from spherex_reduce.reduce import executor

    monkeypatch.setattr(executor, "BAND_PIXELS", 4 * 16)  # several bands of 4 rows
    raw = example_raw_exposure(small_schedule, seed=7)
    write(raw, tmp_path / "raw.fits")
    out = tmp_path / f"out{threads}.fits"
    assert run("reduce", tmp_path / "raw.fits", "-c", "spherex-default", "-o", out,
               "--threads", threads) == 0
    reduced = read(out)
    by_hand = spherex_reduce.sigma_clip(spherex_reduce.fit_ramp(
        spherex_reduce.correct_reference(spherex_reduce.subtract_phantom(
            spherex_reduce.unchop(read(tmp_path / "raw.fits"))))))  # as stored: float32
    np.testing.assert_array_equal(reduced.data.data, by_hand.data.data.astype(np.float32))
    assert f"on {threads} thread(s)" in reduced.tables["PROVENANCE"]["route"][0]
    capsys.readouterr()
    assert run("reduce", tmp_path / "raw.fits", "-c", "spherex-default", "-o",
               tmp_path / "x.fits", "--threads", "0") == 2
    assert "--threads" in capsys.readouterr().err


def test_plugins_lists_providers(capsys):
    assert run("plugins") == 0
    out = capsys.readouterr().out
    assert any(line.split()[:5] == ["step", "unchop", "S_UNCHOP", "builtin.unchop",
                                    "spherex-reduce"]
               for line in out.splitlines())


def test_demo_runs_and_refuses_to_overwrite(tmp_path, capsys):
    from spherex_reduce.analysis.figures.demo import PRODUCTS, RAW_PRODUCTS

    assert run("-q", "demo", "-o", tmp_path / "d", "--size", 128, "--nframes", 6,
               "--keep-raw") == 0
    out = capsys.readouterr().out
    # the nominal band; the θ the k limits give on 6.2″ pixels only in the table's meta
    assert "band power 5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel)" in out and "4.99" not in out
    assert "photon noise of 1 e/s" in out
    assert {p.name for p in (tmp_path / "d").iterdir()} == {*PRODUCTS, *RAW_PRODUCTS}
    raw = read(tmp_path / "d" / "raw_chopped.fits")
    assert raw.schedule.skip == 24 and raw.is_ramp and raw.schedule.nframes == 6
    reduced = read(tmp_path / "d" / "reduced_chopped.fits")
    assert reduced.header["S_REFCOR"] == "COMPLETE" and reduced.order == "physical"
    spectra = Table.read(tmp_path / "d" / "spectra.ecsv")
    assert all(spectra[c].description for c in spectra.colnames)  # "what is power_err?"
    assert "standard error" in spectra["power_err_chopped"].description
    assert {"k", "theta", "power_chopped", "power_unchopped"} <= set(spectra.colnames)
    assert spectra.meta["band"] == "5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel)"
    assert spectra.meta["band_theta_exact"] == "θ = 4.99–21.6′ for 6.2″ pixels"
    assert run("demo", "-o", tmp_path / "d", "--size", 128) == 2
    assert "exists" in capsys.readouterr().err
    assert run("demo", "-o", tmp_path / "e", "--size", 100) == 2
    assert "multiple of 64" in capsys.readouterr().err


def test_console_script_unexpected_and_usage(tmp_path):
    """The installed console script: usage errors exit 2, no traceback."""
    exe = [sys.executable, "-m", "spherex_reduce.cli"]
    r = subprocess.run([*exe, "readout", "--skip", "x"], capture_output=True, text=True)
    assert r.returncode == 2 and "argument --skip: not a number: 'x'" in r.stderr
    r = subprocess.run([*exe, "reduce", str(tmp_path / "none.fits"), "-c", "unchop", "-o",
                        str(tmp_path / "o.fits")], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_demo_removes_its_raw_files_unless_asked(tmp_path, capsys):
    """The README promises FITS images, a table and plots: the raw ramps (2 x 1.28 GB at
    full size) are simulated into the directory and removed once reduced."""
    from spherex_reduce.analysis.figures.demo import PRODUCTS

    assert run("-q", "demo", "-o", tmp_path / "d", "--size", 64, "--nframes", 3) == 0
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == sorted(PRODUCTS)
    assert "raw_chopped.fits" not in capsys.readouterr().out
