"""The stored image <-> readout frame mapping, checked against definitions written here.

Every expectation is built from the layout's definition by loops in the test (which
stored pixel a channel reads k-th, when), never from the mapping under test.
"""

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, ReadoutSchedule, RefBorder
from spherex_reduce.core.channel_layout import ChannelLayout, stored_pixel_times
from spherex_reduce.core.presets import PRESETS

LAYOUTS = [("columns", "outer", "rows"), ("rows", "outer", "rows"),
           *(("quadrants", c, f) for c in ("outer", "inner") for f in ("rows", "columns"))]


def _quadrant_read_order(nrows, ncols, corner, fast):
    """Stored (row, column) of each quadrant's pixels in the order they are read: the
    first-read corner, then along the fast axis toward the quadrant's other side."""
    h, w = nrows // 2, ncols // 2
    orders = []
    for q in range(4):
        top, left = q // 2, q % 2  # quadrant 0: rows and columns from 0
        outer_row = 0 if top == 0 else nrows - 1
        outer_col = 0 if left == 0 else ncols - 1
        inner_row = h - 1 if top == 0 else h
        inner_col = w - 1 if left == 0 else w
        r0, c0 = (outer_row, outer_col) if corner == "outer" else (inner_row, inner_col)
        dr = 1 if r0 in (0, h) else -1
        dc = 1 if c0 in (0, w) else -1
        order = []
        if fast == "rows":
            for slow in range(h):
                order.append([(r0 + dr * slow, c0 + dc * k) for k in range(w)])
        else:
            for slow in range(w):
                order.append([(r0 + dr * k, c0 + dc * slow) for k in range(h)])
        orders.append(order)
    return orders


@pytest.mark.parametrize(("channels", "corner", "fast"), LAYOUTS)
def test_mapping_is_its_own_exact_inverse_on_any_leading_axes(channels, corner, fast):
    lay = ChannelLayout(6, 10, channels, corner, fast) if channels != "rows" else \
        ChannelLayout(6, 10, channels)
    rng = np.random.default_rng(0)
    for shape in [(6, 10), (3, 6, 10), (2, 3, 6, 10)]:
        a = rng.normal(size=shape)
        frame = lay.to_readout(a)
        assert frame.shape == (*shape[:-2], *lay.frame_shape)
        assert np.array_equal(lay.to_stored(frame), a)
        assert np.array_equal(lay.to_readout(lay.to_stored(frame)), frame)


def test_columns_and_rows_are_views():
    a = np.arange(60.0).reshape(6, 10)
    assert ChannelLayout(6, 10).to_readout(a) is a
    view = ChannelLayout(6, 10, "rows").to_readout(a)
    assert np.shares_memory(view, a) and np.array_equal(view, a.T)


@pytest.mark.parametrize("corner", ["outer", "inner"])
@pytest.mark.parametrize("fast", ["rows", "columns"])
def test_quadrant_frame_holds_each_channel_in_read_order(corner, fast):
    nrows, ncols = 6, 8
    lay = ChannelLayout(nrows, ncols, "quadrants", corner, fast)
    image = np.arange(nrows * ncols).reshape(nrows, ncols)
    frame = lay.to_readout(image)
    width = frame.shape[1] // 4
    for q, order in enumerate(_quadrant_read_order(nrows, ncols, corner, fast)):
        expected = [[image[r, c] for r, c in row] for row in order]
        assert frame[:, q * width:(q + 1) * width].tolist() == expected



@pytest.mark.parametrize(("channels", "corner", "fast"), LAYOUTS)
def test_frame_coordinates_of_each_stored_pixel_are_where_it_is_read(channels, corner, fast):
    """Read slow-th in its channel, k-th in that row: frame (slow, channel start + k)."""
    nrows, ncols = 6, 8
    lay = ChannelLayout(nrows, ncols, channels, corner, fast) if channels == "quadrants" \
        else ChannelLayout(nrows, ncols, channels)
    if channels == "columns":
        expected = {(r, c): (r, c) for r in range(nrows) for c in range(ncols)}
    elif channels == "rows":  # the fast scan runs down the stored columns
        expected = {(r, c): (c, r) for r in range(nrows) for c in range(ncols)}
    else:
        width = lay.frame_shape[1] // 4
        expected = {pixel: (slow, q * width + k)
                    for q, order in enumerate(_quadrant_read_order(nrows, ncols, corner, fast))
                    for slow, row in enumerate(order) for k, pixel in enumerate(row)}
    r, c = np.array(sorted(expected)).T
    i, j = lay.frame_coordinates(r, c)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == [expected[p] for p in sorted(expected)]

def test_band_of_frame_rows_comes_from_the_stored_rows_named():
    for lay in (ChannelLayout(8, 6, "quadrants"), ChannelLayout(8, 6, "rows"),
                ChannelLayout(8, 6, "quadrants", "inner", "columns")):
        image = np.arange(48.0).reshape(8, 6)
        frame = lay.to_readout(image)
        for first, stop in [(0, 1), (1, 3), (0, lay.frame_shape[0])]:
            rows, take = lay.stored_rows_of(first, stop)
            assert np.array_equal(image[rows][take], frame[first:stop])


def test_quadrant_pixel_times_follow_a_hand_written_schedule():
    """Quadrant q, first-read corner, fast axis, row overhead: each pixel's time."""
    nrows, ncols, rate, overhead, phantoms = 8, 12, 1000.0, 3, 2
    for corner in ("outer", "inner"):
        for fast in ("rows", "columns"):
            g = DetectorGeometry(nrows, ncols, 4, ref_border=1, pixel_rate=rate,
                                 channels="quadrants", first_corner=corner, fast_axis=fast)
            s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=phantoms,
                                row_overhead=overhead, nframes=3, frame_time=1.0)
            expected = np.full((nrows, ncols), np.nan)
            for order in _quadrant_read_order(nrows, ncols, corner, fast):
                row_samples = phantoms + len(order[0]) + overhead
                for slow, line in enumerate(order):
                    for k, (r, c) in enumerate(line):
                        expected[r, c] = 2.0 + (slow * row_samples + phantoms + k) / rate
            got = stored_pixel_times(s, frame=2).to_value("s")
            assert np.allclose(got, expected, rtol=0, atol=1e-12), (corner, fast)


def test_rows_pixel_times_run_down_the_columns():
    g = DetectorGeometry(8, 6, 2, ref_border=0, pixel_rate=100.0, channels="rows")
    s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, row_overhead=0,
                        nframes=1, frame_time=1.0)
    got = stored_pixel_times(s).to_value("s")
    expected = np.empty((8, 6))
    for r in range(8):  # band r // 4 read along column c, pixel r % 4 of it
        for c in range(6):
            expected[r, c] = (c * 4 + r % 4) / 100.0
    assert np.allclose(got, expected)


def test_border_on_the_stored_image_gives_the_frames_reference_pixels():
    g = DetectorGeometry(16, 12, 4, ref_border=2, channels="quadrants")
    f = g.frame
    assert (f.nrows, f.ncols, f.channel_width) == (8, 24, 6)
    assert f.reference_rows.tolist() == [0, 1]
    assert f.reference_column_mask().reshape(4, 6).tolist() == [[True] * 2 + [False] * 4] * 4
    expected = np.zeros((16, 12), bool)  # the stored border, every side
    expected[:2], expected[-2:], expected[:, :2], expected[:, -2:] = True, True, True, True
    assert np.array_equal(g.reference_pixel_mask(), expected)
    assert np.array_equal(g.layout.to_stored(f.reference_pixel_mask()), expected)
    rows = DetectorGeometry(8, 6, 2, ref_border={"top": 1, "left": 2}, channels="rows").frame
    assert rows.border == RefBorder(top=2, bottom=0, left=1, right=0)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"nrows": 15, "channels": "quadrants", "nchannels": 4}, "even number of rows"),
    ({"channels": "quadrants", "nchannels": 2}, "nchannels must be 4"),
    ({"channels": "quadrants", "nchannels": 4, "ref_border": {"top": 2}}, "opposite"),
    ({"first_corner": "inner"}, "describe quadrants"),
    ({"channels": "rows", "nrows": 15, "nchannels": 2}, "nrows a multiple"),
    ({"preset": "H5RG"}, "not a known preset"),
])
def test_impossible_layouts_are_refused_naming_why(kwargs, message):
    values = {"nrows": 16, "ncols": 16, "nchannels": 2, "ref_border": 0, **kwargs}
    with pytest.raises(ValueError, match=message):
        DetectorGeometry(**values)


def test_presets_build_what_their_documentation_says():
    wfc3 = DetectorGeometry.from_preset("WFC3-IR")
    assert (wfc3.nrows, wfc3.ncols, wfc3.nchannels, wfc3.border.uniform) == (1024, 1024, 4, 5)
    assert int((~wfc3.reference_pixel_mask()).sum()) == 1014 * 1014  # handbook 5.6.1
    assert (wfc3.frame.nrows, wfc3.frame.channel_width) == (512, 512)
    roman = DetectorGeometry.from_preset("H4RG-10")
    assert (roman.nrows, roman.channel_width, roman.scan_directions[:3].tolist()) == (
        4096, 128, [1, -1, 1])
    jwst = DetectorGeometry.from_preset("SIDECAR")
    assert (jwst.channel_width, jwst.pixel_rate, jwst.scan) == (512, 1e5, "alternate")
    science = DetectorGeometry.from_preset("SIDECAR-science")
    assert science.frame.to_dict() == science.to_dict()
    assert science.frame.ncols == 2048 and science.layout.channels == "rows"
    assert DetectorGeometry.from_preset("H2RG") == DetectorGeometry(preset="H2RG")
    assert DetectorGeometry.from_preset("WFC3-IR", ref_border=4).border.uniform == 4
    assert set(PRESETS) == {"H2RG", "H4RG-10", "WFC3-IR", "SIDECAR", "SIDECAR-science"}
