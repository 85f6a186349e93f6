"""Telegraph noise of reference pixels (``scene: rtn: pixels``): continuous-time switching."""

import numpy as np
import pytest

from spherex_reduce import simulate
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.simulation import load_scene

RATE = 5.0  # Hz: flip probabilities from ~0.05 (reads of a row within a frame) to ~0.3


def _scene(pixels, mode="ramps", nframes=60, fraction=1.0):
    return {"geometry": {"nrows": 32, "ncols": 64, "nchannels": 2, "ref_border": 4},
            "readout": {"skip": 4, "ref_reads": 32, "ref_mode": "distributed",
                        "phantom_reads": 2, "nframes": nframes},
            "noise": {"components": []}, "output": {"mode": mode},
            "scene": {"rtn": {"fraction": fraction, "amplitude": 1.0, "rate": RATE,
                              "pixels": pixels}}}


def _read_times(s):
    """Time (s, from the start of the exposure) of every read of every pixel, (N, reads, cols),
    from the schedule alone."""
    tau = s.pixel_times().to_value("s")
    t0 = np.arange(s.nframes) * s.frame_time.to_value("s")
    return t0[:, None, None] + tau[None]


def test_reference_pixels_switch_with_the_analytic_probability():
    """Every reference pixel a telegraph of amplitude 1, no other noise: the state at each read
    is the data.  Between consecutive reads of a pixel ``dt`` apart, the fraction of flips is
    ``(1 - exp(-2 rate dt)) / 2`` (binomial errors, 5 sigma per gap, chi-square over all)."""
    e = simulate(_scene("reference"), seed=7)
    s = e.schedule
    g = s.geometry
    data = e.data.data
    assert set(np.unique(data).tolist()) == {0.0, 1.0}
    times = _read_times(s)
    refcol = g.reference_column_mask()
    dts, flips = [], []
    for row in range(g.nrows):
        reads = np.flatnonzero(s.rows == row)
        is_ref_row = row in g.reference_rows
        for col in range(g.ncols):
            if not (is_ref_row or refcol[col]):
                assert not data[:, reads, col].any()  # active pixels untouched
                continue
            t = times[:, reads, col].ravel()
            x = data[:, reads, col].ravel()
            order = np.argsort(t)
            t, x = t[order], x[order]
            dts.append(np.round(np.diff(t), 9))
            flips.append(x[1:] != x[:-1])
    dts, flips = np.concatenate(dts), np.concatenate(flips)
    gaps = np.unique(dts)
    assert gaps.size >= 3  # reads of a row within a frame, and from frame to frame
    chi2 = 0.0
    for gap in gaps:
        sel = dts == gap
        n = int(sel.sum())
        p = (1 - np.exp(-2 * RATE * gap)) / 2
        sd = np.sqrt(p * (1 - p) / n)
        assert abs(flips[sel].mean() - p) < 5 * sd, (gap, n, flips[sel].mean(), p)
        chi2 += ((flips[sel].mean() - p) / sd) ** 2
    assert chi2 < gaps.size + 5 * np.sqrt(2 * gaps.size)
    assert data[:, s.is_reference].mean() == pytest.approx(0.5, abs=0.03)


def test_reference_rows_change_within_a_frame():
    """A reference row read several times per frame sees a different state at some reads of
    one frame (a pixel read once per frame never could)."""
    e = simulate(_scene("reference"), seed=2)
    s = e.schedule
    row = s.geometry.reference_rows[0]
    reads = np.flatnonzero(s.rows == row)
    assert reads.size == 4
    vals = e.data.data[:, reads, 10]  # (frames, reads of the row)
    assert (vals.min(axis=1) != vals.max(axis=1)).any()


def test_active_default_and_all_keep_the_active_pixels_numbers():
    """``pixels: active`` is the default and ``all`` adds reference pixels without changing a
    single active pixel's numbers; ``reference`` leaves the active pixels alone."""
    base = simulate(_scene("active", fraction=0.3), seed=5)
    sc = _scene("active", fraction=0.3)
    del sc["scene"]["rtn"]["pixels"]
    np.testing.assert_array_equal(simulate(sc, seed=5).data.data, base.data.data)
    both = simulate(_scene("all", fraction=0.3), seed=5)
    s = base.schedule
    active = (~s.is_reference)[:, None] & ~s.geometry.reference_column_mask()[None, :]
    np.testing.assert_array_equal(both.data.data[:, active], base.data.data[:, active])
    assert not base.data.data[:, ~active].any() and both.data.data[:, ~active].any()
    ref = simulate(_scene("reference", fraction=0.3), seed=5)
    assert not ref.data.data[:, active].any()
    np.testing.assert_array_equal(ref.data.data[:, ~active], both.data.data[:, ~active])


def test_slopes_are_the_least_squares_slopes_of_the_ramps():
    """In slope mode a telegraph reference pixel gives the least-squares slope of its
    states (numpy polyfit of the ramps, same seed)."""
    ramps = simulate(_scene("reference", nframes=8), seed=4)
    slopes = simulate(_scene("reference", mode="slopes", nframes=8), seed=4)
    s = ramps.schedule
    t = np.arange(s.nframes) * s.frame_time.to_value("s")
    cube = ramps.data.data.reshape(s.nframes, -1).astype(float)
    fitted = np.polyfit(t, cube, 1)[0].reshape(s.n_reads, -1)
    np.testing.assert_allclose(slopes.data.data, fitted, atol=1e-5)


def test_pixels_is_validated():
    with pytest.raises(ConfigError, match=r"scene\.rtn\.pixels"):
        load_scene({"scene": {"rtn": {"fraction": 0.1, "pixels": "rows"}}})
