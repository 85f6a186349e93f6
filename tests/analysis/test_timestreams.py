"""Which pixels the noise streams of a raw exposure hold: reference pixels only.

The expected streams are written here from the definition (the side reference
columns and the reference rows of a hand-written border, a straight line over
the frames removed with numpy's polyfit), on an array whose light-sensitive
pixels hold extreme values.
"""

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
from spherex_reduce.analysis import fit_raw_noise, reference_timestream
from spherex_reduce.core.errors import SpherexReduceError

NF = 6
#: top 3 reference rows, none at the bottom; 4 reference columns left, 2 right
BORDER = {"top": 3, "bottom": 0, "left": 4, "right": 2}


def _exposure(light=None, seed=0):
    """White noise in every pixel (24 x 32, 2 channels, re-read reference rows); the
    light-sensitive pixels replaced by ``light`` (an array of the ramps' shape) if given."""
    g = DetectorGeometry(24, 32, 2, ref_border=BORDER, pixel_rate=1e5)
    s = ReadoutSchedule(g, skip=4, ref_reads=6, ref_mode="distributed", phantom_reads=0,
                        nframes=NF)
    data = np.random.default_rng(seed).normal(0, 2.0, (NF, s.n_reads, 32))
    if light is not None:
        sensitive = (np.arange(24) >= 3)[s.rows][:, None] & (np.arange(32) >= 4) \
            & (np.arange(32) < 30)  # hand-written: not the border
        data = np.where(sensitive, light, data)
    return Exposure.from_arrays(data, s)


def _detrended(v):
    """A straight line over the frames (axis 1) removed at every position, scaled by
    sqrt(N / (N - 2)), with numpy's polyfit."""
    t = np.arange(v.shape[1])
    flat = np.moveaxis(v, 1, 0).reshape(v.shape[1], -1)
    coef = np.polynomial.polynomial.polyfit(t, flat, 1)
    res = flat - np.polynomial.polynomial.polyval(t, coef).T
    return np.moveaxis(res.reshape(np.moveaxis(v, 1, 0).shape), 0, 1) * np.sqrt(NF / (NF - 2))


def test_the_streams_hold_the_reference_pixels_the_border_declares():
    e = _exposure()
    data, s = e.data.data, e.schedule
    # border columns: the same number (2, the narrower side) from each side, the outermost
    want = _detrended(np.stack([data[:, :, [0, 1]].mean(-1), data[:, :, [30, 31]].mean(-1)]))
    np.testing.assert_allclose(reference_timestream(e, "columns").values, want, atol=1e-12)
    # re-read rows: the reads of rows 0-2, every column in each channel's scan order
    reads = np.flatnonzero(s.rows < 3)
    assert reads.size == 6
    rows = data[:, reads]  # frames, reads, columns
    want = np.stack([rows[:, :, :16], rows[:, :, 16:]])  # channels, frames, reads, 16
    got = reference_timestream(e, "rows").values
    np.testing.assert_allclose(got, _detrended(want.reshape(2, NF, -1)).reshape(got.shape),
                               atol=1e-12)


def test_extreme_light_sensitive_pixels_change_no_stream_and_no_fit():
    quiet = _exposure()
    shape = quiet.data.data.shape
    bright = _exposure(light=1e6 + 1e5 * np.random.default_rng(9).standard_normal(shape))
    assert np.abs(bright.data.data).max() > 1e5  # the light-sensitive pixels are extreme
    for source in ("columns", "rows"):
        np.testing.assert_array_equal(reference_timestream(bright, source).values,
                                      reference_timestream(quiet, source).values)
    a, b = fit_raw_noise(quiet, fit=("alpha",)), fit_raw_noise(bright, fit=("alpha",))
    for name in ("alpha", "alpha_err", "chi2"):
        assert a[name][0] == b[name][0], name
    # and the reference pixels are what is fitted: louder reference pixels, a louder fit
    loud = Exposure.from_arrays(quiet.data.data * 10, quiet.schedule)
    assert fit_raw_noise(loud, fit=("alpha",))["alpha"][0] == pytest.approx(100 * a["alpha"][0])


def test_integrations_of_one_readout_are_fitted_together():
    """Two exposures of white noise (sigma 2): the white level 2 sigma² / pixel_rate,
    measured better than from one."""
    a, b = _exposure(seed=1), _exposure(seed=2)
    joined, one = fit_raw_noise(iter([a, b]), fit=("alpha",)), fit_raw_noise(a, fit=("alpha",))
    alpha, err = joined["alpha"][0], joined["alpha_err"][0]
    assert abs(alpha - 2 * 2.0**2 / 1e5) < 4 * err
    assert 0.6 < err / one["alpha_err"][0] < 0.8  # twice the streams
    other = Exposure.from_arrays(a.data.data[:-1], a.schedule.replace(nframes=NF - 1))
    with pytest.raises(SpherexReduceError, match="exposure 1 has another schedule"):
        fit_raw_noise([a, other])
