"""``side_columns`` of the ``mean`` and ``acn`` strategies: only the side reference columns are
read, and their pixels join their channel's mean as numpy's plain mean says."""

import tracemalloc
import warnings

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, correct_reference
from spherex_reduce.io.sources import context_of, side_block
from spherex_reduce.reduce.steps.reference.strategies import MeanReference
from spherex_reduce.reduce.steps.reference.telegraph import find_telegraph


def _exposure(nframes=6, nrows=40, ncols=64, seed=0):
    """SIDECAR-like ramps: 4 outputs, a 4-pixel border all round (side columns on the outer
    two outputs), reference rows read at the start and end of each frame."""
    g = DetectorGeometry(nrows, ncols, 4, ref_border=4)
    s = ReadoutSchedule(g, skip=1, ref_reads=0, ref_mode="none", phantom_reads=0,
                        nframes=nframes)
    rng = np.random.default_rng(seed)
    data = rng.normal(0, 4.0, (nframes, s.n_reads, ncols)) + rng.normal(0, 300, (s.n_reads,
                                                                              ncols))
    data += rng.normal(0, 20, (nframes, 1, 4)).repeat(ncols // 4, axis=2)  # channel offsets
    return Exposure.from_arrays(data, s), data


@pytest.mark.parametrize("strategy", ["mean", "acn"])
def test_side_pixels_join_their_channels_plain_mean(strategy):
    """Unclipped, a channel's offset is the mean of its reference-row pixels and (outer
    outputs) its side-column pixels of the active rows, per frame and parity (numpy here);
    the light-sensitive pixels of the active rows are never read: garbage there changes
    nothing."""
    e, data = _exposure()
    s = e.schedule
    g = s.geometry
    garbage = data.copy()
    light = ~g.reference_column_mask()
    garbage[:, s.active_read_indices[:, None], np.flatnonzero(light)] = np.nan
    garbage[:, s.active_read_indices[::3, None], np.flatnonzero(light)] = 1e300
    expected = np.empty((s.nframes, g.nchannels, 2 if strategy == "acn" else 1))
    ref, side = data[:, s.is_reference], data[:, s.active_read_indices]
    parity = g.column_offsets() % 2
    for ch in range(g.nchannels):
        for p in range(expected.shape[2]):
            cols = (g.channel_of_column() == ch) & ((parity == p) | (strategy == "mean"))
            pixels = [ref[:, :, cols], side[:, :, cols & ~light]]
            expected[:, ch, p] = (sum(x.sum(axis=(1, 2)) for x in pixels)
                                  / sum(x[0].size for x in pixels))
    for values in (data, garbage):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # side columns on the outer channels only
            t = correct_reference(Exposure.from_arrays(values, s), strategy, sigma=1e30,
                                  maxiters=1, side_columns=True).tables["REFOFFS"]
        got = np.asarray(t["offset"].value).reshape(expected.shape)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


def _peak_bytes(strategy, exposure):
    """Peak of the memory numpy allocates while ``strategy`` estimates (a second call)."""
    side, context = side_block(exposure), context_of(exposure)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # side columns on the outer channels only
        strategy.estimate(side, context, exposure)
        tracemalloc.start()
        try:
            strategy.estimate(side, context, exposure)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()


def test_side_columns_cost_no_full_size_copy():
    """The side columns are 8 of 1024 columns: the estimate reads those (and the reference
    rows) alone, so they add memory in proportion to their pixels, not the exposure's.  It
    copied every column of every active row into a float64 array and gathered it again
    (3x the exposure here; issue 34: 15-22x the time of ``mean`` without them at
    2048² x 10; now ~1.1x)."""
    e, data = _exposure(nframes=10, nrows=128, ncols=1024)
    extra = (_peak_bytes(MeanReference(side_columns=True), e)
             - _peak_bytes(MeanReference(side_columns=False), e))
    assert extra < 0.3 * data.nbytes, (extra, data.nbytes)


def test_telegraph_search_on_some_columns_names_detector_columns():
    """``columns``: the values hold those detector columns only (the side columns); what is
    found is named by detector column and its reads by the values' columns."""
    g = DetectorGeometry(64, 64, 2, ref_border=4)
    rng = np.random.default_rng(0)
    reads, rows = 40, np.arange(4, 60)
    cols = np.flatnonzero(g.reference_column_mask())  # 0-3 and 60-63
    values = rng.normal(0, 1, (reads, rows.size, cols.size))
    values[:, 10, 5] += 6 * (rng.random(reads) < 0.5)  # row 14, detector column 61
    found = find_telegraph(values, rows, g, columns=cols)
    assert list(zip(found.rows.tolist(), found.columns.tolist(), strict=True)) == [(14, 61)]
    assert found.channels.tolist() == [1] and found.reads.shape == (rows.size, cols.size)
    assert np.flatnonzero(found.reads[10]).tolist() == [5] and found.reads.sum() == 1
