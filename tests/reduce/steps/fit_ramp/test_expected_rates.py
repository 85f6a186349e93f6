"""`expected_errors`: ERR from each pixel's expected rate, piece by piece on threads."""

import numpy as np
import pytest

from spherex_reduce.reduce.steps.fit_ramp import expected_rates as er


def _slopes(n, seed=3):
    """A dark of 0.01 e/s scattered by 0.04 e/s with hot pixels, NaN (not fitted) and
    per-pixel variances (float32, as `RampSolution` holds them)."""
    rng = np.random.default_rng(seed)
    slope = 0.01 + 0.04 * rng.standard_normal(n)
    slope[rng.choice(n, n // 50, replace=False)] = rng.uniform(0.5, 50, n // 50)
    slope[::97] = np.nan
    var_rnoise = (0.0016 * rng.uniform(0.8, 1.2, n)).astype(np.float32)
    var_per_rate = np.full(n, 0.01, np.float32)
    return slope, var_rnoise, var_per_rate


@pytest.mark.parametrize("threads", [1, 3])
def test_errors_are_those_of_the_expected_rates_whatever_the_pieces(monkeypatch, threads):
    """sqrt(var_rnoise + rate * var_per_rate) at `expected_rates`' rates (numpy on the whole
    arrays), bit for bit with pieces of 1000 pixels on any threads; NaN kept."""
    slope, vr, vp = _slopes(20000)
    rate = er.expected_rates(slope, vr, vp)
    want = np.sqrt(rate * vp.astype(np.float64) + vr)
    want[np.isnan(slope)] = np.nan
    err = np.where(np.isnan(slope), np.nan, 1.0).reshape(100, 200)
    monkeypatch.setattr(er, "RATE_PIECE", 1000)
    assert er.expected_errors(slope.reshape(100, 200), vr.reshape(100, 200),
                              vp.reshape(100, 200), err, threads=threads)
    np.testing.assert_array_equal(err.ravel(), want)
    # hot pixels take their own rate, the dark the bulk's (0.01 e/s)
    hot = slope > 0.4
    np.testing.assert_allclose(err.ravel()[hot] ** 2, vr[hot] + slope[hot] * vp[hot], rtol=1e-6)


def test_too_few_pixels_leave_the_errors_untouched():
    slope, vr, vp = _slopes(200)
    err = np.ones(200)
    assert not er.expected_errors(slope, vr, vp, err, bulk=np.arange(200) < 50)
    assert (err == 1).all()


def test_a_strided_error_array_is_refused():
    slope, vr, vp = _slopes(400)
    err = np.ones((20, 40))[:, ::2]
    with pytest.raises(ValueError, match="C-ordered"):
        er.expected_errors(slope.reshape(20, 20), vr.reshape(20, 20), vp.reshape(20, 20), err)


def test_variances_given_as_numbers_are_those_of_every_pixel():
    """One number for a variance (the docs allow it) is that variance at every pixel: the
    rates and errors of full arrays of it (the bulk's noise was a median of one number)."""
    slope, _, _ = _slopes(5000)
    full = er.expected_rates(slope, np.full(5000, 0.0016), np.full(5000, 0.01))
    np.testing.assert_array_equal(er.expected_rates(slope, 0.0016, np.float64(0.01)), full)
    err, want = np.ones(5000), np.ones(5000)
    assert er.expected_errors(slope, 0.0016, 0.01, err)
    assert er.expected_errors(slope, np.full(5000, 0.0016), np.full(5000, 0.01), want)
    np.testing.assert_array_equal(err, want)


def test_a_negative_variance_keeps_the_pixels_error():
    """A variance below zero at a pixel's expected rate (not from a fit: a caller's, here
    var_rnoise < 0 on a sky whose spreads stay positive) leaves that pixel's error as it
    was, the others computed, without NaN or an invalid-value warning."""
    rng = np.random.default_rng(0)
    slope = 10 + rng.standard_normal(1000)
    slope[0] = 0.0  # its expected rate is its own (far from the bulk): var < 0 there
    err = np.ones(1000)
    with np.errstate(invalid="raise"):
        assert er.expected_errors(slope, np.full(1000, -0.05), np.full(1000, 0.01), err)
    assert err[0] == 1.0 and np.isfinite(err).all() and (err[1:] != 1).all()
