"""``spherex-reduce fit-noise`` on the inputs ``reduce`` takes: one file per read, 4-D files.

A small lab ramp (64 x 64 pixels, 2 channels, a 4-pixel reference border, 40
reads in row order, no phantom: fewer rows give too short a band of
frequencies to tell the white level from the 1/f terms) holds white noise of a known sigma in every
pixel: the fitted white level of the pixel-rate process is then ``2 sigma² /
pixel_rate`` (one-sided), whatever the averaging and decimation of the
streams.  The light-sensitive pixels also carry a dark ramp, which no stream
may see.
"""

import hashlib

import numpy as np
import pytest
from _configs import write_config
from astropy import units as u
from astropy.io import fits
from astropy.table import Table

from spherex_reduce.cli import main

SIGMA, FS, NREADS = 3.0, 1e5, 40
N = 64
GEOMETRY = {"nrows": N, "ncols": N, "nchannels": 2, "ref_border": 4, "pixel_rate": FS}
READOUT = {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0,
           "nframes": NREADS, "frame_time": 1.0}
#: the one-sided PSD of white noise of variance SIGMA² sampled at FS
ALPHA = 2 * SIGMA**2 / FS


def _ramp(seed):
    """Reads (40, 64, 64) in ADU: white noise in every pixel, a dark ramp in the
    light-sensitive ones (not the 4-pixel border)."""
    rng = np.random.default_rng(seed)
    ramp = 1000.0 + rng.normal(0, SIGMA, (NREADS, N, N))
    ramp[:, 4:-4, 4:-4] += 50.0 * np.arange(NREADS)[:, None, None]
    return ramp.astype(np.float32)


def _image(data, path):
    hdu = fits.PrimaryHDU(data)
    hdu.header["BUNIT"] = "ADU"
    hdu.writeto(path)
    return path


def _reads(ramp, folder):
    folder.mkdir()
    return [_image(frame, folder / f"read_{k + 1}.fits") for k, frame in enumerate(ramp)]


def _config(tmp_path):
    return write_config(tmp_path / "lab.yaml", GEOMETRY, READOUT, ["fit_ramp: {}"])


def _fit(capsys, *argv):
    capsys.readouterr()
    code = main(["-q", "fit-noise", *map(str, argv)])
    return code, capsys.readouterr()


def _same_table(a, b):
    for name in a.colnames:
        if a[name].dtype.kind == "f":
            np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]), name)
        else:
            assert list(a[name]) == list(b[name]), name


def _digest(paths):
    return [hashlib.sha256(p.read_bytes()).hexdigest() for p in paths]


def test_reads_give_the_table_of_the_3d_file_and_the_white_level(tmp_path, capsys):
    ramp = _ramp(1)
    cube = _image(ramp, tmp_path / "lab.fits")
    paths = _reads(ramp, tmp_path / "dark")
    config = _config(tmp_path)
    before = _digest([cube, *paths])
    code, out = _fit(capsys, "--reads", tmp_path / "dark" / "read_*.fits", "-c", config,
                     "-o", tmp_path / "reads.ecsv")
    assert code == 0, out.err
    assert _fit(capsys, cube, "-c", config, "-o", tmp_path / "cube.ecsv")[0] == 0
    reads, one = Table.read(tmp_path / "reads.ecsv"), Table.read(tmp_path / "cube.ecsv")
    _same_table(one, reads)
    assert list(reads["stream"]) == ["reference"]
    assert reads.meta["read_files"] == NREADS and "implausible" not in reads.meta
    assert reads["alpha"].unit == u.adu**2 / u.Hz
    alpha, err = reads["alpha"][0], reads["alpha_err"][0]
    assert abs(alpha - ALPHA) < 4 * err and err < 0.1 * ALPHA, (alpha, err, ALPHA)
    assert _digest([cube, *paths]) == before


def _uncal(path, ramps):
    """A 4-D SCI (integrations, groups, rows, columns) of float32 ADU."""
    sci = fits.ImageHDU(np.stack(ramps), name="SCI")
    sci.header["BUNIT"] = "ADU"
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(path)
    return path


def test_a_4d_file_fits_every_integration_or_the_one_asked_for(tmp_path, capsys):
    ramps = [_ramp(2), _ramp(3)]
    uncal = _uncal(tmp_path / "uncal.fits", ramps)
    second = _image(ramps[1], tmp_path / "second.fits")
    config = _config(tmp_path)
    before = _digest([uncal])
    code, out = _fit(capsys, uncal, "-c", config, "-o", tmp_path / "all.ecsv")
    assert code == 0, out.err
    both = Table.read(tmp_path / "all.ecsv")
    assert both.meta["integrations"] == [0, 1]
    assert _fit(capsys, uncal, "-c", config, "--integration", 1, "-o",
                tmp_path / "one.ecsv")[0] == 0
    assert _fit(capsys, second, "-c", config, "-o", tmp_path / "second.ecsv")[0] == 0
    one = Table.read(tmp_path / "one.ecsv")
    _same_table(Table.read(tmp_path / "second.ecsv"), one)
    assert one.meta["integrations"] == [1]
    # twice the streams: the white level is measured with ~1/sqrt(2) of one's error
    alpha, err = both["alpha"][0], both["alpha_err"][0]
    assert abs(alpha - ALPHA) < 4 * err, (alpha, err, ALPHA)
    assert 0.6 < err / one["alpha_err"][0] < 0.8
    assert _digest([uncal]) == before


@pytest.mark.parametrize("case", ["no match", "shapes differ", "integration out of range",
                                  "integration of one ramp", "file and reads"])
def test_refusals_are_one_line(tmp_path, capsys, case):
    config = _config(tmp_path)
    ramp = _ramp(4)
    argv = ["-c", config, "-o", tmp_path / "x.ecsv"]
    if case == "no match":
        argv += ["--reads", tmp_path / "none_*.fits"]
        expected = "matches no file"
    elif case == "shapes differ":
        paths = _reads(ramp, tmp_path / "dark")
        paths[3].unlink()
        _image(ramp[3, :, :32], paths[3])  # 32 columns instead of 64
        argv += ["--reads", tmp_path / "dark" / "read_*.fits"]
        expected = "read_4.fits"
    elif case == "integration out of range":
        argv += [_uncal(tmp_path / "uncal.fits", [ramp, ramp]), "--integration", 2]
        expected = "has 2 integrations (0 to 1)"
    elif case == "integration of one ramp":
        argv += [_image(ramp, tmp_path / "lab.fits"), "--integration", 0]
        expected = "is one ramp, not a 4-D file"
    else:
        argv += [_image(ramp, tmp_path / "lab.fits"), "--reads", tmp_path / "r_*.fits"]
        expected = "not both"
    code, out = _fit(capsys, *argv)
    assert code == 2
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("spherex-reduce fit-noise: error:"), out.err
    assert expected in lines[0]
    assert not (tmp_path / "x.ecsv").exists()
