"""The forecast of a readout in an explicit read order (``readout.order``) against a brute-force
covariance of every sample pushed through the reduction as a matrix, and against the skip order
it spells out; the rows and lags computed a chunk at a time against the same brute force."""

import numpy as np
import pytest
from _forecast_brute import Samples, expected_spectrum, reduction_matrix
from _forecast_scenes import (
    BINS,
    BOTH,
    BOTH_COMMON,
    COMMON,
    PHANTOM,
    PINK_ACN,
    PIPELINES,
    check_against_brute_force,
    tiny,
)
from astropy import units as u

from spherex_reduce.analysis import forecast
from spherex_reduce.analysis.forecast import rows as forecast_rows
from spherex_reduce.simulation import load_scene

#: 20 rows: reference rows 0, 1 (top) and 18, 19 (bottom); light rows 2-17 read in a shuffled
#: order, with reference reads between them (one reference row read three times).
ORDER = [0, 9, 3, 14, 17, 18, 6, 2, 11, 5, 16, 1, 8, 13, 4, 10, 0, 15, 7, 12, 19, 0]


def scene(order=None, skip=None):
    readout = {"phantom_reads": 2, "nframes": 4, "frame_overhead": 20000}
    readout.update({"order": order} if order is not None else {"skip": skip, "ref_reads": 4})
    return load_scene({
        "geometry": {"nrows": 20, "ncols": 20, "nchannels": 2,
                     "ref_border": {"top": 2, "bottom": 2, "left": 2, "right": 2}},
        "readout": readout,
        "noise": {"components": [PINK_ACN, COMMON]},
    })


@pytest.mark.parametrize("pipeline", [None, "spherex-default"])
def test_an_explicit_order_equals_brute_force(pipeline):
    """Every sample's covariance at its lag, the reduction as an explicit matrix (phantom
    mean, then the mean of the reference reads: row 0 read three times counts three times),
    pushed through `power_spectrum` (tests/_forecast_brute.py)."""
    sc = scene(ORDER)
    assert sc.schedule.rows.tolist() == ORDER
    samples = Samples(sc)
    reduced = pipeline is not None
    lmat = reduction_matrix(samples, phantom=reduced, reference="mean" if reduced else None,
                            reference_phantom=reduced)
    cov = sum(samples.covariance(sc.components).values())
    expect = expected_spectrum(samples, lmat, cov, BINS)
    got = u.Quantity(forecast(sc, pipeline, measure={"bins": BINS})["power"]).value
    np.testing.assert_allclose(got, expect, rtol=1e-3)


@pytest.mark.parametrize("skip", [1, 3])
def test_an_explicit_order_spelling_out_a_skip_order_forecasts_the_same(skip):
    a = scene(skip=skip)
    b = scene(order=a.schedule.rows.tolist())
    fa, fb = (u.Quantity(forecast(x, measure={"bins": BINS})["power"]).value for x in (a, b))
    np.testing.assert_allclose(fb, fa, rtol=1e-12)
    shuffled = u.Quantity(forecast(scene(ORDER), measure={"bins": BINS})["power"]).value
    assert np.max(np.abs(shuffled / fa - 1)) > 0.01  # the order matters: not a tautology


def test_rows_and_lags_a_chunk_at_a_time_equal_brute_force(monkeypatch):
    """The k_y rows in chunks of 2 (the memory bound of a tall image) and the lags' slope
    covariance 100 at a time: the same spectrum as the brute force."""
    monkeypatch.setattr(forecast_rows, "CHUNK_ROWS", 2)
    monkeypatch.setattr(forecast_rows, "CHUNK_LAGS", 100)
    scene = tiny([PINK_ACN, BOTH, BOTH_COMMON, PHANTOM], scan="alternate")
    check_against_brute_force(scene, *PIPELINES["acn-side-columns"])


def _searched(**changes):
    """A 20 x 20 scene of a search's readouts (pink ACN and common noise), with ``changes``."""
    base = {"skip": 3, "ref_reads": 4, "phantom_reads": 2, "nframes": 4, "frame_overhead": 20000}
    return load_scene({"geometry": {"nrows": 20, "ncols": 20, "nchannels": 2, "ref_border": 2},
                       "readout": {**base, **changes},
                       "noise": {"components": [PINK_ACN, COMMON]}})


def test_a_lag_table_serves_every_row_order_of_its_timing_and_no_other_timing():
    """A search over readouts reuses a timing's lag table for every order of its rows, never
    for another timing: forecast one after the other (each timing's table kept), the
    spectra of c = 2, c = 3, a longer frame and r = 6 still equal the brute force."""
    first, reordered = _searched(), _searched(skip=5)
    comps = first.components
    assert forecast_rows._lag_table(first.schedule, comps, 11, 8) is \
        forecast_rows._lag_table(reordered.schedule, comps, 11, 8)
    for changes in ({}, {"phantom_reads": 3}, {"frame_overhead": 15000}, {"ref_reads": 6}):
        check_against_brute_force(_searched(**changes), *PIPELINES["spherex-default"])


def test_timings_at_one_frame_time_share_one_slope_covariance_line():
    """c = 2 and c = 3 (other row times, the same frames) ask the same line for their own
    lags: it computes each lag once and holds the union, each value that of
    slope_covariance at that lag; a longer frame gets its own line."""
    from spherex_reduce.noise.variance import slope_covariance

    def timed(**changes):  # a fixed frame time, as a search's budget fixes it
        sc = _searched(**changes)
        readout = {k: v for k, v in sc.config["readout"].items() if k != "frame_overhead"}
        return load_scene({**sc.config, "readout": {**readout, "frame_time": 0.25}})

    first, other_c = timed(), timed(phantom_reads=3)
    assert first.schedule.row_samples != other_c.schedule.row_samples
    comps = first.components
    for sc in (first, other_c):
        forecast(sc, measure={"bins": BINS})
    line = forecast_rows._covariance_line(first.schedule, comps)
    assert forecast_rows._covariance_line(other_c.schedule, comps) is line
    assert forecast_rows._covariance_line(_searched().schedule, comps) is not line
    tables = [forecast_rows._lag_table(sc.schedule, comps, 9 + sc.schedule.phantom_reads, 8)
              for sc in (first, other_c)]
    assert tables[0] is not tables[1]
    assert np.all(np.diff(line.lags) > 0) and line.lags.size > 0
    np.testing.assert_allclose(line.values, slope_covariance(comps, first.schedule, line.lags),
                               rtol=1e-12, atol=0)


def test_the_light_functionals_are_shared_by_row_orders_and_timings_not_by_c():
    """A search's forecasts share the light rows' functional and its correlations (they
    depend on the geometry, the cells, c and the reduction, not on the row order or the
    timing): forecast one after the other, orders, timings and reference reads sharing one
    and c = 3 another, every spectrum still equals the brute force."""
    def light(sc, c):
        from spherex_reduce.analysis.forecast.steps import reduction

        red = reduction("spherex-default")
        return forecast_rows._light(sc.schedule, slice(2, 18), slice(2, 18), np.arange(9),
                                    c, red)

    first, other = _searched(), _searched(skip=5, frame_overhead=15000, ref_reads=6)
    assert light(first, 2) is light(other, 2)
    assert light(first, 2) is not light(_searched(phantom_reads=3), 3)
    for changes in ({}, {"skip": 5}, {"phantom_reads": 3}, {"frame_overhead": 15000},
                    {"ref_reads": 6}, {}):
        for name in ("spherex-default", "acn-side-columns"):
            check_against_brute_force(_searched(**changes), *PIPELINES[name])


def test_column_phases_are_kept_read_only():
    """The phase table is shared between forecasts: it cannot be written to, and it is
    ``exp(-i k_x (j - j0))`` written out."""
    from spherex_reduce.analysis.forecast.functionals import column_phases

    sc = scene(skip=3)
    kx = np.array([0, 3, 5])
    j, phase = column_phases(sc.schedule.geometry, slice(2, 18), kx)
    expect = np.exp(-2j * np.pi * np.outer(np.arange(16), kx) / 16)
    np.testing.assert_allclose(phase, expect, rtol=0, atol=1e-14)
    assert j.tolist() == list(range(2, 18))
    with pytest.raises(ValueError):
        phase[0, 0] = 0
    assert column_phases(sc.schedule.geometry, slice(2, 18), kx.copy())[1] is phase


def test_the_rows_autocorrelation_is_shared_by_a_readouts_frame_counts_and_is_numpys():
    """The slope scatter forecasts one readout at several frame counts: the rows' read-slot
    autocorrelation ``A(k_y, m)`` (it depends on the rows' slots, not on the frames) is
    computed once for them, read-only, another row order gets its own, each equal to
    the sum over pairs of light rows written out, and the forecasts still equal the brute
    force."""
    def readout(nframes=4, skip=3):
        sc = scene(skip=skip)
        return load_scene({**sc.config, "readout": {**sc.config["readout"],
                                                     "nframes": nframes}})

    rows, ky = slice(2, 18), np.arange(9)
    four, eight, other = readout(), readout(nframes=8), readout(skip=5)
    a = forecast_rows._row_pairs(four.schedule, rows, ky)
    assert forecast_rows._row_pairs(eight.schedule, rows, ky) is a
    b = forecast_rows._row_pairs(other.schedule, rows, ky)
    assert b is not a
    with pytest.raises(ValueError):
        a[0, 0] = 0
    for sc, got in ((four, a), (other, b)):
        slot = forecast_rows._slots(sc.schedule)[sc.schedule.read_of_row()[2:18]]
        n = got.shape[1]
        want = np.zeros_like(got)
        for i, k in enumerate(2 * np.pi * ky / 16):
            for p in range(16):
                for q in range(16):
                    want[i, (slot[p] - slot[q]) % n] += np.exp(-1j * k * (p - q))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    for sc in (four, eight, other):
        check_against_brute_force(sc, *PIPELINES["spherex-default"])


def test_cells_refuse_rows_that_do_not_increase():
    """`component_planes` puts each cell row from its distinct row in two runs (k_y >= 0,
    then k_y < 0), which holds for increasing rows only."""
    with pytest.raises(ValueError, match="must increase"):
        forecast_rows.Cells(np.array([3, 1, 2]), np.arange(4))
    with pytest.raises(ValueError, match="must increase"):
        forecast_rows.Cells(np.array([1, 1]), np.arange(4))
    assert forecast_rows.Cells.full(8, 8).ky.tolist() == list(range(8))
