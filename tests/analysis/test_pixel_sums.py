"""`add_dark`: how a dark's bands are read and summed in threads."""

import threading

import numpy as np
import pytest

from spherex_reduce.analysis import pixel_sums
from spherex_reduce.analysis.pixel_sums import add_dark, new_sums


def _dark(seed=4, shape=(12, 40, 24)):
    rng = np.random.default_rng(seed)
    t = np.arange(shape[0]) * 1.5
    x = rng.normal(0.0, 4.0, shape) + 0.3 * t[:, None, None]
    x[7:, 5, 3] += 200.0  # a jump
    return x.astype(np.float32), t


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_the_sums_do_not_depend_on_the_threads(monkeypatch, threads):
    x, t = _dark()
    monkeypatch.setattr(pixel_sums, "PIXEL_THREADS", 1)
    one = new_sums(x.shape, t, 5.0)
    slopes1, jumped1 = add_dark(one, lambda sl: x[:, sl], x.shape, t, band_rows=4)
    monkeypatch.setattr(pixel_sums, "PIXEL_THREADS", threads)
    monkeypatch.setattr(pixel_sums, "default_threads", lambda: 4)
    many = new_sums(x.shape, t, 5.0)
    slopes, jumped = add_dark(many, lambda sl: x[:, sl], x.shape, t, band_rows=4)
    np.testing.assert_array_equal(slopes, slopes1)
    np.testing.assert_array_equal(jumped, jumped1)
    assert jumped[5, 3] and jumped.sum() == 1
    for key in ("wd", "wdt", "vr", "vs", "q", "kept", "jumps", "jsize", "offset", "lagq"):
        np.testing.assert_array_equal(many[key], one[key], err_msg=key)


def test_the_next_band_is_read_while_the_bands_before_it_are_summed(monkeypatch):
    """With two threads, band 2 is read while bands 0 and 1 are worked on (before, a
    group of two was read, summed and added before the next was read: the reads and the
    sums never overlapped)."""
    x, t = _dark()
    monkeypatch.setattr(pixel_sums, "PIXEL_THREADS", 2)
    monkeypatch.setattr(pixel_sums, "default_threads", lambda: 2)
    third_read, overlapped, starts = threading.Event(), [], {}
    work = pixel_sums._band

    def band(x_, *args, **kwargs):
        if starts[id(x_)][0] < 8:  # bands 0 and 1 wait (bounded) for band 2's read
            overlapped.append(third_read.wait(timeout=20))
        return work(x_, *args, **kwargs)

    def read(sl):
        if sl.start == 8:
            third_read.set()
        view = x[:, sl]
        starts[id(view)] = (sl.start, view)  # kept alive: its id is not reused
        return view

    monkeypatch.setattr(pixel_sums, "_band", band)
    slopes, _ = add_dark(new_sums(x.shape, t, 5.0), read, x.shape, t, band_rows=4)
    assert overlapped[:2] == [True, True]
    assert np.isfinite(slopes).all()
