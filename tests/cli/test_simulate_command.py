"""``spherex-reduce simulate`` and the streamed FITS writer."""

import numpy as np
import pytest
from astropy.io import fits

from spherex_reduce import read, simulate
from spherex_reduce.cli import main
from spherex_reduce.simulation import simulate_to_fits

SCENE = """\
geometry: {nrows: 32, ncols: 64, nchannels: 4, ref_border: 2, scan: alternate}
readout: {skip: 5, ref_reads: 4, phantom_reads: 2, nframes: 4, frame_overhead: 100}
scene: {photocurrent: 1.0, leakage: 3.0}
output: {mode: ramps}
seed: 42
"""


@pytest.fixture
def scene_file(tmp_path):
    f = tmp_path / "scene.yaml"
    f.write_text(SCENE)
    return f


def test_cli_ramps_streamed_equals_in_memory(scene_file, tmp_path, capsys):
    out = tmp_path / "raw.fits"
    assert main(["-q", "simulate", str(scene_file), "-o", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    with fits.open(out, checksum=True) as hdul:  # a bad checksum would warn (= error)
        assert [h.name for h in hdul] == ["PRIMARY", "SCI", "PHANTOM", "READOUT"]
        assert "CHECKSUM" in hdul["SCI"].header and hdul[0].header["SIMSEED"] == "42"
    e = read(out)
    mem = simulate(str(scene_file))
    np.testing.assert_array_equal(e.data.data, mem.data.data)
    np.testing.assert_array_equal(e.phantom, mem.phantom)
    assert e.schedule == mem.schedule and e.is_ramp


def test_cli_refuses_existing_output_then_overwrites(scene_file, tmp_path, capsys):
    out = tmp_path / "s.fits"
    out.write_text("keep me")
    assert main(["-q", "simulate", str(scene_file), "-o", str(out), "--mode", "slopes"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "keep me"
    assert main(["-q", "simulate", str(scene_file), "-o", str(out), "--mode", "slopes",
                 "--seed", "3", "--overwrite"]) == 0
    e = read(out)
    assert not e.is_ramp and e.unit.to_string() == "electron / s"
    assert e.header["SIMSEED"] == "3"


def test_cli_bad_scene_names_the_path(tmp_path, capsys):
    f = tmp_path / "bad.yaml"
    f.write_text("noise: {components: [video8, {name: x, beta: -2}]}\n")
    assert main(["simulate", str(f), "-o", str(tmp_path / "x.fits")]) == 2
    assert "noise.components[1].beta" in capsys.readouterr().err


def test_simulate_to_fits_slopes_and_nothing_left_on_error(scene_file, tmp_path):
    out = simulate_to_fits(str(scene_file), tmp_path / "a.fits", mode="slopes")
    assert read(out).shape == (32, 64)
    with pytest.raises(ValueError):
        simulate_to_fits(str(scene_file), tmp_path / "b.fits", mode="cube")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.fits", "scene.yaml"]


def test_no_progress_bar_is_written_to_a_stderr_that_is_not_a_terminal(scene_file, tmp_path,
                                                                        capsys):
    """Without -q the frames' bar is shown on a terminal only: redirected, stderr stays
    empty (tqdm wrote its cursor codes into logs)."""
    assert main(["simulate", str(scene_file), "-o", str(tmp_path / "raw.fits")]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and "wrote" in captured.out
