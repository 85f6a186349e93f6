"""`dark_streams`: bands of reads summed in threads while the next is read.

(What the streams are, against numpy: ``test_characterize.py``'s
``test_the_streams_of_bands_are_the_channel_means_numpy_takes``.)
"""

import threading

import numpy as np
import pytest

from spherex_reduce.analysis.characterize import streams
from spherex_reduce.analysis.characterize.streams import dark_streams
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.io.sources import MemorySource


def _arrays(st):
    return [st.sum, st.diff, st.phantom, st.reference_rows, st.reference_kept,
            *st.reference_sides.values()]


@pytest.mark.parametrize("threads", [2, 3])
def test_the_streams_do_not_depend_on_the_threads(monkeypatch, threads):
    e = example_raw_exposure()
    monkeypatch.setattr(streams, "STREAM_THREADS", 1)
    one = dark_streams(MemorySource(e), [slice(0, 3), slice(None)], band_reads=5)
    monkeypatch.setattr(streams, "STREAM_THREADS", threads)
    monkeypatch.setattr(streams, "default_threads", lambda: 4)
    many = dark_streams(MemorySource(e), [slice(0, 3), slice(None)], band_reads=5)
    for a, b in zip(one, many, strict=True):
        for x, y in zip(_arrays(a), _arrays(b), strict=True):
            np.testing.assert_array_equal(x, y)
        assert a.boxes == b.boxes


def test_the_next_band_is_read_while_the_bands_before_it_are_summed(monkeypatch):
    """With two threads, band 2 is read while bands 0 and 1 are summed (a band's sums wait,
    bounded, for that read: one read after another, they would wait in vain)."""
    e = example_raw_exposure()
    source = MemorySource(e)
    third_read, waited = threading.Event(), {}
    read = source.read

    def reading(lo, hi):
        if lo == 10:
            third_read.set()
        return read(lo, hi)

    kept_sum = streams._kept_sum

    def summing(data, cols, drop):
        me = threading.get_ident()
        if me not in waited and len(waited) < 2:
            waited[me] = third_read.wait(timeout=20)
        return kept_sum(data, cols, drop)

    monkeypatch.setattr(source, "read", reading)
    monkeypatch.setattr(streams, "_kept_sum", summing)
    monkeypatch.setattr(streams, "STREAM_THREADS", 2)
    monkeypatch.setattr(streams, "default_threads", lambda: 2)
    st = dark_streams(source, [slice(None)], band_reads=5)[0]
    assert list(waited.values()) == [True, True]
    assert np.isfinite(st.sum).all()
