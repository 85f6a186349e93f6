"""Explicit read orders (``readout.order``): the schedule they give against orders and
sample times written by hand, their FITS round trip, and the orders refused."""

import numpy as np
import pytest
from astropy.table import Table

from spherex_reduce import ConfigError, DetectorGeometry, FormatError, ReadoutSchedule
from spherex_reduce.core import limits
from spherex_reduce.core.errors import ResourceError
from spherex_reduce.core.window import Window
from spherex_reduce.io.config import schedule_from_config

GEOMETRY = DetectorGeometry(32, 16, 2, ref_border=2)  # rows 0 1 and 30 31 are reference rows


def distributed_by_hand(nrows, border, skip, r):
    """The paper's order from its definition: the active rows ``border ... nrows-border-1``
    in passes ``k, k+S, ...``; reference read j (rows top then bottom, cycling) goes before
    active read ``floor(j * n_active / r)``."""
    active = list(range(border, nrows - border))
    chopped = [row for k in range(skip) for row in active[k::skip]]
    refs = [*range(border), *range(nrows - border, nrows)]
    before = {}
    for j in range(r):
        before.setdefault(j * len(active) // r, []).append(refs[j % len(refs)])
    order, is_ref = [], []
    for i, row in enumerate(chopped):
        order += before.get(i, [])
        is_ref += [True] * len(before.get(i, []))
        order.append(row)
        is_ref.append(False)
    return order, is_ref


@pytest.mark.parametrize(("skip", "r"), [(4, 6), (5, 3), (1, 0), (7, 32)])
def test_an_explicit_chopped_order_is_the_skip_schedule(skip, r):
    order, is_ref = distributed_by_hand(32, 2, skip, r)
    chopped = ReadoutSchedule(GEOMETRY, skip=skip, ref_reads=r, phantom_reads=3, nframes=5)
    explicit = ReadoutSchedule(GEOMETRY, order=order, phantom_reads=3, nframes=5)
    assert explicit.rows.tolist() == order == chopped.rows.tolist()
    assert explicit.is_reference.tolist() == is_ref == chopped.is_reference.tolist()
    assert np.array_equal(explicit.starts, chopped.starts)
    assert explicit.frame_time == chopped.frame_time
    a, b = explicit.to_table(), chopped.to_table()
    for name in ("read", "row", "kind", "start", "time"):
        assert np.array_equal(a[name], b[name]), name
    assert explicit.order == order and "explicit order" in explicit.summary()


def test_bit_reversed_order_samples_every_pixel_when_a_loop_says():
    """16 rows (no reference rows) read in bit-reversed order; 2 channels of 4 columns
    scanned in alternate directions; c = 2 phantom samples and 3 overhead samples a read."""
    order = [int(f"{k:04b}"[::-1], 2) for k in range(16)]
    assert order[:5] == [0, 8, 4, 12, 2]
    g = DetectorGeometry(16, 8, 2, ref_border=0, scan="alternate", pixel_rate=1000.0)
    s = ReadoutSchedule(g, order=order, phantom_reads=2, row_overhead=3, nframes=2)
    expected = np.zeros((16, 8))  # sample index of each physical pixel, by hand
    for i, row in enumerate(order):
        for col in range(8):
            channel, pos = divmod(col, 4)
            offset = pos if channel == 0 else 3 - pos
            expected[row, col] = i * (2 + 4 + 3) + 2 + offset
    got = np.zeros((16, 8))
    got[s.rows] = s.pixel_samples()
    assert np.array_equal(got, expected)
    np.testing.assert_allclose(s.pixel_times().value[np.argsort(s.rows)], expected / 1000.0,
                               rtol=0, atol=1e-15)
    assert not s.is_reference.any() and s.read_of_row().tolist() == np.argsort(order).tolist()


def test_reference_rows_may_be_read_any_number_of_times_anywhere():
    active = list(range(2, 30))
    order = [31, 0, 0, *active[::-1], 1, 30, 0]
    s = ReadoutSchedule(GEOMETRY, order=order)
    assert s.reference_read_indices.tolist() == [0, 1, 2, 31, 32, 33]
    assert s.n_reads == 34 and s.kinds[3] == "active"


def test_a_file_with_an_explicit_order_reads_back_without_a_config():
    order, _ = distributed_by_hand(32, 2, 3, 5)
    order = order[::-1]  # an order no skip gives
    s = ReadoutSchedule(GEOMETRY, order=order, nframes=4)
    h = s.to_header()
    assert h["ROWORDER"] == "explicit"
    assert not {"ROWSKIP", "NREFRD", "REFMODE"} & set(h)
    again = ReadoutSchedule.from_header(h, s.to_table())
    assert again == s and again.rows.tolist() == order
    with pytest.raises(FormatError, match="ROWORDER = 'explicit' needs the READOUT table"):
        ReadoutSchedule.from_header(h)
    h2 = h.copy()
    h2["ROWSKIP"] = 24
    with pytest.raises(FormatError, match=r"ROWORDER, or readout.order\) and ROWSKIP are both"):
        ReadoutSchedule.from_header(h2, s.to_table())
    h2 = s.replace(order=None, skip=3).to_header()  # a chopped file, a config's order
    with pytest.raises(FormatError, match="and ROWSKIP, NREFRD, REFMODE are both given"):
        ReadoutSchedule.from_header(h2, order=order)
    h2 = h.copy()
    h2["ROWORDER"] = "chopped"
    with pytest.raises(FormatError, match="keyword ROWORDER: must be 'explicit'"):
        ReadoutSchedule.from_header(h2, s.to_table())
    table = s.to_table()
    i, j = s.active_read_indices[:2]
    table["row"][j] = table["row"][i]  # an active row read twice
    with pytest.raises(FormatError, match=f"invalid schedule: order reads active row "
                                          f"{order[i]} twice"):
        ReadoutSchedule.from_header(h, table)
    del h["ROWORDER"]  # then ROWSKIP is needed
    with pytest.raises(FormatError, match=r"missing readout keyword\(s\) ROWSKIP \(or ROWORDER\)"):
        ReadoutSchedule.from_header(h, s.to_table())


def test_the_order_of_an_ecsv_file(tmp_path):
    order, _ = distributed_by_hand(32, 2, 4, 4)
    path = tmp_path / "rows.ecsv"
    Table({"row": order}).write(path, format="ascii.ecsv")
    s = schedule_from_config({"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 2},
                             {"order": str(path)})
    assert s.rows.tolist() == order and s.order == order
    assert s.to_dict()["order"] == order and "skip" not in s.to_dict()
    assert s.replace(nframes=3).rows.tolist() == order


def _refusal(order, geometry=GEOMETRY):
    with pytest.raises(ValueError) as info:
        ReadoutSchedule(geometry, order=order)
    return str(info.value)


ACTIVE = list(range(2, 30))


@pytest.mark.parametrize(("order", "message"), [
    ([], "order is empty"),
    ([0, *ACTIVE[1:]], "order misses 1 active row(s), the first 2"),
    ([*ACTIVE, 5], "order reads active row 5 twice (entries 3 and 28)"),
    ([*ACTIVE, 32], "order entry 28 is row 32, outside the array's rows 0 to 31"),
    ([*ACTIVE, -1], "order entry 28 is row -1, outside"),
    ([*ACTIVE[:-1], 29.0], "order entry 27 must be an integer row index, got 29.0"),
    ([*ACTIVE, True], "order entry 28 must be an integer row index, got True"),
    ([*ACTIVE, "0"], "order entry 28 must be an integer row index, got '0'"),
    ({"rows": ACTIVE}, "order must be a list of row indices or the path of an ECSV file"),
])
def test_orders_refused_name_the_entry(order, message):
    assert message in _refusal(order)


@pytest.mark.parametrize(("text", "message"), [
    ("# %ECSV 1.0\n# ---\n# datatype:\n# - {name: a, datatype: int64}\n# - {name: b, "
     "datatype: int64}\na b\n1 2\n", "must have one column of row indices, it has 2"),
    ("# %ECSV 1.0\n# ---\n# datatype:\n# - {name: row, datatype: float64}\nrow\n1.0\n",
     "column 'row' must hold integers (row indices), it holds float64"),
    ("row\n1\n2\n", "is not an ECSV table"),
])
def test_order_files_refused(tmp_path, text, message):
    path = tmp_path / "rows.ecsv"
    path.write_text(text)
    assert message in _refusal(str(path))
    assert "No such file or directory" in _refusal(str(tmp_path / "none.ecsv"))


def test_an_order_too_long_for_memory_is_refused(monkeypatch):
    monkeypatch.setattr(limits, "memory_budget", lambda: 10_000)
    with pytest.raises(ResourceError, match="an explicit read order of 1000 reads"):
        ReadoutSchedule(GEOMETRY, order=[0] * 1000)


def test_order_replaces_skip_and_the_reference_reads():
    assert "order gives the read order, so skip=4 cannot be given with it" in _refusal_with(
        skip=4)
    assert "ref_mode='none' cannot" in _refusal_with(ref_mode="none")
    g = {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 2}
    with pytest.raises(ConfigError, match=r"^readout: order gives the read order, so skip "
                                          r"cannot be given with it: leave out skip, "):
        schedule_from_config(g, {"order": ACTIVE, "skip": 24})  # even the default value


def _refusal_with(**given):
    with pytest.raises(ValueError) as info:
        ReadoutSchedule(GEOMETRY, order=ACTIVE, **given)
    return str(info.value)


def test_a_window_takes_no_explicit_order():
    g = Window(0, 0, DetectorGeometry(32, 16, 2, ref_border=2)).geometry(8, 16)
    assert "an explicit order cannot be given for a window" in _refusal(ACTIVE, g)
