"""One file per read: ``spherex-reduce reduce --reads 'DIR/read_*.fits'``.

Each ramp is built here from small arrays, as a lab whose electronics write
one 2-D image per read would store it (no ``READOUT`` table, the readout
parameters from the pipeline config).  Slopes are checked against numpy's
least squares over the frames in natural order, and against reducing the same
ramp written as one 3-D file.
"""

import hashlib
import os

import numpy as np
import pytest
from _configs import write_config
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce.cli import main
from spherex_reduce.core.errors import FormatError
from spherex_reduce.io.readers.read_files import ReadFiles, read_file_paths
from spherex_reduce.io.sources import FileSource
from spherex_reduce.reduce import executor

GEOMETRY = {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 2, "pixel_rate": 1e5}
#: chopped, with re-read reference rows: reads in a mixed order
READOUT = {"skip": 4, "ref_reads": 8, "ref_mode": "repeated", "phantom_reads": 0,
           "nframes": 3, "frame_time": 2.0}
#: the numbers in the file names: natural order differs from lexicographic (1, 10, 2, ...)
NUMBERS = [1, 2, 3, 5, 9, 10]
LEXICOGRAPHIC = sorted(range(len(NUMBERS)), key=lambda k: f"read_{NUMBERS[k]}.fits")


def _schedule(**readout):
    return sr.ReadoutSchedule(sr.DetectorGeometry(32, 16, 2, ref_border=2, pixel_rate=1e5),
                              **{**READOUT, "nframes": len(NUMBERS), **readout})


def _ramps(schedule, seed=7):
    """Ramps (frames, reads, columns) with a different rate in every pixel, float32."""
    rng = np.random.default_rng(seed)
    k = np.arange(schedule.nframes)[:, None, None]
    rate = rng.uniform(1, 5, (1, schedule.n_reads, 16))
    noise = rng.normal(0, 0.5, (schedule.nframes, schedule.n_reads, 16))
    return (100 + rate * k * 2.0 + noise).astype(np.float32)


def _lstsq(ramps, tframe=2.0):
    """Least-squares slope of every pixel over the frames (numpy, float64)."""
    n = ramps.shape[0]
    design = np.vstack([np.arange(n) * tframe, np.ones(n)]).T
    coef = np.linalg.lstsq(design, ramps.reshape(n, -1).astype(np.float64), rcond=None)[0]
    return coef[0].reshape(ramps.shape[1:])


def _config(path, steps, **readout):
    return write_config(path, GEOMETRY, {**READOUT, **readout}, steps)


def _write_reads(directory, ramps, header=None):
    """Frame ``k`` of ``ramps`` into ``directory/read_{NUMBERS[k]}.fits``; the paths."""
    directory.mkdir(exist_ok=True)
    paths = []
    for k, frame in enumerate(ramps):
        path = directory / f"read_{NUMBERS[k]}.fits"
        fits.PrimaryHDU(frame, header).writeto(path, checksum=True)
        paths.append(path)
    return paths


def _digests(paths):
    return [hashlib.sha256(p.read_bytes()).hexdigest() for p in paths]


FIT = ["fit_ramp: {weighting: uniform}"]
FULL = ["unchop: {}", "correct_reference: {strategy: mean}", "fit_ramp: {weighting: uniform}"]


def test_natural_order_of_the_files(tmp_path):
    paths = _write_reads(tmp_path / "r", _ramps(_schedule()))
    found = read_file_paths(str(tmp_path / "r" / "read_*.fits"))
    assert found == [str(p) for p in paths]
    assert [int(p.split("_")[-1][:-5]) for p in found] == NUMBERS


def test_slopes_are_least_squares_over_the_reads_in_natural_order(tmp_path):
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    before = _digests(paths)
    cfg = _config(tmp_path / "fit.yaml", FIT)
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                 str(cfg), "-o", str(out)]) == 0
    assert _digests(paths) == before
    with fits.open(out) as hdul:
        slopes = hdul["SCI"].data
        assert hdul[0].header["NFRAMES"] == len(NUMBERS)
    expected = _lstsq(sci)
    np.testing.assert_allclose(slopes, expected, rtol=1e-6, atol=1e-6)
    wrong = _lstsq(sci[LEXICOGRAPHIC])  # the files in the order 1, 10, 2, 3, 5, 9
    assert np.abs(slopes - wrong).max() > 0.1


@pytest.mark.parametrize("stored", ["float32", "uint16"])
def test_same_result_as_the_ramp_in_one_3d_file(tmp_path, stored):
    """Streamed from the read files, the reduction equals that of the 3-D file, bit for bit
    (unsigned integer files, stored with BZERO = 32768, are scaled on read as a 3-D file is)."""
    s = _schedule()
    sci = _ramps(s)
    if stored == "uint16":
        sci = (np.round(sci * 10) + 30000).astype(np.uint16)  # beyond int16
    paths = _write_reads(tmp_path / "r", sci)
    if stored == "uint16":
        assert fits.getheader(paths[0])["BZERO"] == 32768
    cube = fits.PrimaryHDU(sci)
    cube.writeto(tmp_path / "cube.fits", checksum=True)
    before = _digests(paths)
    cfg = _config(tmp_path / "full.yaml", FULL, nframes=len(NUMBERS))
    pipeline = sr.Pipeline.from_yaml(cfg)
    one = pipeline.run(tmp_path / "cube.fits")
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                 str(cfg), "-o", str(out)]) == 0
    assert _digests(paths) == before
    with fits.open(out) as hdul:
        np.testing.assert_array_equal(hdul["SCI"].data, one.data.data.astype(np.float32))
        assert hdul[0].header["S_REFCOR"] == "COMPLETE"
    assert np.isfinite(one.data.data[GEOMETRY["ref_border"]:-2, 2:-2]).all()


def test_the_files_are_read_in_bands_never_whole(tmp_path, monkeypatch):
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    asked, rows = [], []
    original_read, original_rows = FileSource.read, ReadFiles.frame_rows
    monkeypatch.setattr(FileSource, "read", lambda self, lo, hi: (asked.append((lo, hi)),
                                                                  original_read(self, lo, hi))[1])
    monkeypatch.setattr(ReadFiles, "frame_rows", lambda self, k, a, b: (
        rows.append(b - a), original_rows(self, k, a, b))[1])
    monkeypatch.setattr(ReadFiles, "exposure", lambda self: pytest.fail("read whole"))
    monkeypatch.setattr(executor, "BAND_PIXELS", 5 * GEOMETRY["ncols"])
    cfg = _config(tmp_path / "full.yaml", FULL, nframes=len(NUMBERS))
    out = sr.Pipeline.from_yaml(cfg)
    with ReadFiles(paths, **out.supplied()) as reader:
        result = out.run(reader, threads=2)
    covered = sorted(r for lo, hi in asked for r in range(lo, hi))
    assert covered == list(range(s.n_reads))  # every read once
    assert max(hi - lo for lo, hi in asked) == 5
    assert max(rows) < s.n_reads  # no file is ever read whole
    assert result.header["S_RAMPFT"] == "COMPLETE"
    one = sr.Pipeline.from_yaml(cfg).run(_one_file(tmp_path, sci))
    np.testing.assert_array_equal(result.data.data, one.data.data)


def _one_file(tmp_path, sci):
    path = tmp_path / "cube.fits"
    fits.PrimaryHDU(sci).writeto(path)
    return path


def test_physical_order_files_are_reduced_in_memory(tmp_path):
    """Files in physical order (ORDER = PHYSICAL) give the slopes of the same 3-D file."""
    s = _schedule(ref_mode="none")
    raw = _ramps(s)
    physical = np.empty((s.nframes, 32, 16), np.float32)
    physical[:, s.rows] = raw
    header = fits.Header({"ORDER": "PHYSICAL"})
    paths = _write_reads(tmp_path / "r", physical, header)
    cfg = _config(tmp_path / "fit.yaml", FIT, ref_mode="none")
    with ReadFiles(paths, **sr.Pipeline.from_yaml(cfg).supplied()) as reader:
        assert not reader.readable_in_bands()
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                 str(cfg), "-o", str(out)]) == 0
    np.testing.assert_allclose(fits.getdata(out, "SCI"), _lstsq(physical), rtol=1e-6,
                               atol=1e-6)


def test_a_first_step_on_the_whole_ramp_reads_it_into_memory(tmp_path):
    """A first step that needs the whole ramp (the median reference strategy) gets it in
    memory."""
    s = _schedule()
    sci = _ramps(s)
    _write_reads(tmp_path / "r", sci)
    cfg = _config(tmp_path / "median.yaml", ["correct_reference: {strategy: median}", *FIT],
                  nframes=len(NUMBERS))
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                 str(cfg), "-o", str(out)]) == 0
    one = sr.Pipeline.from_yaml(cfg).run(_one_file(tmp_path, sci))
    np.testing.assert_array_equal(fits.getdata(out, "SCI"), one.data.data.astype(np.float32))


def test_files_that_disagree_are_refused(tmp_path):
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    supplied = {**GEOMETRY, **READOUT}
    fits.PrimaryHDU(sci[0].astype(np.float64)).writeto(paths[3], overwrite=True)
    with pytest.raises(FormatError, match=r"BITPIX is -64, but .*read_1\.fits has -32"):
        ReadFiles(paths, **supplied)
    fits.PrimaryHDU(sci[0], fits.Header({"BUNIT": "adu"})).writeto(paths[3], overwrite=True)
    with pytest.raises(FormatError, match="unit"):
        ReadFiles(paths, **supplied)
    fits.PrimaryHDU(sci[:2]).writeto(paths[3], overwrite=True)
    with pytest.raises(FormatError, match="one 2-D image"):
        ReadFiles(paths, **supplied)
    with pytest.raises(FormatError, match="two files"):
        ReadFiles(paths[:1], **supplied)


def test_gzipped_files_are_read_by_sections_with_the_same_result(tmp_path):
    """Files astropy unpacks (gzip) are read by sections: the same slopes as plain files."""
    s = _schedule()
    sci = _ramps(s)
    plain = _write_reads(tmp_path / "p", sci)
    (tmp_path / "z").mkdir()
    for path in plain:
        fits.PrimaryHDU(fits.getdata(path)).writeto(tmp_path / "z" / (path.name + ".gz"))
    cfg = _config(tmp_path / "full.yaml", FULL)
    for d in ("p", "z"):
        assert main(["-q", "reduce", "--reads", str(tmp_path / d / "read_*.fits*"), "-c",
                     str(cfg), "-o", str(tmp_path / f"{d}.fits")]) == 0
    np.testing.assert_array_equal(fits.getdata(tmp_path / "z.fits", "SCI"),
                                  fits.getdata(tmp_path / "p.fits", "SCI"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="counts /proc/self/fd")
def test_one_descriptor_per_plain_file_while_open(tmp_path):
    """A ramp of many reads must not run out of file descriptors: one per plain file."""
    paths = _write_reads(tmp_path / "r", _ramps(_schedule()))
    before = len(os.listdir("/proc/self/fd"))
    with ReadFiles(paths, **GEOMETRY, **READOUT):
        assert len(os.listdir("/proc/self/fd")) - before == len(paths)
    assert len(os.listdir("/proc/self/fd")) == before


@pytest.mark.parametrize("bits", [None, 4])
def test_a_read_file_carries_its_own_dq(tmp_path, bits):
    """A DQ extension in a read file flags that read's pixels: the flagged read is left out
    of each pixel's fit (numpy least squares over the other reads), by default for any
    bit; with ``dq_bits`` only for those bits.  The files are not changed."""
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    flags = np.zeros(sci.shape[1:], np.uint32)
    flags[5, 3] = 4  # read 2 of pixel (5, 3): a bit the default and dq_bits 4 both mask
    flags[7, 9] = 2  # masked by default only
    with fits.open(paths[2]) as hdul:
        fits.HDUList([hdul[0].copy(), fits.ImageHDU(flags, name="DQ")]).writeto(
            paths[2], overwrite=True, checksum=True)
    before = _digests(paths)
    cfg = _config(tmp_path / "fit.yaml", FIT)
    out = tmp_path / "out.fits"
    dq_bits = [] if bits is None else ["--dq-bits", str(bits)]
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                 str(cfg), "-o", str(out), *dq_bits]) == 0
    assert _digests(paths) == before
    slopes = fits.getdata(out, "SCI")
    expected = _lstsq(sci)
    others = np.delete(np.arange(len(NUMBERS)), 2)
    design = np.vstack([others * 2.0, np.ones(others.size)]).T
    for r, c in ((5, 3), (7, 9)):
        without = np.linalg.lstsq(design, sci[others, r, c].astype(np.float64), rcond=None)[0][0]
        expected[r, c] = without if (bits is None or flags[r, c] & bits) else expected[r, c]
    np.testing.assert_allclose(slopes, expected, rtol=1e-6, atol=1e-6)
    assert fits.getheader(out)["SXRDQBIT"] == (2**32 - 1 if bits is None else bits)


@pytest.mark.parametrize("planes", [2, 3])
def test_one_mask_file_flags_the_reads(tmp_path, planes):
    """``--reads-dq MASK.fits``: a 2-D mask leaves its pixels out of every read (their slope
    NaN: no read to fit), a 3-D one flags pixel (r, c) of read k where plane k does: that
    read is left out of the pixel's fit (numpy least squares over the others).  The files
    and the mask are not changed."""
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    flags = np.zeros((len(NUMBERS), *sci.shape[1:]), np.int16)
    flags[2, 5, 3] = 1  # read 2 of pixel (5, 3)
    flags[:, 7, 9] = 8  # every read of pixel (7, 9)
    mask = tmp_path / "mask.fits"
    fits.PrimaryHDU(flags if planes == 3 else flags[2]).writeto(mask, checksum=True)
    before = _digests([*paths, mask])
    cfg = _config(tmp_path / "fit.yaml", FIT)
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "--reads-dq",
                 str(mask), "-c", str(cfg), "-o", str(out)]) == 0
    assert _digests([*paths, mask]) == before
    slopes = fits.getdata(out, "SCI")
    expected = _lstsq(sci)
    if planes == 3:
        others = np.delete(np.arange(len(NUMBERS)), 2)
        design = np.vstack([others * 2.0, np.ones(others.size)]).T
        expected[5, 3] = np.linalg.lstsq(design, sci[others, 5, 3].astype(np.float64),
                                         rcond=None)[0][0]
    else:  # the 2-D mask flags (5, 3) and (7, 9) in every read
        expected[5, 3] = np.nan
    expected[7, 9] = np.nan
    np.testing.assert_allclose(slopes, expected, rtol=1e-6, atol=1e-6)
    assert "mask.fits" in str(fits.getheader(out)["HISTORY"])


def test_a_mask_file_of_another_shape_is_refused(tmp_path, capsys):
    sci = _ramps(_schedule())
    paths = _write_reads(tmp_path / "r", sci)
    mask = tmp_path / "mask.fits"
    fits.PrimaryHDU(np.zeros((len(NUMBERS) - 1, *sci.shape[1:]), np.int16)).writeto(mask)
    cfg = _config(tmp_path / "fit.yaml", FIT)
    out = tmp_path / "out.fits"
    args = ["reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c", str(cfg), "-o",
            str(out)]
    assert main([*args, "--reads-dq", str(mask)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("spherex-reduce reduce: error: ")
    image = sci.shape[1:]  # a read's image: its reads (rows read) x columns
    assert (f"the mask has shape {(len(NUMBERS) - 1, *image)}; expected {image} (one mask for "
            f"every read) or {(len(NUMBERS), *image)}") in err
    assert not out.exists() and len(paths) == len(NUMBERS)
    fits.PrimaryHDU(np.zeros(image, np.float32)).writeto(mask, overwrite=True)
    assert main([*args, "--reads-dq", str(mask)]) == 2  # flags are integers
    assert ("mask.fits: HDU 'PRIMARY' holds flags, which must be integers; it holds "
            "floating-point numbers (BITPIX = -32)") in capsys.readouterr().err
    assert main(["reduce", str(paths[0]), "--reads-dq", str(mask), "-c", str(cfg), "-o",
                 str(out)]) == 2
    assert "give --reads too" in capsys.readouterr().err
    table = fits.BinTableHDU.from_columns([fits.Column("dq", "J", array=[0])], name="DQ")
    fits.HDUList([fits.PrimaryHDU(), table]).writeto(mask, overwrite=True)
    assert main([*args, "--reads-dq", str(mask)]) == 2  # a table named DQ: not a mask
    assert "holds the flags as a DQ extension or in its primary HDU" in capsys.readouterr().err


def _read_dq(path, flags):
    """``path`` rewritten with ``flags`` as its DQ extension."""
    with fits.open(path) as hdul:
        fits.HDUList([hdul[0].copy(), fits.ImageHDU(flags, name="DQ")]).writeto(
            path, overwrite=True, checksum=True)


def test_a_float_dq_in_a_read_file_is_refused_in_one_line(tmp_path, capsys):
    """A read file's DQ stored as float (0.5 on the bad pixel): refused in one line naming the
    file, with ``--reads-dq`` or without (it was a TypeError, exit 1, with a mask file, and
    fitted as unflagged without one); the files are not changed."""
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    flags = np.zeros(sci.shape[1:], np.float32)
    flags[5, 3] = 0.5
    _read_dq(paths[2], flags)
    mask = tmp_path / "mask.fits"
    fits.PrimaryHDU(np.zeros(sci.shape[1:], np.int16)).writeto(mask)
    before = _digests([*paths, mask])
    cfg = _config(tmp_path / "fit.yaml", FIT)
    out = tmp_path / "out.fits"
    args = ["reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c", str(cfg), "-o",
            str(out)]
    for more in (["--reads-dq", str(mask)], []):
        assert main([*args, *more]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and err.startswith("spherex-reduce reduce: error: "), err
        assert ("read_3.fits: HDU 'DQ' holds flags, which must be integers; it holds "
                "floating-point numbers (BITPIX = -32)") in err
    assert not out.exists() and _digests([*paths, mask]) == before


def test_read_file_flags_keep_their_own_bits(tmp_path):
    """An int16 DQ's -32768 is its bit 15 alone: with ``--dq-bits`` 0x10000 (bit 16) it masks
    nothing (it was sign-extended to bits 15-63, and masked); with 0x8000 it masks that
    read, whose pixel is then fitted over the others (numpy least squares)."""
    s = _schedule()
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    flags = np.zeros(sci.shape[1:], np.int16)
    flags[5, 3] = -32768
    _read_dq(paths[2], flags)
    cfg = _config(tmp_path / "fit.yaml", FIT)
    expected = _lstsq(sci)
    for bits in ("0x10000", "0x8000"):
        out = tmp_path / f"out{bits}.fits"
        assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                     str(cfg), "-o", str(out), "--dq-bits", bits]) == 0
        if bits == "0x8000":
            others = np.delete(np.arange(len(NUMBERS)), 2)
            design = np.vstack([others * 2.0, np.ones(others.size)]).T
            expected[5, 3] = np.linalg.lstsq(design, sci[others, 5, 3].astype(np.float64),
                                             rcond=None)[0][0]
        np.testing.assert_allclose(fits.getdata(out, "SCI"), expected, rtol=1e-6, atol=1e-6)


def test_the_declared_frame_time_is_kept_not_rounded_to_whole_samples(tmp_path):
    """Issue 31: one file per read rounded the frame time to whole samples (0.277815 s,
    27781.5 samples at 100 kHz, became 0.27781 s): slopes 1.8e-5 too high.  The slopes
    of the read files equal numpy's with the declared frame time, as the 3-D file's do."""
    tframe = 0.277815
    s = _schedule(frame_time=tframe)
    sci = _ramps(s)
    paths = _write_reads(tmp_path / "r", sci)
    fits.PrimaryHDU(sci).writeto(tmp_path / "cube.fits")
    cfg = _config(tmp_path / "fit.yaml", FIT, frame_time=tframe, nframes=len(paths))
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c",
                 str(cfg), "-o", str(out)]) == 0
    expected = _lstsq(sci, tframe)
    one = sr.Pipeline.from_yaml(cfg).run(tmp_path / "cube.fits")
    np.testing.assert_allclose(one.data.data, expected, rtol=1e-6)  # float32 sums
    with fits.open(out) as hdul:
        assert hdul[0].header["TFRAME"] == tframe
        slopes = hdul["SCI"].data
        np.testing.assert_allclose(slopes, expected, rtol=1e-6)
        np.testing.assert_array_equal(slopes, one.data.data.astype(slopes.dtype))
