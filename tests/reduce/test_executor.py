"""The executor: kernels over bands of rows of memory or a file, into a consumer or an exposure."""

import pytest
from _toy_steps import FrameSum, NoteKernel, PerFrameNote, ToyPlugin, registry_with, write_raw

from spherex_reduce import Pipeline, PluginError
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.reduce.hookspecs import hookimpl


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=5)


def test_a_file_is_read_once_in_bands_of_reads_never_whole_frames(tmp_path, raw, monkeypatch):
    from spherex_reduce.io import FrameReader
    from spherex_reduce.reduce.executor import FileSource

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
