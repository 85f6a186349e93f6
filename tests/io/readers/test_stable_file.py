"""Explicit reads of a file that must not change while it is read."""

import os

import numpy as np
import pytest

from spherex_reduce.core.errors import FormatError
from spherex_reduce.io.readers.stable_file import StableFile, pread_into


def _file(tmp_path, n=1000):
    path = tmp_path / "f.bin"
    values = (np.arange(n) * 0.5).astype(">f4")
    path.write_bytes(values.tobytes())
    return path, values


def test_reads_the_bytes_at_an_offset(tmp_path):
    path, values = _file(tmp_path)
    with StableFile(path) as f:
        got = f.read(4 * 100, ">f4", (3, 50))
    np.testing.assert_array_equal(got, values[100:250].reshape(3, 50))


def test_a_truncated_file_is_named(tmp_path):
    path, _ = _file(tmp_path)
    with StableFile(path) as f:
        os.truncate(path, 400)
        with pytest.raises(FormatError, match=r"f\.bin changed while it was read \(4000 bytes "
                                              r"when opened, now 400\)"):
            f.read(0, ">f4", (10,))


def test_a_file_rewritten_in_place_is_named(tmp_path):
    path, values = _file(tmp_path)
    with StableFile(path) as f:
        mtime = os.stat(path).st_mtime_ns
        path.write_bytes(values[::-1].tobytes())  # same size, other bytes
        os.utime(path, ns=(mtime, mtime + 10**9))
        with pytest.raises(FormatError, match="modified since it was opened"):
            f.read(0, ">f4", (10,))


def test_a_read_past_the_end_is_named(tmp_path):
    path, _ = _file(tmp_path, 10)
    fd = os.open(path, os.O_RDONLY)
    try:
        with pytest.raises(FormatError, match="ends inside frame 3"):
            pread_into(fd, np.empty(20, ">f4"), 0, "f.bin: the file ends inside frame 3")
    finally:
        os.close(fd)


def test_a_file_changed_while_its_checksums_are_verified_is_named(tmp_path, monkeypatch):
    """The reader's stamp is taken before the checks: a file rewritten while its checksums
    are verified (then read) is refused, not read as bytes nobody checked."""
    import time

    from spherex_reduce import write
    from spherex_reduce.io.examples import example_raw_exposure
    from spherex_reduce.io.readers import fits_read
    from spherex_reduce.io.readers.fits_read import CheckedFITS

    path = write(example_raw_exposure(seed=1), tmp_path / "raw.fits")
    verify = fits_read.bad_checksums

    def verify_then_change(p, hdus):
        bad = verify(p, hdus)
        time.sleep(0.01)  # a new modification time
        with open(p, "r+b") as f:  # the same size, other bytes (the last data block)
            f.seek(-8, os.SEEK_END)
            f.write(b"\x7f" * 8)
        return bad

    monkeypatch.setattr(fits_read, "bad_checksums", verify_then_change)
    reader = CheckedFITS(path)
    try:
        with pytest.raises(FormatError, match=r"raw\.fits changed while it was read"):
            reader.exposure()
    finally:
        reader.close()


def test_a_frame_of_a_file_cut_while_it_is_open_is_an_error_not_a_signal(tmp_path):
    """FrameReader.frame read from a memory map: a frame past the new end killed the
    process with SIGBUS.  It reads with pread now."""
    from spherex_reduce import write
    from spherex_reduce.io import FrameReader
    from spherex_reduce.io.examples import example_raw_exposure

    path = write(example_raw_exposure(seed=1), tmp_path / "raw.fits")
    with FrameReader(path) as frames:
        first = frames.frame(0).data.data
        os.truncate(path, path.stat().st_size // 2)
        with pytest.raises(FormatError, match=r"raw\.fits: the file ends inside frame"):
            frames.frame(frames.nframes - 1)
    assert np.isfinite(first).all()
