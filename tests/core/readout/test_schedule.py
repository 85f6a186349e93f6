"""The readout schedule against hand-worked orders and the paper's numbers."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.core.readout.schedule import chopped_order


def test_paper_example_s4_on_16_rows():
    assert chopped_order(16, 4).tolist() == [0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15]


def test_chopping_by_brute_force_rule():
    """The paper's rule (§2.3) simulated literally: skip S-1 unread... rows, wrap, read."""
    def literal(n, s):
        read, order, pos = np.zeros(n, bool), [], 0
        while len(order) < n:
            order.append(pos)
            read[pos] = True
            nxt = pos + s
            if nxt >= n:  # wrap: return to the first unread row
                unread = np.flatnonzero(~read)
                if unread.size == 0:
                    break
                nxt = unread[0]
            pos = nxt
        return order

    for n in (1, 7, 16, 17, 100, 2040):
        for s in (1, 2, 3, 4, 7, 24, 99, n, n + 5):
            assert chopped_order(n, s).tolist() == literal(n, s), (n, s)


@pytest.mark.parametrize("skip", [1, 2, 3, 5, 7, 24, 56, 57, 1000])
@pytest.mark.parametrize("mode", ["none", "repeated", "distributed"])
def test_every_active_row_read_once(skip, mode):
    g = DetectorGeometry(64, 16, 2, ref_border=4)
    s = ReadoutSchedule(g, skip=skip, ref_reads=10, ref_mode=mode)
    active = s.rows[~s.is_reference]
    assert sorted(active.tolist()) == list(range(4, 60))
    assert set(s.rows[s.is_reference].tolist()) <= {0, 1, 2, 3, 60, 61, 62, 63}


def test_s1_and_s_ge_rows_are_physical():
    g = DetectorGeometry(40, 16, 1, ref_border=4)
    for skip in (1, 32, 33, 500):
        s = ReadoutSchedule(g, skip=skip, ref_mode="none")
        assert s.rows.tolist() == list(range(40))


@pytest.mark.parametrize("r", [1, 7, 8, 32, 100, 2040, 5000])
def test_distributed_reference_reads(r):
    s = ReadoutSchedule(skip=24, ref_reads=r, ref_mode="distributed")
    pos = np.flatnonzero(s.is_reference)
    assert pos.size == r
    if r > 1:
        gaps = np.diff(pos)
        assert gaps.max() - gaps.min() <= 1
    refs = s.rows[pos]
    assert refs.tolist() == [[0, 1, 2, 3, 2044, 2045, 2046, 2047][i % 8] for i in range(r)]
    counts = np.bincount(refs, minlength=2048)[[0, 1, 2, 3, 2044, 2045, 2046, 2047]]
    assert counts.max() - counts.min() <= 1  # each read about r/8 times


def test_repeated_reference_reads_in_place():
    s = ReadoutSchedule(skip=24, ref_reads=9, ref_mode="repeated")
    assert s.rows[:5].tolist() == [0, 1, 2, 3, 0]
    assert s.rows[-4:].tolist() == [2044, 2045, 2046, 2047]
    assert s.is_reference.sum() == 9
    assert not s.is_reference[5:-4].any()


def test_none_mode_reads_border_once():
    s = ReadoutSchedule(skip=24, ref_reads=32, ref_mode="none")
    assert s.rows[:4].tolist() == [0, 1, 2, 3]
    assert s.rows[-4:].tolist() == [2044, 2045, 2046, 2047]
    assert s.n_reads == 2048


def test_r0_means_no_reference_reads():
    s = ReadoutSchedule(ref_reads=0, ref_mode="distributed")
    assert s.n_reads == 2040 and not s.is_reference.any()
    assert (s.read_of_row()[[0, 2047]] == -1).all()


def test_paper_frame_time_and_integration():
    s = ReadoutSchedule()  # S=24, r=32 distributed, c=4 (Table 3)
    assert (s.skip, s.ref_reads, s.ref_mode, s.phantom_reads) == (24, 32, "distributed", 4)
    assert s.n_reads == 2040 + 32
    assert s.frame_time.to_value(u.s) == pytest.approx(1.51, abs=1e-12)
    assert s.integration_time.to_value(u.s) == pytest.approx(74 * 1.51)
    assert s.frame_samples == 151_000


def test_frame_time_given_directly():
    s = ReadoutSchedule(frame_time=2.0 * u.s, skip=3)
    assert s.frame_time == 2.0 * u.s
    assert s.frame_overhead == 200_000 - s.n_reads * s.row_samples
    with pytest.raises(ValueError, match="frame_time must be >="):
        ReadoutSchedule(frame_time=0.1)
    with pytest.raises(ValueError, match="give only one"):
        ReadoutSchedule(frame_time=2.0, frame_overhead=5)


def test_sample_times(small_schedule):
    s = small_schedule
    g = s.geometry
    samples = s.pixel_samples()
    assert samples.shape == (s.n_reads, g.ncols)
    # read i starts after i row reads and the c phantom samples of read i
    assert samples[:, 0].tolist() == (np.arange(s.n_reads) * (3 + 8 + 2) + 3).tolist()
    assert (np.diff(samples[:, :8], axis=1) == 1).all()
    ph = s.phantom_samples()
    assert ph.shape == (s.n_reads, 3)
    assert (ph[:, -1] + 1 == s.starts).all()
    assert s.pixel_times()[1, 0] == samples[1, 0] / g.pixel_rate * u.s
    assert s.frame_samples == s.n_reads * 13 + 50


def test_alternate_scan_reverses_odd_channels():
    g = DetectorGeometry(16, 16, 4, ref_border=0, scan="alternate")
    s = ReadoutSchedule(g, ref_reads=0, ref_mode="none", phantom_reads=0, row_overhead=0)
    first = s.pixel_samples()[0]
    assert first.tolist() == [0, 1, 2, 3, 3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0]
    g2 = DetectorGeometry(16, 16, 4, ref_border=0, scan=[1, 1, -1, 1])
    assert g2.scan_label == "++-+"


@pytest.mark.parametrize(
    ("kwargs", "width", "channels"),
    [
        ({"nchannels": 4, "scan": "alternate"}, 512, 4),  # JWST
        ({"nrows": 4096, "ncols": 4096, "nchannels": 32}, 128, 32),  # Roman H4RG
        ({"nrows": 64, "ncols": 128, "nchannels": 2, "ref_border": 0}, 64, 2),  # subarray
    ],
)
def test_other_layouts(kwargs, width, channels):
    g = DetectorGeometry(**kwargs)
    assert (g.channel_width, g.nchannels) == (width, channels)
    s = ReadoutSchedule(g, ref_reads=0 if g.ref_border == 0 else 8)
    assert sorted(s.rows[~s.is_reference]) == list(g.active_rows)


@pytest.mark.parametrize(
    ("make", "name", "allowed"),
    [
        (lambda: ReadoutSchedule(skip=0), "skip", ">= 1"),
        (lambda: ReadoutSchedule(ref_reads=-1), "ref_reads", ">= 0"),
        (lambda: ReadoutSchedule(phantom_reads=-2), "phantom_reads", ">= 0"),
        (lambda: ReadoutSchedule(nframes=0), "nframes", ">= 1"),
        (lambda: ReadoutSchedule(ref_mode="sometimes"), "ref_mode", "none"),
        (lambda: DetectorGeometry(ncols=2048, nchannels=30), "nchannels x channel width", "ncols"),
        (lambda: DetectorGeometry(nrows=8, ncols=8, nchannels=1, ref_border=4), "ref_border",
         "[0, 3]"),
        (lambda: DetectorGeometry(pixel_rate=-5), "pixel_rate", "positive"),
        (lambda: ReadoutSchedule(skip=2.5), "skip", "integer"),
        (lambda: DetectorGeometry(pixel_rate=float("nan")), "pixel_rate", "finite"),
        (lambda: DetectorGeometry(pixel_rate="100000"), "pixel_rate", "positive"),
        (lambda: DetectorGeometry(pixel_rate=True), "pixel_rate", "positive"),
        (lambda: ReadoutSchedule(frame_time=float("nan")), "frame_time", "finite"),
        (lambda: ReadoutSchedule(frame_time=float("inf")), "frame_time", "finite"),
        (lambda: ReadoutSchedule(frame_time=True), "frame_time", "positive"),
        (lambda: ReadoutSchedule(frame_time=1.51, frame_overhead=1816.5), "frame_overhead",
         "integer"),
        (lambda: ReadoutSchedule(frame_overhead=2**60), "frame_overhead", "in [0,"),
        (lambda: ReadoutSchedule(nframes=10**12), "nframes", "samples"),
    ],
)
def test_invalid_parameters_name_the_parameter(make, name, allowed):
    with pytest.raises(ValueError) as info:
        make()
    assert name in str(info.value) and allowed in str(info.value)


def test_reference_reads_need_a_border():
    g = DetectorGeometry(16, 16, 1, ref_border=0)
    with pytest.raises(ValueError, match="ref_border is 0"):
        ReadoutSchedule(g, ref_reads=4)
    assert ReadoutSchedule(g, ref_reads=0).n_reads == 16


def test_table_and_header_round_trip(small_schedule):
    t = small_schedule.to_table()
    assert t.colnames == ["read", "row", "kind", "start", "time"]
    assert t["time"].unit == u.s
    h = small_schedule.to_header()
    again = ReadoutSchedule.from_header(h, t)
    assert again == small_schedule
    assert np.array_equal(again.rows, small_schedule.rows)
    assert np.array_equal(again.pixel_samples(), small_schedule.pixel_samples())
