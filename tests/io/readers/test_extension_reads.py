"""A ramp stored as image extensions, one read each (HST WFC3/IR ``_raw``): ``input: reads:
extensions``.

The file is built here from small arrays as HST writes it: ``SCI,1 ... SCI,6``
(``EXTVER``), the latest read first, each with its ``SAMPTIME`` (uneven, as
the SPARS sample sequences), in counts stored as unsigned 16-bit integers
(``BZERO = 32768``), with a ``DQ,i`` per read.  Slopes are checked against
numpy's least squares on the ``SAMPTIME`` values written here.
"""

import hashlib
import re

import numpy as np
import pytest
from _configs import write_config
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce.cli import main
from spherex_reduce.core.errors import FormatError
from spherex_reduce.io.readers.extension_reads import ExtensionReads
from spherex_reduce.io.sources import FileSource

GEOMETRY = {"nrows": 16, "ncols": 16, "nchannels": 4, "ref_border": 0, "pixel_rate": 1e5}
READOUT = {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0,
           "row_overhead": 0, "frame_time": 2.932}
#: SAMPTIME of the zeroth read first: RAPID, then a SPARS10-like gap (s)
TIMES = [0.0, 2.932, 12.933, 22.934, 25.866, 35.867]
#: pixel (row, column) flagged in read 3 (in time order) by its DQ
FLAGGED = (5, 6)
FIT = ["fit_ramp: {weighting: uniform}"]


def _ramps(seed=3):
    """Counts of every read in time order (reads, rows, columns), a rate per pixel."""
    rng = np.random.default_rng(seed)
    rate = rng.uniform(20, 80, (16, 16))
    t = np.array(TIMES)[:, None, None]
    return np.round(1000 + rate * t + rng.normal(0, 3, (len(TIMES), 16, 16)))


def _write(path, ramps, dq=True, change=None):
    """``ramps`` (time order) as SCI,1 ... SCI,n, the latest read first, with DQ,i."""
    hdus = [fits.PrimaryHDU()]
    n = len(ramps)
    for version in range(1, n + 1):
        k = n - version  # SCI,1 is the last read
        sci = fits.ImageHDU(ramps[k].astype(np.uint16), name="SCI", ver=version)
        sci.header["SAMPTIME"] = TIMES[k]
        sci.header["BUNIT"] = "COUNTS"
        flags = np.zeros((16, 16), np.int16)
        if k == 3:
            flags[FLAGGED] = 256  # WFC3: full-well saturation
        hdus += [sci, fits.ImageHDU(flags if dq else None, name="DQ", ver=version)]
    hdul = fits.HDUList(hdus)
    if change is not None:
        change(hdul)
    hdul.writeto(path, checksum=True)
    return path


def _lstsq(ramps, times):
    design = np.vstack([np.asarray(times), np.ones(len(times))]).T
    n = len(times)
    return np.linalg.lstsq(design, ramps.reshape(n, -1), rcond=None)[0][0].reshape(16, 16)


def _config(path, **input):
    write_config(path, GEOMETRY, READOUT, FIT)
    text = "input: {reads: extensions" + "".join(f", {k}: {v}" for k, v in input.items())
    path.write_text(path.read_text() + text + "}\n")
    return path


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_slopes_are_least_squares_on_the_samptimes_without_the_flagged_read(tmp_path):
    ramps = _ramps()
    raw = _write(tmp_path / "x_raw.fits", ramps)
    before = _digest(raw)
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", str(raw), "-c", str(_config(tmp_path / "wfc3.yaml")), "-o",
                 str(out)]) == 0
    assert _digest(raw) == before
    slopes = fits.getdata(out, "SCI")
    expected = _lstsq(ramps, TIMES)
    others = [k for k in range(len(TIMES)) if k != 3]
    r, c = FLAGGED
    expected[r, c] = _lstsq(ramps[others], [TIMES[k] for k in others])[r, c]
    np.testing.assert_allclose(slopes, expected, rtol=2**-23, atol=1e-9)
    even = _lstsq(ramps, np.arange(len(TIMES)) * READOUT["frame_time"])
    assert np.abs(slopes - even).max() > 1  # the reads fitted as if even: far off
    header = fits.getheader(out)
    assert header["NFRAMES"] == len(TIMES)
    assert [float(t) for t in header["RDTIMES"].split(",")] == TIMES


def test_streamed_and_in_memory_are_equal(tmp_path, monkeypatch):
    """Without flags the reads are streamed a band at a time (never read whole), and give
    what `read` then `Pipeline.run` on the exposure give, bit for bit."""
    ramps = _ramps()
    raw = _write(tmp_path / "x_raw.fits", ramps, dq=False)
    pipeline = sr.Pipeline.from_yaml(_config(tmp_path / "wfc3.yaml"))
    exposure = sr.read(raw, input=pipeline.input_options, **pipeline.supplied())
    assert exposure.schedule.read_times == tuple(TIMES)
    np.testing.assert_array_equal(exposure.data.data, ramps)
    in_memory = pipeline.run(exposure)
    bands = []
    original = FileSource.read

    def counted(self, lo, hi):
        bands.append(hi - lo)
        return original(self, lo, hi)

    monkeypatch.setattr(FileSource, "read", counted)
    monkeypatch.setattr(ExtensionReads, "exposure", lambda self: pytest.fail("read whole"))
    streamed = pipeline.run(raw, threads=1)
    assert bands and sum(bands) == 16
    np.testing.assert_array_equal(streamed.data.data, in_memory.data.data)


def test_dq_bits_choose_which_wfc3_flags_mask(tmp_path):
    """``input: dq_bits`` leaves out of the fit only reads flagged with those bits."""
    ramps = _ramps()
    raw = _write(tmp_path / "x_raw.fits", ramps)
    out = tmp_path / "out.fits"
    cfg = _config(tmp_path / "wfc3.yaml", dq_bits=4)  # bad detector pixel only: not 256
    assert main(["-q", "reduce", str(raw), "-c", str(cfg), "-o", str(out)]) == 0
    np.testing.assert_allclose(fits.getdata(out, "SCI"), _lstsq(ramps, TIMES), rtol=2**-23,
                               atol=1e-9)
    assert fits.getheader(out)["SXRDQBIT"] == 4


def _drop_samptime(hdul):
    del hdul["SCI", 2].header["SAMPTIME"]


def _same_samptime(hdul):
    hdul["SCI", 2].header["SAMPTIME"] = hdul["SCI", 3].header["SAMPTIME"]


def _other_shape(hdul):
    hdul["SCI", 4].data = hdul["SCI", 4].data[:8]


def _rate_unit(hdul):
    for h in hdul:
        if h.name == "SCI":
            h.header["BUNIT"] = "ELECTRONS/S"


def _other_unit(hdul):
    hdul["SCI", 5].header["BUNIT"] = "ELECTRONS"


@pytest.mark.parametrize("change, message", [
    (_drop_samptime, r"SCI,2 has no SAMPTIME"),
    (_same_samptime, r"SCI,2 and SCI,3 have the same SAMPTIME 22.934 s: two reads at one"),
    (_other_shape, r"SCI,4 has shape \(8, 16\), SCI,6 \(16, 16\)"),
    (_rate_unit, r"the reads are in 'ELECTRONS/S', a rate .* reduce the _raw file"),
    (_other_unit, r"SCI,5 has BUNIT 'ELECTRONS', SCI,6 'COUNTS'"),
], ids=["no-samptime", "same-samptime", "shapes-differ", "rate-unit", "units-differ"])
def test_refused_in_one_line(tmp_path, capsys, change, message):
    err = _refused(tmp_path, capsys, change)
    assert re.search(message, err), err


def _refused(tmp_path, capsys, change):
    """The one-line error (exit 2) of reducing the ramp ``change`` made, which is unchanged
    and leaves no output."""
    raw = _write(tmp_path / "x_raw.fits", _ramps(), change=change)
    before = _digest(raw)
    out = tmp_path / "out.fits"
    assert main(["reduce", str(raw), "-c", str(_config(tmp_path / "wfc3.yaml")), "-o",
                 str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("spherex-reduce reduce: error: ")
    assert not out.exists() and _digest(raw) == before
    return err


def test_several_sci_without_input_reads_are_refused(tmp_path, capsys):
    """Not asked for, the extensions are refused (never reduced from SCI,1), in one line
    naming what was found and what to set; by `read` too."""
    raw = _write(tmp_path / "x_raw.fits", _ramps())
    cfg = tmp_path / "plain.yaml"
    write_config(cfg, GEOMETRY, READOUT, FIT)
    assert main(["reduce", str(raw), "-c", str(cfg), "-o", str(tmp_path / "out.fits")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert ("holds 6 SCI extensions (EXTVER 1 ... 6, SAMPTIME 35.867 ... 0.0 s): one image "
            "per read") in err and "set input.reads: extensions" in err
    with pytest.raises(FormatError, match=r"set input\.reads: extensions"):
        sr.read(raw, **GEOMETRY, **READOUT)


def test_drop_first_reads_drops_the_earliest(tmp_path):
    """``input: drop_first_reads`` leaves out the first reads in time order (the zeroth
    read, SCI,n), and their times."""
    ramps = _ramps()
    raw = _write(tmp_path / "x_raw.fits", ramps, dq=False)
    exposure = sr.read(raw, input={"reads": "extensions", "drop_first_reads": 1},
                       **GEOMETRY, **READOUT)
    assert exposure.schedule.read_times == tuple(TIMES[1:])
    np.testing.assert_array_equal(exposure.data.data, ramps[1:])


def _null_dq(hdul):
    """DQ,i without data, as _raw files store them: PIXVALUE 0, but 8 (every pixel) in DQ,2."""
    for h in [h for h in hdul if h.name == "DQ"]:
        h.data = None
        h.header["PIXVALUE"] = 8 if h.ver == 2 else 0


def test_a_dq_without_data_flags_every_pixel_with_its_pixvalue(tmp_path):
    """DQ,2 (the read at 25.866 s) flags every pixel: that read is left out of every fit;
    the DQ,i of PIXVALUE 0 flag none."""
    ramps = _ramps()
    raw = _write(tmp_path / "x_raw.fits", ramps, change=_null_dq)
    with fits.open(raw) as hdul:
        assert hdul["DQ", 2].header["NAXIS"] == 0
    pipeline = sr.Pipeline.from_yaml(_config(tmp_path / "wfc3.yaml"))
    slopes = pipeline.run(raw).data.data
    others = [k for k in range(len(TIMES)) if k != 4]
    np.testing.assert_allclose(slopes, _lstsq(ramps[others], [TIMES[k] for k in others]),
                               rtol=1e-9, atol=1e-9)


def test_one_sci_with_input_reads_is_refused(tmp_path):
    path = tmp_path / "one.fits"
    sci = fits.ImageHDU(np.zeros((16, 16), np.float32), name="SCI")
    sci.header["SAMPTIME"] = 0.0
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(path)
    with pytest.raises(FormatError, match=r"input\.reads is extensions, but the file holds 1 "
                                          r"SCI extension"):
        sr.read(path, input={"reads": "extensions"}, **GEOMETRY, **READOUT)
    with pytest.raises(FormatError, match="FrameReader reads one 3-D SCI"):
        sr.io.FrameReader(path, input={"reads": "extensions"}, **GEOMETRY, **READOUT)


def test_a_config_without_input_reads_keeps_its_hash():
    """``input.reads`` enters the effective config (and SXRCONF) only when set: an output
    made before the key existed is still recognised by a batch (the value below is the hash
    the package gave this config before)."""
    config = {"input": {"unit": "adu", "gain": 2.0},
              "geometry": {"nrows": 16, "ncols": 16, "nchannels": 2}, "steps": ["fit_ramp"]}
    assert sr.Pipeline(config).config_hash == "2305e54ac6b77912"
    with_reads = {**config, "input": {**config["input"], "reads": "extensions"}}
    assert sr.Pipeline(with_reads).config["input"]["reads"] == "extensions"
    assert sr.Pipeline(with_reads).config_hash != "2305e54ac6b77912"


def _flags_of_read_3(dtype, value):
    """A change: DQ,3 (the read at 22.934 s, read 3 in time order) as ``dtype``, flagging
    pixel `FLAGGED` with ``value`` (and no other)."""
    def change(hdul):
        flags = np.zeros((16, 16), dtype)
        flags[FLAGGED] = value
        hdul["DQ", 3].data = flags
    return change


def test_a_float_dq_of_a_read_is_refused_in_one_line(tmp_path, capsys):
    """``DQ,3`` stored as float with 0.5 on the bad read: cast to an integer it masked nothing
    and the read was fitted; refused, integral or not (as a 3-D file's float DQ is)."""
    for value in (0.5, 256.0):
        err = _refused(tmp_path, capsys, _flags_of_read_3(np.float32, value))
        assert ("x_raw.fits: HDU 'DQ',3 holds flags, which must be integers; it holds "
                "floating-point numbers (BITPIX = -32)") in err
        (tmp_path / "x_raw.fits").unlink()


@pytest.mark.parametrize("bit", [40, 63])
def test_a_64_bit_dq_of_a_read_masks_on_its_high_bits(tmp_path, bit):
    """``DQ,3`` as int64 with only bit 40 (or 63, a negative value) set: by default every bit
    masks, so read 3 of that pixel is left out of its fit (numpy least squares over the
    other reads); it was fitted (the mask kept bits 0-31 only).  ``dq_bits`` names bits
    0-31 only: with 256 the high bit does not mask."""
    ramps = _ramps()
    value = np.array(2**bit, np.uint64).view(np.int64)
    raw = _write(tmp_path / "x_raw.fits", ramps, change=_flags_of_read_3(np.int64, value))
    with fits.open(raw) as hdul:
        assert hdul["DQ", 3].header["BITPIX"] == 64
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", str(raw), "-c", str(_config(tmp_path / "wfc3.yaml")), "-o",
                 str(out)]) == 0
    expected = _lstsq(ramps, TIMES)
    others = [k for k in range(len(TIMES)) if k != 3]
    r, c = FLAGGED
    expected[r, c] = _lstsq(ramps[others], [TIMES[k] for k in others])[r, c]
    np.testing.assert_allclose(fits.getdata(out, "SCI"), expected, rtol=2**-23, atol=1e-9)
    assert "pixels with any bit set" in "".join(fits.getheader(out)["HISTORY"])
    chosen = tmp_path / "chosen.fits"
    assert main(["-q", "reduce", str(raw), "-c", str(_config(tmp_path / "b.yaml", dq_bits=256)),
                 "-o", str(chosen)]) == 0
    np.testing.assert_allclose(fits.getdata(chosen, "SCI"), _lstsq(ramps, TIMES), rtol=2**-23,
                               atol=1e-9)


def test_one_ramp_as_extensions_and_as_one_file_per_read_gives_one_slope(tmp_path):
    """Issue 31: one file per read (--reads) rounded the declared frame time to whole
    samples (0.277815 s, 27781.5 samples at 100 kHz, became 0.27781 s): its slopes were
    1.8e-5 higher than those of the same ramp read as extensions at their SAMPTIME."""
    tframe = 0.277815
    times = [k * tframe for k in range(len(TIMES))]
    ramps = _ramps()

    def evenly(hdul):
        for hdu in hdul[1:]:
            if hdu.name == "SCI":
                hdu.header["SAMPTIME"] = times[len(times) - hdu.ver]

    raw = _write(tmp_path / "x_raw.fits", ramps, dq=False, change=evenly)
    cfg = write_config(tmp_path / "ext.yaml", GEOMETRY, {**READOUT, "frame_time": tframe}, FIT)
    cfg.write_text(cfg.read_text() + "input: {reads: extensions}\n")
    reads = tmp_path / "r"
    reads.mkdir()
    for k, frame in enumerate(ramps):
        fits.PrimaryHDU(frame.astype(np.float32)).writeto(reads / f"read_{k}.fits")
    cfg2 = write_config(tmp_path / "reads.yaml", GEOMETRY,
                        {**READOUT, "frame_time": tframe, "nframes": len(times)}, FIT)
    assert main(["-q", "reduce", str(raw), "-c", str(cfg), "-o", str(tmp_path / "e.fits")]) == 0
    assert main(["-q", "reduce", "--reads", str(reads / "read_*.fits"), "-c", str(cfg2), "-o",
                 str(tmp_path / "r.fits")]) == 0
    by_extensions = fits.getdata(tmp_path / "e.fits", "SCI")
    by_files = fits.getdata(tmp_path / "r.fits", "SCI")
    expected = _lstsq(ramps, times)
    np.testing.assert_allclose(by_extensions, expected, rtol=2**-23, atol=1e-9)
    np.testing.assert_allclose(by_files, expected, rtol=2**-23, atol=1e-9)
    np.testing.assert_allclose(by_files, by_extensions, rtol=2**-23, atol=0)
