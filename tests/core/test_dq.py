"""Flags are 32 bits end to end; which bits mask a read, which mask a pixel of an image."""

import numpy as np
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce import dq

BITS = [dq.DO_NOT_USE, dq.SATURATED, dq.HOT, dq.NO_REFERENCE, dq.FEW_READS, dq.NOT_READ,
        dq.JUMP, dq.REFERENCE]


def test_every_bit_is_one_distinct_bit_and_named():
    assert sorted(BITS) == [2**k for k in range(len(BITS))]
    assert [dq.describe(b) for b in BITS] == [[n] for n in (
        "DO_NOT_USE", "SATURATED", "HOT", "NO_REFERENCE", "FEW_READS", "NOT_READ", "JUMP",
        "REFERENCE")]
    assert dq.describe(2**31 | dq.HOT) == ["HOT", "BIT31"]


def test_which_bits_mask():
    flags = np.array([0, *BITS, 2**19, 2**31], np.uint32)
    informs_image = {0, dq.JUMP, dq.SATURATED, dq.REFERENCE}
    informs_read = {0, dq.JUMP, dq.REFERENCE, dq.NO_REFERENCE}  # uncorrected, not unusable
    assert dq.image_usable(flags).tolist() == [int(f) in informs_image for f in flags]
    assert dq.read_usable(flags).tolist() == [int(f) in informs_read for f in flags]


def test_flags_above_bit_15_survive_memory_files_and_steps(tmp_path):
    s = sr.ReadoutSchedule(sr.DetectorGeometry(4, 4, 1, ref_border=0), skip=1, ref_reads=0,
                           ref_mode="none", phantom_reads=0, nframes=4)
    flags = np.zeros((4, 4, 4), np.uint32)
    flags[1, 2, 2] = 2**31 | 2**16
    flags[0, 0, 0] = 2**19
    e = sr.Exposure.from_arrays(np.ones((4, 4, 4), np.float32), s, mask=flags)
    assert e.dq.dtype == np.uint32 and np.array_equal(e.dq, flags)
    assert e.data.mask[1, 2, 2] and e.data.mask[0, 0, 0]
    path = tmp_path / "ramps.fits"
    sr.write(e, path)
    with fits.open(path) as hdul:  # stored as int32, the same 32 bits
        assert hdul["DQ"].data.dtype.kind == "i" and hdul["DQ"].data.dtype.itemsize == 4
        assert np.array_equal(hdul["DQ"].data.astype(np.uint32), flags)
    back = sr.read(path)
    assert back.dq.dtype == np.uint32 and np.array_equal(back.dq, flags)
    out = sr.fit_ramp(back)
    assert out.dq.dtype == np.uint32
    # each flagged read left out; no bit set on every read, so the slopes are clean
    assert out.dq[2, 2] == 0 and out.dq[0, 0] == 0
    assert out.tables["RAMPFIT"]["nreads"][2][2] == 3
