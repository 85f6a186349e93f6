"""The executor: kernels over bands of rows of memory or a file, into a consumer or an exposure."""

import threading
import time

import numpy as np
import pytest
from _toy_steps import FrameSum, NoteKernel, PerFrameNote, ToyPlugin, registry_with, write_raw

from spherex_reduce import Exposure, Pipeline, PluginError
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.io.sources import FileSource, MemorySource, context_of
from spherex_reduce.reduce.executor import bands, execute
from spherex_reduce.reduce.hookspecs import hookimpl
from spherex_reduce.reduce.options import RunOptions
from spherex_reduce.reduce.step import Consumer, Kernel


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=5)


def test_a_file_is_read_once_in_bands_of_reads_never_whole_frames(tmp_path, raw, monkeypatch):
    from spherex_reduce.io import FrameReader
    from spherex_reduce.io.sources import FileSource

    path = write_raw(tmp_path, raw)
    asked, frames = [], []
    original = FileSource.read
    monkeypatch.setattr(FileSource, "read", lambda self, lo, hi: (asked.append((lo, hi)),
                                                                  original(self, lo, hi))[1])
    monkeypatch.setattr(FrameReader, "frame", lambda self, k: frames.append(k))
    with patch_band_rows(monkeypatch, 5):
        Pipeline({"steps": ["unchop", "framesum"]}, registry=registry_with(ToyPlugin())).run(
            path, threads=2)
    covered = sorted(r for lo, hi in asked for r in range(lo, hi))
    assert covered == list(range(raw.schedule.n_reads))  # every read once
    assert max(hi - lo for lo, hi in asked) == 5 and frames == []


class patch_band_rows:
    """Bands of ``rows`` rows in the executor (small files would otherwise be one band)."""

    def __init__(self, monkeypatch, rows):
        from spherex_reduce.reduce import executor

        self.monkeypatch, self.executor, self.rows = monkeypatch, executor, rows

    def __enter__(self):
        ncols = 16
        self.monkeypatch.setattr(self.executor, "BAND_PIXELS", self.rows * ncols)
        return self

    def __exit__(self, *exc):
        return False


class _BrokenKernel(NoteKernel):
    def apply(self, means, block):
        if block.index[0] > 10:
            raise RuntimeError("kernel broke on a band")
        return super().apply(means, block)


class FailingNote(PerFrameNote):
    name, keyword = "failnote", "S_FAILN"

    def kernel(self, context):
        return _BrokenKernel(context)


class FailingPlugin:
    @hookimpl
    def register_steps(self):
        return [FrameSum, FailingNote]


def _band_threads():
    import threading

    return [t for t in threading.enumerate() if t.name.startswith("spherex-reduce-band")]


@pytest.mark.parametrize("threads", [1, 3])
def test_a_kernel_error_in_a_band_reaches_the_caller_and_leaves_no_thread(raw, monkeypatch,
                                                                          threads):
    pipe = Pipeline({"steps": ["unchop", "failnote", "framesum"]},
                    registry=registry_with(FailingPlugin()))
    with patch_band_rows(monkeypatch, 4), pytest.raises(PluginError,
                                                        match="kernel broke") as info:
        pipe.run(raw, threads=threads)
    assert isinstance(info.value.__cause__, RuntimeError)
    assert _band_threads() == []


# -- execute on its own: kernels and consumers made here, numpy as the reference -------------
class AddRowValue(Kernel):
    """Adds ``10 * row + 0.5`` to every pixel of each row (a per-row value known in advance)."""

    def apply(self, coefficients, block):
        return block.replace(data=block.data + (10.0 * block.index + 0.5)[None, :, None])


class RowLog(Consumer):
    """Keeps every band's rows, pixels and thread; its result is the exposure it was given."""

    def __init__(self, exposure):
        self.exposure, self.bands, self.threads = exposure, [], set()

    def band(self, block):
        self.bands.append((block.index.copy(), np.array(block.data)))
        self.threads.add(threading.current_thread().name)

    def finish(self, reference, header, tables):
        return self.exposure


class BreaksOnFirstRow(Kernel):
    """Raises on the band of row 0; every other band takes 20 ms. Records the bands it saw."""

    def __init__(self, context):
        super().__init__(context)
        self.seen = []

    def apply_side(self, coefficients, side):
        return side

    def apply(self, coefficients, block):
        self.seen.append(int(block.index[0]))
        if 0 in block.index:
            raise RuntimeError("broke on row 0")
        time.sleep(0.02)
        return block


@pytest.mark.parametrize("rows", [1, 2, 5, 13, 1000])
@pytest.mark.parametrize("threads", [1, 2, 3])
@pytest.mark.parametrize("ramp", [True, False])
def test_a_per_row_kernel_in_any_bands_and_threads_equals_numpy(raw, rows, threads, ramp):
    exposure = raw if ramp else Exposure.from_arrays(raw.data.data[0], raw.schedule)
    before = np.array(exposure.data.data)
    done = []
    out, _ = execute(MemorySource(exposure), [AddRowValue(context_of(exposure))],
                     options=RunOptions(threads=threads), rows_per_band=rows,
                     progress=done.append)
    nrows = before.shape[-2]
    expected = before + (10.0 * np.arange(nrows) + 0.5)[:, None]
    assert out.data.data.shape == before.shape
    np.testing.assert_array_equal(out.data.data, expected)
    np.testing.assert_array_equal(exposure.data.data, before)  # the input is not written
    if ramp:
        np.testing.assert_array_equal(out.phantom, raw.phantom)  # carried through untouched
    assert sum(done) == nrows and len(done) == -(-nrows // rows)


@pytest.mark.parametrize(("threads", "expected"), [(1, 3), (3, 3), (4, 5), (8, 5)])
def test_memory_bands_are_doubled_only_while_every_thread_has_one(raw, monkeypatch, threads,
                                                                  expected):
    # 8 rows of 16 columns per file band, 16 in memory; the readout frame has 34 reads
    import spherex_reduce.reduce.executor as executor

    monkeypatch.setattr(executor, "BAND_PIXELS", 8 * raw.data.data.shape[-1])
    assert raw.data.data.shape[-2] == 34
    out, stats = execute(MemorySource(raw), [AddRowValue(context_of(raw))],
                         options=RunOptions(threads=threads))
    assert stats.bands == expected  # 34 rows: 3 bands of 16 rows, else 5 of 8
    np.testing.assert_array_equal(out.data.data, raw.data.data + (10.0 * np.arange(34)
                                                                  + 0.5)[:, None])


class LessFrameMean(Kernel):
    """Needs the whole exposure: minus each frame's mean over every pixel, in place where the
    block may be written; keeps the exposure its estimate saw."""

    needs_exposure = True

    def prepare(self, side, exposure=None):
        self.seen, self.saw = exposure.data.data, np.array(exposure.data.data)
        return np.asarray(exposure.data.data, np.float64).mean(axis=(1, 2))

    def apply(self, means, block):
        out = block.writable(np.float64)
        for f in range(out.shape[0]):
            out[f] -= means[f]
        return block.replace(data=out, owned=block.owned | {"data"})


@pytest.mark.parametrize("rows", [1, 5, 1000])
@pytest.mark.parametrize("threads", [1, 3])
def test_a_kernel_needing_the_exposure_after_another_sees_its_output(raw, rows, threads):
    exposure = Exposure.from_arrays(np.asarray(raw.data.data, np.float64), raw.schedule)
    before = np.array(exposure.data.data)
    whole = LessFrameMean(context_of(exposure))
    out, stats = execute(MemorySource(exposure), [AddRowValue(context_of(exposure)), whole],
                         options=RunOptions(threads=threads), rows_per_band=rows)
    nrows = before.shape[-2]
    added = before + (10.0 * np.arange(nrows) + 0.5)[:, None]
    np.testing.assert_array_equal(whole.saw, added)  # the first kernel's output
    expected = added - added.mean(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(out.data.data, expected, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(exposure.data.data, before)  # the input is not written
    # corrected in place: the output is the exposure the first stage made
    assert np.shares_memory(out.data.data, whole.seen)
    assert len(stats.kernels) == 2 and stats.stages == 2


def test_a_staged_pass_reports_every_row_once_over_its_two_stages(raw):
    exposure = Exposure.from_arrays(np.asarray(raw.data.data, np.float64), raw.schedule)
    done = []
    execute(MemorySource(exposure), [AddRowValue(context_of(exposure)),
                                     LessFrameMean(context_of(exposure))],
            options=RunOptions(threads=2), rows_per_band=5, progress=done.append)
    nrows = exposure.data.data.shape[-2]
    assert sum(done) == nrows and all(isinstance(n, int) and n > 0 for n in done)
    assert len(done) > -(-nrows // 5)  # more calls than one stage has bands: both told


def test_an_exposure_of_the_callers_is_never_written_by_a_kernel_needing_it(raw):
    exposure = Exposure.from_arrays(np.asarray(raw.data.data, np.float64), raw.schedule)
    before = np.array(exposure.data.data)
    out, _ = execute(MemorySource(exposure), [LessFrameMean(context_of(exposure))],
                     options=RunOptions(threads=2), rows_per_band=3)
    np.testing.assert_array_equal(exposure.data.data, before)
    assert not np.shares_memory(out.data.data, exposure.data.data)
    np.testing.assert_allclose(out.data.data, before - before.mean(axis=(1, 2))[:, None, None],
                               rtol=0, atol=1e-9)


@pytest.mark.parametrize("rows", [1, 4, 7, 1000])
@pytest.mark.parametrize("threads", [1, 3])
def test_a_consumer_sees_every_row_of_memory_exactly_once(raw, rows, threads):
    source = MemorySource(raw)
    log = RowLog(raw)
    result, stats = execute(source, [], log, options=RunOptions(threads=threads),
                            rows_per_band=rows)
    assert result is raw
    seen = np.concatenate([idx for idx, _ in log.bands])
    assert np.array_equal(np.sort(seen), np.arange(raw.schedule.n_reads))  # once each
    for idx, data in log.bands:
        np.testing.assert_array_equal(data, raw.data.data[:, idx])
        assert len(idx) <= rows
    nbands = -(-raw.schedule.n_reads // rows)
    assert stats.bands == len(log.bands) == nbands
    assert stats.threads == threads and stats.kernels == ()
    assert stats.consumer > 0 and stats.read > 0
    if threads == 1 or nbands == 1:
        assert log.threads == {threading.current_thread().name}


@pytest.mark.parametrize("threads", [1, 3])
def test_a_consumer_sees_every_row_of_a_file_exactly_once(tmp_path, raw, threads):
    from spherex_reduce.io import FrameReader

    path = write_raw(tmp_path, raw)
    with FrameReader(path) as reader:
        source = FileSource(reader)
        log = RowLog(raw)
        execute(source, [], log, options=RunOptions(threads=threads), rows_per_band=3)
    seen = np.concatenate([idx for idx, _ in log.bands])
    assert np.array_equal(np.sort(seen), np.arange(raw.schedule.n_reads))
    for idx, data in log.bands:
        np.testing.assert_array_equal(data, raw.data.data[:, idx])


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_an_error_in_a_band_reaches_the_caller_and_the_bands_not_started_never_run(raw,
                                                                                   threads):
    kernel = BreaksOnFirstRow(context_of(raw))
    with pytest.raises(RuntimeError, match="broke on row 0"):
        execute(MemorySource(raw), [kernel], options=RunOptions(threads=threads),
                rows_per_band=1)
    if threads == 1:  # in order: nothing after the failing band
        assert kernel.seen == [0]
    # 34 bands of one row: only those already running when band 0 failed ran
    assert 0 in kernel.seen and len(kernel.seen) <= 2 * threads < raw.schedule.n_reads
    assert _band_threads() == []


def test_bands_cover_the_rows_in_order_without_overlap():
    assert bands(10, 3) == [(0, 3), (3, 6), (6, 9), (9, 10)]
    assert bands(4, 4) == bands(4, 100) == [(0, 4)]
    assert bands(3, 0) == [(0, 1), (1, 2), (2, 3)]  # at least one row per band
    assert bands(0, 5) == []
