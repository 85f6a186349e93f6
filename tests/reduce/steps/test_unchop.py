"""Un-chopping against the schedule's definition, on encoded data."""

import numpy as np
import pytest

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    ReadoutSchedule,
    StepSkipped,
    dq,
    rechop,
    unchop,
)
from spherex_reduce.reduce.steps.unchop import UnchopStep


def encoded(schedule, nframes=2):
    """Ramps whose value encodes (frame, read, column); reads are known independently."""
    f, r, c = np.meshgrid(np.arange(nframes), np.arange(schedule.n_reads),
                          np.arange(schedule.geometry.ncols), indexing="ij")
    data = (f * 1e6 + r * 1e3 + c).astype(np.float64)
    phantom = (f * 1e6 + r * 1e3)[:, :, : schedule.geometry.nchannels] - 1.0
    return Exposure.from_arrays(data, schedule.replace(nframes=nframes), phantom=phantom)


@pytest.mark.parametrize("skip", [1, 3, 5, 40])
@pytest.mark.parametrize("mode", ["none", "repeated", "distributed"])
def test_rows_land_where_they_were_read(skip, mode):
    g = DetectorGeometry(20, 8, 2, ref_border=2)
    s = ReadoutSchedule(g, skip=skip, ref_reads=5, ref_mode=mode, phantom_reads=1, nframes=2)
    raw = encoded(s)
    out = unchop(raw)
    assert out.order == "physical" and out.shape == (2, 20, 8)
    for read_index, row in enumerate(s.rows):  # brute force over the schedule's reads
        if not s.is_reference[read_index]:
            expected = np.arange(2)[:, None] * 1e6 + read_index * 1e3 + np.arange(8)
            np.testing.assert_array_equal(out.data.data[:, row, :], expected)
            np.testing.assert_array_equal(out.phantom[:, row, :],
                                          np.broadcast_to(expected[:, :1] - 1.0, (2, 2)))
    # reference reads kept aside with their read index, hence their time
    ref_reads = np.flatnonzero(s.is_reference)
    np.testing.assert_array_equal(out.reference.reads, ref_reads)
    np.testing.assert_array_equal(out.reference.rows, s.rows[ref_reads])
    np.testing.assert_array_equal(out.reference.data[:, :, 0], ref_reads[None, :] * 1e3
                                  + np.arange(2)[:, None] * 1e6)
    # a re-read reference row holds the mean of its reads
    for row in set(s.rows[ref_reads].tolist()):
        idx = np.flatnonzero(s.rows == row)
        np.testing.assert_allclose(out.data.data[:, row, 0],
                                   np.arange(2) * 1e6 + idx.mean() * 1e3)


def test_unchop_then_rechop_is_identity(small_schedule):
    raw = encoded(small_schedule, nframes=3)
    back = rechop(unchop(raw))
    np.testing.assert_array_equal(back.data.data, raw.data.data)
    np.testing.assert_array_equal(back.phantom, raw.phantom)


def test_input_not_modified(small_schedule):
    raw = encoded(small_schedule)
    raw.data.data.setflags(write=False)
    raw.phantom.setflags(write=False)
    copy = raw.data.data.copy()
    unchop(raw)
    np.testing.assert_array_equal(raw.data.data, copy)
    assert raw.order == "readout"


def test_rows_never_read_are_nan_and_flagged():
    g = DetectorGeometry(12, 8, 1, ref_border=2)
    s = ReadoutSchedule(g, skip=3, ref_reads=0, phantom_reads=0, nframes=1)
    out = unchop(Exposure.from_arrays(np.ones((s.n_reads, 8)), s))
    assert np.isnan(out.data.data[[0, 1, 10, 11]]).all()
    assert (out.dq[[0, 1, 10, 11]] & dq.NOT_READ).all() and out.data.mask[[0, 1, 10, 11]].all()
    assert not out.data.mask[2:10].any() and np.isfinite(out.data.data[2:10]).all()
    assert out.reference.data.shape == (0, 8)


def test_slopes_with_uncertainty(small_schedule):
    n = small_schedule.n_reads
    e = Exposure.from_arrays(np.arange(n * 16.0).reshape(n, 16), small_schedule,
                             uncertainty=np.ones((n, 16)))
    out = unchop(e)
    assert out.data.uncertainty.array.shape == (32, 16)
    for row in set(small_schedule.rows[small_schedule.is_reference].tolist()):
        k = int((small_schedule.rows == row).sum())
        np.testing.assert_allclose(out.data.uncertainty.array[row], 1 / np.sqrt(k))


def test_uncertainty_of_a_re_read_row_with_unequal_and_unusable_reads(small_schedule):
    # the mean of the usable reads has sigma sqrt(sum sigma_i^2) / n, not mean(sigma)/sqrt(N)
    s = small_schedule
    n = s.n_reads
    rng = np.random.default_rng(3)
    sigma = rng.uniform(1, 5, (n, 16))
    data = rng.normal(0, 1, (n, 16))
    flags = np.zeros((n, 16), np.uint16)
    row = int(s.rows[s.is_reference][0])
    reads = np.flatnonzero(s.rows == row)
    assert reads.size >= 2
    data[reads[0], 2] = np.nan  # unusable: not finite
    flags[reads[1], 3] = dq.DO_NOT_USE  # unusable: flagged
    out = unchop(Exposure.from_arrays(data, s, uncertainty=sigma, mask=flags))
    for col in range(16):
        use = [r for r in reads if np.isfinite(data[r, col]) and flags[r, col] == 0]
        expected = np.sqrt(sum(sigma[r, col] ** 2 for r in use)) / len(use)
        np.testing.assert_allclose(out.data.uncertainty.array[row, col], expected, rtol=1e-12)
        np.testing.assert_allclose(out.data.data[row, col], np.mean(data[use, col]),
                                   rtol=1e-12)


def test_already_physical_is_skipped(small_schedule):
    out = unchop(encoded(small_schedule))
    again = unchop(out)  # skipped, stpipe style: the input back, the status recorded
    assert again.header["S_UNCHOP"] == "SKIPPED"
    assert any("already in physical order" in str(h) for h in again.header["HISTORY"])
    assert again.tables["PROVENANCE"]["status"].tolist() == ["COMPLETE", "SKIPPED"]
    assert again.tables["PROVENANCE"]["route"][1] == (
        "skipped: the exposure is already in physical order")
    np.testing.assert_array_equal(again.data.data, out.data.data)
    with pytest.raises(StepSkipped, match="already in physical order"):
        UnchopStep().run(out)  # the step's own run says why


def test_rereads_average_only_usable_reads():
    g = DetectorGeometry(8, 4, 1, ref_border=1)
    s = ReadoutSchedule(g, skip=1, ref_reads=4, ref_mode="repeated", phantom_reads=0,
                        nframes=1)
    data = np.ones((s.n_reads, 4))
    flags = np.zeros(data.shape, np.uint16)
    reads_of_row0 = np.flatnonzero(s.rows == 0)
    assert reads_of_row0.size == 2
    data[reads_of_row0[0]] = [np.nan, 1e4, 3.0, 3.0]
    flags[reads_of_row0[0], 1] = dq.SATURATED
    flags[reads_of_row0, 2:] = dq.DO_NOT_USE  # both reads flagged: the row is flagged there
    out = unchop(Exposure.from_arrays(data, s, mask=flags))
    # column 0: the NaN read is not usable, column 1: the flagged read is not
    np.testing.assert_array_equal(out.data.data[0, :2], [1.0, 1.0])
    assert np.isnan(out.data.data[0, 2:]).all()
    assert out.dq[0].tolist() == [0, 0, dq.DO_NOT_USE, dq.DO_NOT_USE]
    pos = out.reference.reads.tolist().index(reads_of_row0[0])
    np.testing.assert_array_equal(out.reference.dq[pos], flags[reads_of_row0[0]])
