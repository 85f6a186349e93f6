"""Hostile FITS input: integer data, truncated files, bad header values, huge sizes and
damaged checksums each give one clear error (exit 2 on the command line) or the right
numbers, and never change the input file.

Every file is built here from small arrays; integer results are checked against numpy
arithmetic on the stored values, read independently of the package.
"""


import warnings

import numpy as np
import pytest
from _cli_helpers import digest
from _one_by_one import one_by_one
from astropy import units as u
from astropy.io import fits
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    FormatError,
    Pipeline,
    ReadoutSchedule,
    read,
    write,
)
from spherex_reduce.analysis.io import read_image
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ResourceError
from spherex_reduce.io import FrameReader, checksum_policy
from spherex_reduce.io.examples import example_raw_exposure

STEPS = {"steps": ["unchop", "subtract_phantom", {"correct_reference": {"strategy": "mean"}},
                   "fit_ramp"]}



def stored(path, name):
    """The values as stored in HDU ``name`` and its BSCALE, BZERO (numpy and astropy without
    scaling: independent of the package's reader)."""
    with fits.open(path, do_not_scale_image_data=True) as hdul:
        h = hdul[name].header
        return (np.array(hdul[name].data), float(h.get("BSCALE", 1.0)),
                float(h.get("BZERO", 0.0)))


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=3)


@pytest.fixture
def uint16_file(tmp_path, raw):
    """Raw ramps and phantoms as unsigned 16-bit counts (astropy writes BZERO = 32768)."""
    ints = raw.replace(data=np.round(raw.data.data - raw.data.data.min() + 60000).astype("u2"),
                       phantom=np.round(raw.phantom - raw.phantom.min() + 40000).astype("u2"))
    path = write(ints, tmp_path / "u16.fits")
    with fits.open(path) as hdul:
        assert hdul["SCI"].header["BZERO"] == 32768 and hdul["SCI"].header["BITPIX"] == 16
    return path


def scaled_copy(src, out, name, bscale, bzero, blank=None, bitpix="int16"):
    """``src`` with HDU ``name`` stored as scaled integers (values rounded by astropy)."""
    with fits.open(src) as hdul:
        hdus = []
        for h in hdul:
            h = h.copy()
            if h.name == name:
                h.scale(bitpix, bscale=bscale, bzero=bzero)
                if blank is not None:
                    h.header["BLANK"] = blank
            hdus.append(h)
        fits.HDUList(hdus).writeto(out, checksum=True)
    if blank is not None:  # one stored value becomes BLANK
        with fits.open(out, mode="update", do_not_scale_image_data=True) as hdul:
            hdul[name].data.flat[5] = blank
            hdul[name].add_checksum()
    return out


# -- integer data ------------------------------------------------------------------------


def test_uint16_file_is_read_as_float_in_memory_and_frame_by_frame(uint16_file):
    before = digest(uint16_file)
    values, bscale, bzero = stored(uint16_file, "SCI")
    expected = values.astype(np.float64) * bscale + bzero  # numpy: BZERO + BSCALE * stored
    pvalues, pscale, pzero = stored(uint16_file, "PHANTOM")
    e = read(uint16_file)
    assert e.data.data.dtype == np.float32
    np.testing.assert_array_equal(e.data.data, expected)
    np.testing.assert_array_equal(e.phantom, pvalues * pscale + pzero)
    assert expected.max() > 32767  # the unsigned range really is used
    with FrameReader(uint16_file) as frames:
        for k in range(frames.nframes):
            f = frames.frame(k)
            assert f.data.data.dtype == np.float32
            np.testing.assert_array_equal(f.data.data[0], expected[k])
            np.testing.assert_array_equal(f.phantom[0], pvalues[k] * pscale + pzero)
    assert digest(uint16_file) == before


def test_bscale_bzero_blank_image_is_scaled_and_blank_is_nan(tmp_path, raw):
    plain = write(raw, tmp_path / "raw.fits")
    path = scaled_copy(plain, tmp_path / "scaled.fits", "SCI", bscale=0.25, bzero=1000.0,
                       blank=-32768)
    before = digest(path)
    values, bscale, bzero = stored(path, "SCI")
    assert (bscale, bzero) == (0.25, 1000.0)
    expected = np.where(values == -32768, np.nan, values * 0.25 + 1000.0)
    np.testing.assert_array_equal(read(path).data.data, expected)
    with FrameReader(path) as frames:
        got = np.concatenate([frames.frame(k).data.data for k in range(frames.nframes)])
    np.testing.assert_array_equal(got, expected)
    assert np.isnan(got).sum() == 1
    assert digest(path) == before


def test_int32_bscale_gives_float64(tmp_path, raw):
    plain = write(raw, tmp_path / "raw.fits")
    path = scaled_copy(plain, tmp_path / "i32.fits", "SCI", bscale=1e-3, bzero=-5.0,
                       bitpix="int32")
    values, bscale, bzero = stored(path, "SCI")
    got = read(path).data.data
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, values * bscale + bzero, rtol=0, atol=1e-12)


def test_integer_file_reduces_like_the_same_values_in_float(tmp_path, uint16_file):
    as_float = read(uint16_file)  # checked against numpy above
    float_file = write(as_float.replace(data=np.array(as_float.data.data),
                                        phantom=np.array(as_float.phantom)),
                       tmp_path / "f32.fits")
    before = digest(uint16_file)
    streamed = Pipeline(STEPS).run(uint16_file)  # frame by frame from the file
    reference = Pipeline(STEPS).run(float_file)
    np.testing.assert_allclose(streamed.data.data, reference.data.data, rtol=1e-5, atol=1e-4)
    in_memory = one_by_one(STEPS, read(uint16_file))
    np.testing.assert_allclose(in_memory.data.data, reference.data.data, rtol=1e-5, atol=1e-4)
    assert digest(uint16_file) == before


def test_integer_files_through_the_commands(tmp_path, uint16_file, capsys):
    before = digest(uint16_file)
    out = tmp_path / "unchopped.fits"
    assert main(["reduce", str(uint16_file), "-c", "unchop", "-o", str(out)]) == 0
    values, bscale, bzero = stored(uint16_file, "SCI")
    unchopped = read(out)
    rows = unchopped.schedule.to_table()
    # numpy: frame 1, the first active row read, is the row it names
    first = int(np.flatnonzero(rows["kind"] == "active")[0])
    np.testing.assert_array_equal(unchopped.data.data[1, rows["row"][first]],
                                  values[1, first] * bscale + bzero)
    as_float = read(uint16_file)
    float_file = write(as_float.replace(data=np.array(as_float.data.data),
                                        phantom=np.array(as_float.phantom)), tmp_path / "f.fits")
    with warnings.catch_warnings():  # random numbers, not the noise model: a fit flagged
        warnings.simplefilter("always", AstropyUserWarning)
        assert main(["fit-noise", str(uint16_file), "-o", str(tmp_path / "fit.ecsv")]) == 0
        assert main(["fit-noise", str(float_file), "-o", str(tmp_path / "fitf.ecsv")]) == 0
    fit, fitf = Table.read(tmp_path / "fit.ecsv"), Table.read(tmp_path / "fitf.ecsv")
    for col in ("alpha", "beta", "gamma"):
        np.testing.assert_allclose(fit[col], fitf[col], rtol=1e-6)
    # two reduced images stored as scaled int16: combine gives their numpy mean
    slopes = Pipeline(STEPS).run(uint16_file)
    images = []
    for i in range(2):
        f = write(slopes.replace(data=np.asarray(slopes.data.data) + 3 * i),
                  tmp_path / f"slopes{i}.fits")
        images.append(scaled_copy(f, tmp_path / f"scaled{i}.fits", "SCI", bscale=0.01,
                                  bzero=0.0))
    master = tmp_path / "master.fits"
    assert main(["combine", *map(str, images), "-o", str(master), "--sigma", "0"]) == 0
    a, b = ((v * s + z) for v, s, z in (stored(p, "SCI") for p in images))
    # float32 (16-bit data): to its rounding of values of a few hundred
    np.testing.assert_allclose(read(master).data.data, (a + b) / 2, rtol=0, atol=1e-4)
    capsys.readouterr()
    assert digest(uint16_file) == before


def test_spectrum_of_a_scaled_integer_image(tmp_path, capsys):
    rng = np.random.default_rng(2)
    hdu = fits.PrimaryHDU(rng.normal(0, 0.5, (128, 128)))
    hdu.scale("int16", bscale=1e-3, bzero=0.0)
    hdu.header["BUNIT"] = "electron / s"
    path = tmp_path / "int.fits"
    hdu.writeto(path, checksum=True)
    values, bscale, bzero = stored(path, "PRIMARY")
    img = read_image(path)
    np.testing.assert_allclose(img.data, values * bscale + bzero, rtol=1e-6)  # float32
    out = tmp_path / "p.ecsv"
    assert main(["spectrum", str(path), "-o", str(out)]) == 0
    floats = tmp_path / "float.fits"
    fits.PrimaryHDU(values * bscale + bzero, header=fits.Header({"BUNIT": "electron / s"})) \
        .writeto(floats)
    assert main(["spectrum", str(floats), "-o", str(tmp_path / "q.ecsv")]) == 0
    p, q = Table.read(out), Table.read(tmp_path / "q.ecsv")
    assert p.meta["band_power"] == pytest.approx(q.meta["band_power"], rel=1e-5)
    capsys.readouterr()


# -- truncated files ----------------------------------------------------------------------


def _reduced(tmp_path, raw):
    return write(Pipeline(STEPS).run(raw), tmp_path / "reduced.fits")


def _cuts(path):
    """Byte offsets that cut ``path``: mid-SCI data, inside the last HDU's header and data,
    and exactly before the last HDU (a valid FITS file, one HDU short)."""
    with fits.open(path) as hdul:
        sci, last = hdul["SCI"].fileinfo(), hdul[-1].fileinfo()
        last_bytes = hdul[-1].header.get("NAXIS1", 0) * hdul[-1].header.get("NAXIS2", 0)
    cuts = {"mid-SCI": sci["datLoc"] + 1001, "last header": last["hdrLoc"] + 500,
            "last HDU missing": last["hdrLoc"]}
    if last_bytes:
        cuts["last data"] = last["datLoc"] + last_bytes // 2
    return cuts


@pytest.mark.parametrize("kind", ["raw", "reduced"])
def test_truncated_files_are_named_as_truncated(tmp_path, raw, kind, capsys):
    path = write(raw, tmp_path / "raw.fits") if kind == "raw" else _reduced(tmp_path, raw)
    data = path.read_bytes()
    for where, cut in _cuts(path).items():
        bad = tmp_path / f"cut-{cut}.fits"
        bad.write_bytes(data[:cut])
        before = digest(bad)
        with pytest.raises(FormatError, match="is truncated") as info:
            read(bad)
        msg = str(info.value)
        assert str(bad) in msg, where
        if where == "last HDU missing":  # valid FITS, one HDU short: the count says so
            with fits.open(path) as whole:
                n = len(whole) - 1
            assert f"announces NEXTEND = {n} extensions, the file ends after {n - 1}" in msg
        else:
            assert f"the file ends after {cut}" in msg, where
        if where == "mid-SCI":
            assert "HDU 1 ('SCI') needs" in msg
        with pytest.raises(FormatError, match="is truncated"):
            read_image(bad)
        command = (["reduce", str(bad), "-c", "spherex-default", "-o", str(tmp_path / "o.fits")]
                   if kind == "raw" else ["spectrum", str(bad), "-o", str(tmp_path / "o.ecsv")])
        assert main(command) == 2, where
        err = capsys.readouterr().err
        assert "is truncated" in err and len(err.strip().splitlines()) == 1, (where, err)
        assert not (tmp_path / "o.fits").exists() and not (tmp_path / "o.ecsv").exists()
        assert digest(bad) == before


def test_frame_reader_refuses_a_truncated_raw_file(tmp_path, raw):
    path = write(raw, tmp_path / "raw.fits")
    bad = tmp_path / "cut.fits"
    bad.write_bytes(path.read_bytes()[: _cuts(path)["mid-SCI"]])
    with pytest.raises(FormatError, match=r"is truncated: HDU 1 \('SCI'\) needs \d+ bytes"):
        FrameReader(bad)


@pytest.mark.parametrize(("content", "message"), [
    (b"", "not a readable FITS file"),
    (b"SIMPLE  =                    T" + b" " * 50 + b"BITPIX  =                   16" + b" " * 49
     + b" " * 80 * 34, "truncated"),  # one block, no END
    ((b"SIMPLE  =                    T".ljust(80) + b"BITPIX  =                  -32".ljust(80)
      + b"NAXIS   =                    0".ljust(80)).ljust(2880 * 2, b" "), "no END card"),
    (b"this is not FITS at all" * 200, "not a readable FITS file"),
])
def test_spectrum_on_corrupt_files(tmp_path, content, message, capsys, monkeypatch):
    from spherex_reduce.io import fits_structure

    monkeypatch.setattr(fits_structure, "_MAX_HEADER_BLOCKS", 2)  # (the real limit is 28.8 MB)
    path = tmp_path / "bad.fits"
    path.write_bytes(content)
    assert main(["spectrum", str(path), "-o", str(tmp_path / "s.ecsv")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert path.read_bytes() == content


def test_spectrum_refuses_our_file_whose_sci_disagrees_with_its_header(tmp_path, capsys):
    g = DetectorGeometry(64, 64, 4, ref_border=4)
    s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, nframes=10)
    image = Exposure.from_arrays(np.zeros((64, 64)), s, unit=u.electron / u.s, order="physical")
    path = write(image, tmp_path / "img.fits")
    with fits.open(path) as hdul:
        hdul["SCI"].data = np.random.default_rng(0).normal(size=(64, 60))
        hdul.writeto(tmp_path / "bad.fits", checksum=True)
    assert main(["spectrum", str(tmp_path / "bad.fits"), "-o", str(tmp_path / "s.ecsv")]) == 2
    assert "axis 1, columns (NCOLS), is 60, expected 64" in capsys.readouterr().err
    assert not (tmp_path / "s.ecsv").exists()


# -- header values --------------------------------------------------------------------------


def _set_card(src, out, key, text, hdu_name=None):
    """Copy ``src`` with the value field of card ``key`` replaced by raw ``text`` (what
    astropy would refuse to write), checksums left as they were (the test turns them off)."""
    data = bytearray(src.read_bytes())
    start = 0
    if hdu_name is not None:
        start = data.index(f"EXTNAME = '{hdu_name}".encode()) // 2880 * 2880
    i = start
    while data[i : i + 8] != key.ljust(8).encode():
        i += 80
    data[i + 8 : i + 80] = (b"= " + text.encode().rjust(20)).ljust(72)
    out.write_bytes(bytes(data))
    return out


@pytest.mark.parametrize(("key", "text", "message"), [
    ("NROWS", "1E999", "header card NROWS = inf, not a finite number"),
    ("NROWS", "-1E999", "header card NROWS = -inf, not a finite number"),
    ("TFRAME", "NAN", "unreadable header card TFRAME = NAN"),
    ("CHANW", "'abc'", "keyword CHANW must be an integer, got 'abc'"),
    ("NFRAMES", "5.5", "keyword NFRAMES must be an integer, got 5.5"),
    ("NROWS", "T", "keyword NROWS must be an integer, got True"),
    ("NCOLS", "'16'", "keyword NCOLS must be an integer, got '16'"),
    ("NCOLS", "-16", "keyword NCOLS must be >= 1, got -16"),
    ("PIXRATE", "0", "keyword PIXRATE must be > 0, got 0"),
    ("REFMODE", "3", "keyword REFMODE must be a string, got 3"),
    ("ORDER", "1", "keyword ORDER must be a string, got 1"),
    ("SCANDIR", "'+x'", "SCANDIR must be 'same', 'alternate' or one '+' or '-' per channel, "
                        "got '+x'"),
])
def test_bad_header_values_name_the_keyword(tmp_path, raw, key, text, message, capsys):
    path = _set_card(write(raw, tmp_path / "raw.fits"), tmp_path / "bad.fits", key, text)
    before = digest(path)
    with checksum_policy(verify=False), pytest.raises(FormatError) as info:
        read(path)
    assert message in str(info.value)
    out = tmp_path / "out.fits"
    assert main(["reduce", str(path), "-c", "unchop", "-o", str(out), "--ignore-checksum"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and digest(path) == before


def test_integral_real_for_an_integer_keyword_is_accepted(tmp_path, raw):
    path = _set_card(write(raw, tmp_path / "raw.fits"), tmp_path / "ok.fits", "NCOLS", "16.0")
    assert read(path, verify_checksum=False).schedule == raw.schedule


def test_bad_scaling_keywords(tmp_path, uint16_file):
    path = _set_card(uint16_file, tmp_path / "bad.fits", "BZERO", "'x'", hdu_name="SCI")
    with pytest.raises(FormatError, match="HDU 'SCI': keyword BZERO must be a finite number"):
        read(path, verify_checksum=False)
    path = _set_card(uint16_file, tmp_path / "zero.fits", "BSCALE", "0", hdu_name="SCI")
    with pytest.raises(FormatError, match="BSCALE = 0"):
        read(path, verify_checksum=False)


@pytest.mark.parametrize(("key", "text"), [("NROWS", "1000000000000000"),
                                           ("NREFRD", "1000000000000"),
                                           ("NCOLS", "4000000000000000")])
def test_huge_header_sizes_are_refused_before_allocating(tmp_path, raw, key, text, capsys):
    path = _set_card(write(raw, tmp_path / "raw.fits"), tmp_path / "huge.fits", key, text)
    with pytest.raises(ResourceError, match=r"readout schedule .* needs .* of memory"):
        read(path, verify_checksum=False)
    assert main(["reduce", str(path), "-c", "unchop", "-o", str(tmp_path / "o.fits"),
                 "--ignore-checksum"]) == 2
    assert "of memory" in capsys.readouterr().err


def test_huge_data_axis_is_a_truncated_file(tmp_path, raw):
    path = _set_card(write(raw, tmp_path / "raw.fits"), tmp_path / "huge.fits", "NAXIS3",
                     "1000000000000", hdu_name="SCI")
    with pytest.raises(FormatError, match=r"is truncated: HDU 1 \('SCI'\) needs 2176"):
        read(path)


# -- checksums ------------------------------------------------------------------------------


def _flip_sci_byte(path, out):
    with fits.open(path) as hdul:
        where = hdul["SCI"].fileinfo()["datLoc"] + 333
    data = bytearray(path.read_bytes())
    data[where] ^= 0x10
    out.write_bytes(bytes(data))
    return out


def test_word_sum_is_the_fits_datasum(tmp_path):
    from spherex_reduce.io.fits_structure import _word_sum

    rng = np.random.default_rng(5)
    for n in (1, 7, 1000, 30001):  # also lengths that are not whole words
        blob = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        path = tmp_path / f"b{n}"
        path.write_bytes(blob)
        words = np.frombuffer(blob.ljust(-(-n // 4) * 4, b"\0"), ">u4").astype(object)
        total = int(sum(words))  # Python integers: the plain definition
        while total >> 32:
            total = (total & 0xFFFFFFFF) + (total >> 32)
        with open(path, "rb") as fh:
            assert _word_sum(fh, 0, n, chunk=4096) == total
    # and astropy's DATASUM of a real HDU
    hdu = fits.ImageHDU(rng.normal(size=(37, 11)).astype(">f4"), name="X")
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(tmp_path / "x.fits", checksum=True)
    with fits.open(tmp_path / "x.fits") as hdul:
        info, declared = hdul["X"].fileinfo(), int(hdul["X"].header["DATASUM"])
    with open(tmp_path / "x.fits", "rb") as fh:
        assert _word_sum(fh, info["datLoc"], info["datSpan"]) == declared


def test_flipped_byte_is_an_error_unless_asked_to_continue(tmp_path, raw, capsys, caplog):
    path = _flip_sci_byte(write(raw, tmp_path / "raw.fits"), tmp_path / "flipped.fits")
    before = digest(path)
    with pytest.raises(FormatError, match=r"checksum of HDU\(s\) SCI does not match"):
        read(path)
    with pytest.raises(FormatError, match="checksum"):
        FrameReader(path)
    out = tmp_path / "red.fits"
    assert main(["reduce", str(path), "-c", "spherex-default", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--ignore-checksum" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    # asked to continue: a warning, recorded in what is read and in the output
    e = read(path, verify_checksum=False)
    assert e.header["SXRCKBAD"] == "SCI"
    assert any("flipped.fits did not match" in h for h in e.header["HISTORY"])
    caplog.clear()
    assert main(["reduce", str(path), "-c", "spherex-default", "-o", str(out),
                 "--ignore-checksum"]) == 0
    assert "does not match" in caplog.text  # a warning (on stderr from the command line)
    with fits.open(out) as hdul:
        assert hdul[0].header["SXRCKBAD"] == "SCI"
        assert any("did not match" in h for h in hdul[0].header["HISTORY"])
    read(out)  # the output's own checksums are valid
    fit = tmp_path / "fit.ecsv"
    assert main(["fit-noise", str(path), "-o", str(fit), "--ignore-checksum"]) == 0
    assert Table.read(fit).meta["input_checksum_failed"] == "SCI"
    capsys.readouterr()
    assert digest(path) == before


def test_edited_header_fails_checksum_and_spectrum_records_ignoring_it(tmp_path, capsys):
    rng = np.random.default_rng(3)
    hdu = fits.PrimaryHDU(rng.normal(size=(64, 64)))
    hdu.header["BUNIT"] = "electron / s"
    hdu.header["OBSERVER"] = "abc"
    path = tmp_path / "img.fits"
    hdu.writeto(path, checksum=True)
    path.write_bytes(path.read_bytes().replace(b"'abc     '", b"'abd     '"))  # by hand
    out = tmp_path / "s.ecsv"
    assert main(["spectrum", str(path), "-o", str(out)]) == 2
    assert "checksum of HDU(s) PRIMARY" in capsys.readouterr().err
    assert main(["spectrum", str(path), "-o", str(out), "--ignore-checksum", "--kmin", "0.3",
                 "--kmax", "1"]) == 0
    assert Table.read(out).meta["input_checksum_failed"] == "PRIMARY"
    capsys.readouterr()


def test_files_without_checksums_are_read(tmp_path, raw):
    path = write(raw, tmp_path / "raw.fits")
    with fits.open(path) as hdul:
        for h in hdul:
            del h.header["CHECKSUM"], h.header["DATASUM"]
        hdul.writeto(tmp_path / "plain.fits")
    np.testing.assert_array_equal(read(tmp_path / "plain.fits").data.data, raw.data.data)


def test_an_ascii_table_written_with_checksums_is_not_damaged(tmp_path, raw):
    """An ASCII-table extension's fill is blanks, and its DATASUM counts them: summing the
    data with zeros after the last word refused a valid file as damaged."""
    path = write(raw, tmp_path / "raw.fits")
    notes = fits.TableHDU.from_columns(
        [fits.Column(name="note", format="A7", array=np.array(["a", "bc", "def"]))],
        name="NOTES")
    with fits.open(path) as hdul:
        fits.HDUList([h.copy() for h in hdul] + [notes]).writeto(tmp_path / "ascii.fits",
                                                                 checksum=True)
    with fits.open(tmp_path / "ascii.fits", checksum=True) as hdul:  # astropy: valid
        assert hdul["NOTES"].verify_datasum() == 1 and len(hdul["NOTES"].data) == 3
    np.testing.assert_array_equal(read(tmp_path / "ascii.fits").data.data, raw.data.data)


@pytest.mark.parametrize("module", ["gzip", "bz2", "lzma"])
def test_truncated_compressed_files(tmp_path, raw, module, capsys):
    import importlib

    opener = importlib.import_module(module)
    path = write(raw, tmp_path / "raw.fits")
    data = path.read_bytes()
    whole = tmp_path / "whole.fits.z"
    with opener.open(whole, "wb") as fh:
        fh.write(data)
    np.testing.assert_array_equal(read(whole).data.data, raw.data.data)  # complete: fine
    cut = _cuts(path)["mid-SCI"]
    inner = tmp_path / "inner.fits.z"  # the FITS bytes cut, then compressed
    with opener.open(inner, "wb") as fh:
        fh.write(data[:cut])
    with pytest.raises(FormatError, match=rf"is truncated: HDU 1 \('SCI'\) needs \d+ bytes, "
                                          rf"the file, decompressed, ends after {cut}"):
        read(inner)
    outer = tmp_path / "outer.fits.z"  # the compressed stream cut
    outer.write_bytes(whole.read_bytes()[: len(whole.read_bytes()) // 2])
    with pytest.raises(FormatError, match="truncated"):
        read(outer)
    assert main(["reduce", str(outer), "-c", "unchop", "-o", str(tmp_path / "o.fits")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_simulated_raw_file_missing_its_last_hdu(tmp_path):
    from spherex_reduce.simulation import simulate_to_fits

    scene = tmp_path / "scene.yaml"
    scene.write_text("geometry: {nrows: 32, ncols: 16, nchannels: 2, ref_border: 2}\n"
                     "readout: {skip: 5, ref_reads: 4, phantom_reads: 2, nframes: 3,"
                     " frame_overhead: 100}\noutput: {mode: ramps}\nseed: 1\n")
    path = simulate_to_fits(str(scene), tmp_path / "raw.fits")
    read(path)  # whole: fine (its checksums too)
    with fits.open(path) as hdul:
        assert hdul[0].header["NEXTEND"] == 3
        cut = hdul["READOUT"].fileinfo()["hdrLoc"]
    short = tmp_path / "short.fits"
    short.write_bytes(path.read_bytes()[:cut])
    with pytest.raises(FormatError, match="announces NEXTEND = 3 extensions, the file ends "
                                          "after 2"):
        read(short)


def test_combine_records_every_input_read_despite_its_checksum(tmp_path, small_schedule, capsys):
    rng = np.random.default_rng(4)
    images = []
    for i in range(3):
        e = Exposure.from_arrays(rng.normal(size=(small_schedule.geometry.nrows, 16)),
                                 small_schedule, unit=u.electron / u.s, order="physical")
        images.append(write(e, tmp_path / f"img{i}.fits"))
    damaged = _flip_sci_byte(images[1], tmp_path / "damaged.fits")
    master = tmp_path / "master.fits"
    inputs = [str(images[0]), str(damaged), str(images[2])]
    assert main(["combine", *inputs, "-o", str(master)]) == 2
    assert "damaged.fits: the checksum of HDU(s) SCI" in capsys.readouterr().err
    assert main(["combine", *inputs, "-o", str(master), "--ignore-checksum"]) == 0
    with fits.open(master) as hdul:
        assert hdul[0].header["SXRCKBAD"] == "SCI"
        assert any("damaged.fits did not match" in h for h in hdul[0].header["HISTORY"])


@pytest.mark.parametrize("module", ["gzip", "bz2", "lzma"])
def test_a_compressed_file_cut_while_it_is_read_is_named(tmp_path, raw, module):
    """The file is opened and checked whole, then cut before its pixels are unpacked (it
    changed under the reader): one FormatError naming it, not the decompressor's EOFError
    (exit 1 on the command line)."""
    import importlib
    import os

    from spherex_reduce.io.readers.fits_read import CheckedFITS

    path = write(raw, tmp_path / "raw.fits")
    packed = tmp_path / "raw.fits.z"
    with importlib.import_module(module).open(packed, "wb") as fh:
        fh.write(path.read_bytes())
    reader = CheckedFITS(packed)
    try:
        os.truncate(packed, packed.stat().st_size // 2)
        with pytest.raises(FormatError, match=r"raw\.fits\.z: the compressed data end early"):
            reader.exposure()
    finally:
        reader.close()
