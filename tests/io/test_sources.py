"""open_input, the one entry point for inputs: every layout gives the pixels astropy reads.

Each input is built here from small arrays and written with astropy; the bands
and side blocks a source serves are compared with numpy slices of what
``astropy.io.fits`` reads from the same file (or of the array given).
"""

import hashlib

import numpy as np
import pytest
from astropy.io import fits

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, write
from spherex_reduce.core.errors import FormatError
from spherex_reduce.io import FrameReader
from spherex_reduce.io.readers.read_files import read_file_paths
from spherex_reduce.io.sources import FileSource, MemorySource, Source, open_input

GEOMETRY = DetectorGeometry(16, 8, 2, ref_border=2, pixel_rate=1e5)


def _schedule(nframes=4, **readout):
    return ReadoutSchedule(GEOMETRY, **{"skip": 3, "ref_reads": 4, "ref_mode": "repeated",
                                        "phantom_reads": 0, "nframes": nframes, **readout})


def _ramps(schedule, seed=3):
    rng = np.random.default_rng(seed)
    return rng.normal(100, 5, (schedule.nframes, schedule.n_reads, 8)).astype(np.float32)


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def raw(tmp_path):
    s = _schedule()
    path = tmp_path / "raw.fits"
    write(Exposure.from_arrays(_ramps(s), s), path)
    return path


def test_an_exposure_is_served_as_views_of_its_arrays():
    s = _schedule()
    ramps = _ramps(s)
    with open_input(Exposure.from_arrays(ramps, s)) as inp:
        source = inp.source()
        assert isinstance(source, MemorySource) and inp.integrations is None
        band = source.read(2, 7)
        np.testing.assert_array_equal(band.data, ramps[:, 2:7])
        assert np.shares_memory(band.data, source.exposure().data.data)
        side = source.side()
        expected = np.flatnonzero(s.is_reference)
        assert set(expected) <= set(side.index)
        np.testing.assert_array_equal(side.data, ramps[:, side.index])


def test_a_raw_file_is_read_in_bands_equal_to_astropys_pixels(raw):
    before = _digest(raw)
    stored = fits.getdata(raw, "SCI")
    with open_input(raw) as inp:
        source = inp.source()
        assert isinstance(source, FileSource) and source.where == "a file"
        for lo, hi in [(0, 1), (3, 9), (0, source.nrows)]:
            np.testing.assert_array_equal(source.read(lo, hi).data, stored[:, lo:hi])
        np.testing.assert_array_equal(source.exposure().data.data, stored)
    assert _digest(raw) == before


def test_a_scaled_integer_file_is_read_whole_in_physical_values(tmp_path):
    s = _schedule()
    ramps = np.round(_ramps(s)).astype(np.int16)
    path = tmp_path / "int.fits"
    header = s.to_header()
    hdu = fits.ImageHDU(ramps, name="SCI")
    hdu.header["BZERO"], hdu.header["BSCALE"] = 10.0, 2.0
    fits.HDUList([fits.PrimaryHDU(header=header), hdu]).writeto(path)
    stored = fits.getdata(path, "SCI")  # astropy applies BSCALE/BZERO
    with open_input(path) as inp:
        source = inp.source()
        assert isinstance(source, MemorySource)  # scaled: not readable in bands
        np.testing.assert_allclose(source.read(0, source.nrows).data, stored)


def test_files_one_per_read_as_a_list_and_a_glob_only_when_expanded(tmp_path):
    s = _schedule(nframes=3, skip=1, ref_mode="none")
    ramps = _ramps(s)
    header = s.to_header()
    header["ORDER"] = "READOUT"
    for k in range(3):
        fits.PrimaryHDU(ramps[k], header).writeto(tmp_path / f"read_{k + 1}.fits")
    paths = [tmp_path / f"read_{k + 1}.fits" for k in range(3)]
    pattern = str(tmp_path / "read_*.fits")
    for given in (paths, read_file_paths(pattern)):
        with open_input(given) as inp:
            source = inp.source()
            assert source.nrows == s.n_reads
            np.testing.assert_array_equal(source.read(0, source.nrows).data, ramps)
    # a pattern given as a path is a path: no file of that name (never a silent expansion)
    with pytest.raises(FileNotFoundError, match="no such file"):
        open_input(pattern)


def test_a_4d_file_gives_one_source_per_integration(tmp_path, raw):
    stored = fits.getdata(raw, "SCI")
    cube = np.stack([stored, stored * 2 + 1])
    path = tmp_path / "uncal.fits"
    with fits.open(raw) as hdul:
        copies = fits.HDUList([h.copy() for h in hdul])
        copies["SCI"].data = cube
        copies.writeto(path, checksum=True)
    with open_input(path) as inp:
        assert inp.integrations == 2
        for k in range(2):
            np.testing.assert_array_equal(inp.source(k).read(0, stored.shape[1]).data, cube[k])
        with pytest.raises(FormatError, match="4-D"):
            inp.source()


def test_an_open_reader_or_source_is_used_and_left_open(raw):
    with FrameReader(raw) as reader:
        with open_input(reader) as inp:
            inp.source().read(0, 2)
        assert reader.reads(0, 0, 1).shape == (1, 8)  # still open
        source = FileSource(reader)
        with open_input(source) as inp:
            assert inp.source() is source
        assert isinstance(source, Source)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.fits"):
        open_input(tmp_path / "nope.fits")


def test_an_integration_of_an_input_without_integrations_is_refused():
    with open_input(Exposure.from_arrays(_ramps(_schedule()), _schedule())) as inp:
        with pytest.raises(FormatError, match="integration=1 given"):
            inp.source(integration=1)


def test_rows_in_any_order_are_taken_from_a_file_and_from_memory(raw):
    """`Source.take` (characterize's per-pixel bands: each row's first read, in physical row
    order) gives the rows asked for, in their order, repeated or not, as astropy's pixels."""
    stored = fits.getdata(raw, "SCI")
    rows = np.array([7, 2, 3, 3, 0])
    with open_input(raw) as inp:
        source = inp.source()
        np.testing.assert_array_equal(source.take(rows), stored[:, rows])
        np.testing.assert_array_equal(source.take([4, 5, 6]), stored[:, 4:7])
        with pytest.raises(IndexError):
            source.take([source.nrows])
        memory = MemorySource(source.exposure())
    np.testing.assert_array_equal(memory.take(rows), stored[:, rows])


def test_the_first_frames_of_a_file_and_of_memory_are_astropys_first_frames(tmp_path):
    """`Source.first_frames` (characterize reduces each dark at its first N reads): bands,
    side block, rows and phantom values of the first N frames as astropy reads them, the
    file's later frames never read, the original source and its reader left as they were."""
    s = _schedule(nframes=5, phantom_reads=2)
    rng = np.random.default_rng(8)
    phantom = rng.normal(size=(5, s.n_reads, GEOMETRY.nchannels))
    path = tmp_path / "raw.fits"
    write(Exposure.from_arrays(_ramps(s), s, phantom=phantom), path)
    stored = fits.getdata(path, "SCI")
    with open_input(path) as inp:
        source = inp.source()
        asked = []
        reads, into = source.reader.reads, source.reader.reads_into
        source.reader.reads = lambda k, lo, hi: (asked.append(k), reads(k, lo, hi))[1]
        source.reader.reads_into = lambda out, runs: (asked.extend(range(out.shape[0])),
                                                      into(out, runs))[1]
        cut = source.first_frames(3)
        memory = MemorySource(Exposure.from_arrays(stored, s, phantom=phantom)).first_frames(3)
        for got in (cut, memory):
            assert got.context.schedule.nframes == 3 and got.nrows == source.nrows
            band = got.read(2, 9)
            np.testing.assert_array_equal(band.data, stored[:3, 2:9])
            np.testing.assert_allclose(band.phantom, phantom[:3, 2:9], rtol=1e-6)
            side = got.side()
            np.testing.assert_array_equal(side.data, stored[:3, side.index])
            np.testing.assert_array_equal(got.take([6, 1]), stored[:3, [6, 1]])
            whole = got.exposure()
            assert whole.schedule.nframes == 3
            np.testing.assert_array_equal(whole.data.data, stored[:3])
        assert asked and max(asked) == 2  # the whole exposure above reads astropy's way
        asked.clear()
        cut.close()  # the cut does not own the reader
        np.testing.assert_array_equal(source.read(0, 4).data, stored[:, 0:4])
        assert sorted(set(asked)) == [0, 1, 2, 3, 4]
        for bad in (0, 6):
            with pytest.raises(ValueError, match="first frames"):
                source.first_frames(bad)


@pytest.mark.parametrize("threads", [1, 3])
def test_the_first_frames_of_a_file_read_whole_once_for_all_cuts(raw, threads):
    """A step that needs the whole exposure, on cuts of one file to its first N frames (the
    slope scatter's grid, whose frame counts are reduced in threads): the file is read whole
    once, not once per cut, even by cuts asking at once (a slow read, as of a large file,
    was read once per thread), and each cut is astropy's first N frames."""
    import time
    from concurrent.futures import ThreadPoolExecutor

    stored = fits.getdata(raw, "SCI")
    with open_input(raw) as inp:
        source = inp.source()
        calls = []
        whole = source.reader.exposure

        def slow():
            calls.append(1)
            time.sleep(0.2)
            return whole()

        source.reader.exposure = slow
        with ThreadPoolExecutor(threads) as pool:  # the whole length is a cut too
            got = list(pool.map(lambda n: source.first_frames(n).exposure(), (4, 1, 2, 3)))
        for n, cut in zip((4, 1, 2, 3), got, strict=True):  # of 4 frames
            np.testing.assert_array_equal(cut.data.data, stored[:n])
        assert len(calls) == 1
