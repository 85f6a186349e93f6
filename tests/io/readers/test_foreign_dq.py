"""A ``DQ`` written by other software: a 2-D mask over ramps, and whose bits mask.

Every file is built here from small arrays, as a lab or JWST would write it
(no ``READOUT`` table, ``DQ`` as unsigned 32-bit integers, the readout
parameters from the pipeline config).  Slopes are checked against numpy's
least squares on the file's values.
"""

import hashlib

import numpy as np
import pytest
from _configs import write_config
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce import dq
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError, FormatError
from spherex_reduce.io import foreign_dq_bits

GEOMETRY = {"nrows": 16, "ncols": 8, "nchannels": 2, "ref_border": 2, "pixel_rate": 1e5}
#: chopped, with re-read reference rows: 20 reads of 16 rows, in a mixed order
READOUT = {"skip": 4, "ref_reads": 8, "ref_mode": "repeated", "phantom_reads": 0,
           "nframes": 5, "frame_time": 2.0}
SUPPLIED = {**GEOMETRY, **READOUT}
NONE = {**SUPPLIED, "ref_mode": "none"}  # each row read once
FLAGGED = [(5, 3), (0, 1), (11, 6)]  # (physical row, column) with bit 0 set
OTHER_BIT = (6, 2)  # (row, column) with bit 2 only (JWST: JUMP_DET; ours would be HOT)
HIGH_BIT = (9, 4)  # bit 31 only (stored as uint32: BZERO = 2**31)


def _schedule(**readout):
    return sr.ReadoutSchedule(sr.DetectorGeometry(16, 8, 2, ref_border=2, pixel_rate=1e5),
                              **{**READOUT, **readout})


def _pixel_mask():
    mask = np.zeros((16, 8), np.uint32)
    for r, c in FLAGGED:
        mask[r, c] = 1 | 8
    mask[OTHER_BIT] = 4
    mask[HIGH_BIT] = 2**31
    return mask


def _config(path, steps, **readout):
    return write_config(path, GEOMETRY, {**READOUT, **readout}, steps)


def _foreign(path, sci, mask, primary=None):
    """A file as other software writes it: SCI and DQ, no READOUT table."""
    hdus = [fits.PrimaryHDU(header=primary), fits.ImageHDU(sci, name="SCI")]
    if mask is not None:
        hdus.append(fits.ImageHDU(mask, name="DQ"))
    fits.HDUList(hdus).writeto(path, checksum=True)
    return path


def _ramps(schedule, seed=3):
    rng = np.random.default_rng(seed)
    k = np.arange(schedule.nframes)[:, None, None]
    rate = rng.uniform(1, 5, (1, schedule.n_reads, 8))
    return (100 + rate * k * 2.0 + rng.normal(0, 0.5, (schedule.nframes, schedule.n_reads, 8))
            ).astype(np.float32)


def _lstsq(ramps, tframe):
    """Least-squares slope of every pixel over the frames (numpy, float64)."""
    n = ramps.shape[0]
    design = np.vstack([np.arange(n) * tframe, np.ones(n)]).T
    coef = np.linalg.lstsq(design, ramps.reshape(n, -1).astype(np.float64), rcond=None)[0]
    return coef[0].reshape(ramps.shape[1:])


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _reference_pixels():
    """The reference pixels of the 16 x 8 array (border 2): the output flags them
    REFERENCE, which masks nothing."""
    ref = np.ones((16, 8), bool)
    ref[2:14, 2:6] = False
    return ref


def _masked_reads(schedule, cells):
    """(read, column) of every read of the rows of ``cells``."""
    return {(int(i), c) for r, c in cells for i in np.flatnonzero(schedule.rows == r)}


@pytest.mark.parametrize("option", [[], ["--dq-bits", "0x9"]])
def test_pixel_mask_masks_every_read_of_its_rows(tmp_path, option):
    """A 2-D (nrows, ncols) DQ over readout-order ramps: every read of a flagged row of every
    frame is masked (slope NaN, FEW_READS); the other slopes are numpy's least squares."""
    s = _schedule()
    assert s.n_reads == 20 and s.n_reads != s.geometry.nrows
    sci = _ramps(s)
    raw = _foreign(tmp_path / "lab.fits", sci, _pixel_mask())
    before = _digest(raw)
    cfg = _config(tmp_path / "fit.yaml", ["fit_ramp: {weighting: uniform}"])
    out = tmp_path / "out.fits"
    assert main(["-q", "reduce", str(raw), "-c", str(cfg), "-o", str(out), *option]) == 0
    assert _digest(raw) == before
    cells = FLAGGED + ([] if option else [OTHER_BIT, HIGH_BIT])  # by default: every bit
    masked = _masked_reads(s, cells)
    assert len(masked) > len(cells)  # re-read rows: more than one read per flagged row
    with fits.open(out) as hdul:
        slopes, flags = hdul["SCI"].data, hdul["DQ"].data
        assert hdul[0].header["SXRDQBIT"] == (0x9 if option else 2**32 - 1)
    expected = _lstsq(sci, 2.0)
    reference = np.where(_reference_pixels()[s.rows], dq.REFERENCE, 0)  # per read
    for i in range(s.n_reads):
        for c in range(8):
            if (i, c) in masked:
                assert np.isnan(slopes[i, c]), (i, c)
                assert flags[i, c] == dq.FEW_READS | dq.DO_NOT_USE | reference[i, c], (i, c)
            else:
                assert flags[i, c] == reference[i, c], (i, c)
                np.testing.assert_allclose(slopes[i, c], expected[i, c], rtol=1e-6, atol=1e-6)


def test_pixel_mask_through_unchop(tmp_path):
    """Un-chopped to physical rows, the flagged pixels of the mask are the NaN slopes."""
    s = _schedule(ref_mode="none")
    sci = _ramps(s, seed=4)
    raw = _foreign(tmp_path / "lab.fits", sci, _pixel_mask())
    cfg = _config(tmp_path / "p.yaml", ["unchop: {}", "fit_ramp: {weighting: uniform}"],
                  ref_mode="none")
    out = sr.Pipeline.from_yaml(cfg).run(raw)
    assert out.order == "physical"
    rows = s.rows
    assert sorted(rows.tolist()) == list(range(16))  # each row read once
    physical = np.empty_like(sci)
    physical[:, rows] = sci
    expected = _lstsq(physical, 2.0)
    bad = np.zeros((16, 8), bool)
    bad[tuple(np.transpose([*FLAGGED, OTHER_BIT, HIGH_BIT]))] = True  # every bit masks
    assert np.isnan(out.data.data[bad]).all()
    reference = np.where(_reference_pixels(), dq.REFERENCE, 0)
    assert (out.dq[bad] == (dq.FEW_READS | dq.DO_NOT_USE | reference)[bad]).all()
    assert (out.dq[~bad] == reference[~bad]).all()
    np.testing.assert_allclose(out.data.data[~bad], expected[~bad], rtol=1e-6, atol=1e-6)


def test_foreign_bits(tmp_path):
    """Every bit masks by default (a flag we cannot read is never fitted as good);
    ``dq_bits`` (argument or context) chooses other bits;
    every masked pixel is DO_NOT_USE, whatever the file's bit."""
    s = _schedule(ref_mode="none")
    raw = _foreign(tmp_path / "lab.fits", _ramps(s), _pixel_mask())
    before = _digest(raw)

    def masked(**kw):
        e = sr.read(raw, **NONE, **kw)
        assert e.dq.shape == e.shape and set(np.unique(e.dq)) <= {0, dq.DO_NOT_USE}
        assert all((e.dq[k] == e.dq[0]).all() for k in range(s.nframes))  # every frame
        return {(int(s.rows[i]), int(c)) for i, c in np.argwhere(e.dq[0])}

    assert masked() == {*FLAGGED, OTHER_BIT, HIGH_BIT}
    assert masked(dq_bits=1) == set(FLAGGED)
    assert masked(dq_bits=4) == {OTHER_BIT}
    assert masked(dq_bits=1 | 4 | 2**31) == {*FLAGGED, OTHER_BIT, HIGH_BIT}
    assert masked(dq_bits=8) == set(FLAGGED)
    with foreign_dq_bits(2**31):
        assert masked() == {HIGH_BIT}
        assert masked(dq_bits=1) == set(FLAGGED)  # the argument wins
    assert masked() == {*FLAGGED, OTHER_BIT, HIGH_BIT}
    e = sr.read(raw, **NONE, dq_bits=0)
    assert e.dq is not None and not e.dq.any()
    e = sr.read(raw, **NONE, dq_bits=5)
    assert e.header["SXRDQBIT"] == 5 and "lab.fits" in str(e.header["HISTORY"])
    for bad in (-1, 2**32, 1.0, True, "1"):
        with pytest.raises(ConfigError, match="dq_bits"):
            sr.read(raw, **NONE, dq_bits=bad)
    assert _digest(raw) == before


def test_own_files_keep_every_bit(tmp_path):
    """A file written by this package (READOUT table) keeps all its flags, whatever dq_bits."""
    s = _schedule()
    flags = np.zeros((s.nframes, s.n_reads, 8), np.uint16)
    flags[1, 3, 4] = dq.HOT
    flags[2, 7, 0] = dq.SATURATED | dq.DO_NOT_USE
    path = sr.write(sr.Exposure.from_arrays(_ramps(s), s, mask=flags), tmp_path / "own.fits")
    for bits in (None, 0, 1):
        e = sr.read(path, dq_bits=bits)
        np.testing.assert_array_equal(e.dq, flags)
        assert "SXRDQBIT" not in e.header
    with pytest.raises(ConfigError, match="dq_bits"):  # checked even where unused
        sr.read(path, dq_bits=-1)


def test_other_layouts_of_a_2d_dq(tmp_path):
    """One row per read (n_reads, ncols) applies to each frame as it is; over physical-order
    ramps the (nrows, ncols) mask is the rows themselves."""
    s = _schedule()
    per_read = np.zeros((s.n_reads, 8), np.int16)
    per_read[2, 5] = 1
    e = sr.read(_foreign(tmp_path / "reads.fits", _ramps(s), per_read), **SUPPLIED)
    assert [tuple(i) for i in np.argwhere(e.dq)] == [(k, 2, 5) for k in range(s.nframes)]

    physical = np.ones((s.nframes, 16, 8), np.float32)
    primary = fits.Header({"ORDER": "PHYSICAL"})
    e = sr.read(_foreign(tmp_path / "phys.fits", physical, _pixel_mask(), primary), **SUPPLIED)
    expected = np.broadcast_to(_pixel_mask() != 0, physical.shape)
    np.testing.assert_array_equal(e.dq != 0, expected)


@pytest.mark.parametrize("shape", [(15, 8), (16, 9), (2, 20, 8), (5, 16, 8), (5,)])
def test_wrong_dq_shape_is_refused(tmp_path, shape):
    s = _schedule()
    raw = _foreign(tmp_path / "lab.fits", _ramps(s), np.zeros(shape, np.int32))
    with pytest.raises(FormatError, match=r"DQ has shape \(.*\), SCI has shape \(5, 20, 8\)"):
        sr.read(raw, **SUPPLIED)


def test_float_dq_is_refused(tmp_path):
    s = _schedule()
    raw = _foreign(tmp_path / "lab.fits", _ramps(s), np.zeros((16, 8), np.float32))
    with pytest.raises(FormatError, match=r"DQ.*integers"):
        sr.read(raw, **SUPPLIED)


def test_a_64_bit_dq_masks_on_its_high_bits(tmp_path):
    """A 3-D int64 DQ with bit 40 on one read and bit 63 (a negative value) on another: by
    default (every bit) both reads are left out of their pixel's fit, the other slopes are
    numpy's least squares; they were fitted (the mask kept bits 0-31).  ``--dq-bits``
    names bits 0-31: with 1 neither high bit masks."""
    s = _schedule()
    sci = _ramps(s)
    flags = np.zeros(sci.shape, np.int64)
    flags[2, 4, 3] = 2**40
    flags[1, 9, 6] = np.array(2**63, np.uint64).view(np.int64)
    raw = _foreign(tmp_path / "lab.fits", sci, flags)
    with fits.open(raw) as hdul:
        assert hdul["DQ"].header["BITPIX"] == 64
    cfg = _config(tmp_path / "fit.yaml", ["fit_ramp: {weighting: uniform}"])
    expected = _lstsq(sci, 2.0)
    for frame, i, c in ((2, 4, 3), (1, 9, 6)):
        kept = np.delete(np.arange(s.nframes), frame)
        design = np.vstack([kept * 2.0, np.ones(kept.size)]).T
        expected[i, c] = np.linalg.lstsq(design, sci[kept, i, c].astype(np.float64),
                                         rcond=None)[0][0]
    for option, want in (([], expected), (["--dq-bits", "1"], _lstsq(sci, 2.0))):
        out = tmp_path / f"out{len(option)}.fits"
        assert main(["-q", "reduce", str(raw), "-c", str(cfg), "-o", str(out), *option]) == 0
        np.testing.assert_allclose(fits.getdata(out, "SCI"), want, rtol=1e-6, atol=1e-6)


def test_an_own_file_with_a_bit_above_31_is_refused(tmp_path, capsys):
    """This package's flags are 32 bits: its file with a 64-bit DQ holding bit 40 (changed by
    other software) is refused in one line, not read with the bit dropped."""
    s = _schedule()
    path = sr.write(sr.Exposure.from_arrays(_ramps(s), s), tmp_path / "own.fits")
    with fits.open(path) as hdul:
        flags = np.zeros(hdul["SCI"].shape, np.int64)
        flags[1, 3, 4] = 2**40 | dq.HOT
        hdul.append(fits.ImageHDU(flags, name="DQ"))
        hdul.writeto(tmp_path / "changed.fits", checksum=True)
    with pytest.raises(FormatError, match=r"changed.fits: DQ holds 1099511627780, a flag above "
                                          r"bit 31 \(bit 40\)"):
        sr.read(tmp_path / "changed.fits")
    cfg = _config(tmp_path / "fit.yaml", ["fit_ramp: {}"])
    assert main(["reduce", str(tmp_path / "changed.fits"), "-c", str(cfg), "-o",
                 str(tmp_path / "out.fits")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "bit 40" in err and not (tmp_path / "out.fits").exists()


def test_cli_dq_bits_is_checked(tmp_path, capsys):
    """``--dq-bits`` takes 0 to 2**32 - 1 (decimal, hex, binary) on every command reading FITS;
    anything else is a one-line usage error naming the option."""
    cfg = _config(tmp_path / "fit.yaml", ["fit_ramp: {}"])
    commands = [["reduce", "none.fits", "-c", str(cfg), "-o", str(tmp_path / "o.fits")],
                ["fit-noise", "none.fits", "-o", str(tmp_path / "o.ecsv")],
                ["spectrum", "none.fits", "-o", str(tmp_path / "o.ecsv")],
                ["combine", "none.fits", "none.fits", "-o", str(tmp_path / "o.fits")]]
    for argv in commands:
        for good in ("0", "5", "0x80000001", "0b101", "4294967295"):
            assert main(["-q", *argv, "--dq-bits", good]) == 2  # the missing file, not the bits
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and "none.fits" in err[0] and "dq-bits" not in err[0], err
        for bad in ("-1", "4294967296", "1e3", "bit0"):
            assert main(["-q", *argv, "--dq-bits", bad]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and "argument --dq-bits" in err[0], err
