"""Each pixel's expected rate given the exposure's slopes: the rate of ERR's shot noise.

A pixel's own slope, clipped at 0, is a biased rate where its noise is as large as the
rate (a dark), and the shot noise taken from it is largest where the slope fluctuated up:
``fit_ramp`` takes the shot noise of each pixel's rate *expected* given the bulk of the
exposure's slopes (`expected_rates`).  `RateBulk` measures the bulk once; its `rates`
then work on pieces of pixels that stay in cache; `expected_errors` turns each piece's
rates into its uncertainties at once, the pieces on threads.
"""

import math
from dataclasses import dataclass

import numpy as np

from ...options import in_threads

__all__ = ["RATE_PIECE", "RateBulk", "expected_errors", "expected_rates"]

#: a slope this many of its sigmas from the bulk of the exposure's slopes is taken as its
#: pixel's own rate for the shot noise (half its weight there; `expected_rates`)
OWN_RATE_SIGMA = 4.0
#: pixels `expected_rates` needs to see the bulk of the slopes; fewer: each pixel's own
EXPECTED_MIN_PIXELS = 100
#: pixels the bulk of `expected_rates` is measured on at most (every k-th pixel of the
#: array, k prime to the rows' length, that is in the bulk)
BULK_SAMPLE = 1 << 16
#: pixels `expected_rates` and `expected_errors` work on at once (a few float64 arrays of
#: them stay in cache: 17-19 ms for 1 Mpix where whole arrays took 28 ms; pieces of 2**15
#: were as fast on one thread, but two threads then gained nothing: each numpy call holds
#: the interpreter's lock too briefly between two; with 2**17, 12-13 ms on two threads)
RATE_PIECE = 1 << 17


def _stride(size, ncols):
    """The step of a sample of at most `BULK_SAMPLE` of ``size`` pixels, prime to the rows'
    length ``ncols``."""
    k = max(1, -(-size // BULK_SAMPLE))
    while k > 1 and math.gcd(k, ncols) != 1:
        k += 1
    return k


def expected_rates(slope, var_rnoise, var_per_rate, bulk=None):
    """Each pixel's expected rate given its slope and the exposure's: the rate whose shot
    noise its uncertainty holds.

    A pixel's own slope, clipped at 0, is a biased rate where its noise is as large as
    the rate (a dark): ``max(slope, 0)`` of a slope of 0.01 +- 0.038 e/s averages
    0.02 e/s, and the shot noise taken from it is largest where the slope fluctuated up,
    so the uncertainties of a dark overstate its scatter (by ~6 % on 74 reads of
    10 e).  The exposure's slopes are a Gaussian bulk of median ``m`` and spread
    ``tau**2`` (their MAD squared less the median noise variance ``v`` at ``m``) and
    each pixel's expected rate given that bulk is ``m + tau**2 / (tau**2 + v) (slope -
    m)`` (empirical Bayes: ``m`` for a flat dark, the pixel's own slope where the rates
    spread more than the noise, as on a sky).  A slope `OWN_RATE_SIGMA` sigmas or more
    from the bulk is its own pixel's (a hot pixel): a logistic weight in its distance
    squared, 1/2 at `OWN_RATE_SIGMA`, moves the rate from the bulk's to the slope.
    Rates are clipped at 0.

    Parameters
    ----------
    slope : `numpy.ndarray`
        Slopes (data unit / s), any shape; NaN where not fitted.
    var_rnoise, var_per_rate : `numpy.ndarray`
        The slopes' variance at zero rate ((data unit / s)**2) and per unit rate
        (data unit / s), as `RampSolution` holds them.
    bulk : `numpy.ndarray` of bool, optional
        The pixels the bulk is measured on (e.g. not the reference pixels, which
        collect no light); all if None.  Measured on the pixels of the bulk among
        every k-th pixel of the array (k prime to the rows' length, so that the
        sample walks through every column), at most `BULK_SAMPLE`.

    Returns
    -------
    `numpy.ndarray` or None
        The expected rates (data unit / s), float64, ``max(slope, 0)`` where ``slope``
        or its variance is not finite; None with fewer than `EXPECTED_MIN_PIXELS` such
        pixels in ``bulk`` (too few to see the bulk).

    Examples
    --------
    A dark of 0.01 e/s whose slopes scatter by 0.04 e/s, and one hot pixel:

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.expected_rates import expected_rates
    >>> slope = 0.01 + 0.04 * np.random.default_rng(0).standard_normal(10000)
    >>> slope[0] = 5.0
    >>> r = expected_rates(slope, np.full(10000, 0.0016), np.full(10000, 0.01))
    >>> np.round(r[:4], 3).tolist()  # the hot pixel its own; the others the dark's
    [5.0, 0.01, 0.01, 0.01]
    """
    slope = np.asarray(slope, np.float64)
    shape = slope.shape
    spread = RateBulk.measure(slope, var_rnoise, var_per_rate, bulk)
    if spread is None:
        return None
    slope, var_rnoise, var_per_rate = spread.flat(slope, var_rnoise, var_per_rate)
    out = np.empty(slope.size)
    for start in range(0, slope.size, RATE_PIECE):
        cut = slice(start, start + RATE_PIECE)
        spread.rates(slope[cut], _take(var_rnoise, cut), _take(var_per_rate, cut), out[cut])
    return out.reshape(shape)


def _median(v):
    """``np.median`` of finite ``v`` (float64, 1-D; one partition, without the NaN check that
    made ``np.median`` of 65 536 values 8x a partition's time)."""
    k = v.size // 2
    if v.size % 2:
        return float(np.partition(v, k)[k])
    part = np.partition(v, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2)


def _take(v, where):
    """``v[where]`` in float64 (``v`` one number or a flat array)."""
    return np.float64(v) if v.ndim == 0 else v[where].astype(np.float64)


@dataclass(frozen=True)
class RateBulk:
    """The bulk of an exposure's slopes, from which each pixel's expected rate follows
    (`expected_rates`): median ``m`` (its non-negative part ``mp``) and the rates'
    spread ``tau2`` beyond the noise ((data unit / s)**2).

    `measure` measures it once on the whole exposure; `rates` then gives the rates of
    any piece of its pixels (each from its own slope and variances, so pieces may be
    worked on in any order).
    """

    m: float
    mp: float
    tau2: float

    @staticmethod
    def flat(slope, var_rnoise, var_per_rate):
        """``slope`` flat (float64) and the variances flat (views of full arrays, any float
        type, made float64 piece by piece by `rates`' callers) or one number."""
        shape = np.shape(slope)
        var_rnoise, var_per_rate = (np.asarray(v) for v in (var_rnoise, var_per_rate))
        return (np.asarray(slope, np.float64).ravel(),
                *(v.reshape(()) if v.size == 1 else np.broadcast_to(v, shape).ravel()
                  for v in (var_rnoise, var_per_rate)))

    @classmethod
    def measure(cls, slope, var_rnoise, var_per_rate, bulk=None):
        """The bulk of ``slope`` (as `expected_rates` takes its arguments), or None with fewer
        than `EXPECTED_MIN_PIXELS` usable pixels in ``bulk``."""
        shape = np.shape(slope)
        slope, var_rnoise, var_per_rate = cls.flat(slope, var_rnoise, var_per_rate)
        # the bulk from every k-th pixel of the array that is in it, at most BULK_SAMPLE (its
        # medians to ~0.5 % of the slopes' sigma; three medians of 1 Mpix took 0.06 s of a
        # 0.26 s fit), k prime to the row's length so that the sample walks through every
        # column (k = 64 on 2048 columns of 64-column channels sampled one column of each)
        bulk = None if bulk is None else np.broadcast_to(bulk, shape).ravel()
        for step in dict.fromkeys((_stride(slope.size, shape[-1] if shape else 1), 1)):
            idx = np.arange(0, slope.size, step)
            sel = (np.isfinite(slope[idx]) & np.isfinite(_take(var_rnoise, idx))
                   & np.isfinite(_take(var_per_rate, idx)))
            if bulk is not None:
                sel &= bulk[idx]
            idx = idx[sel]
            if idx.size >= EXPECTED_MIN_PIXELS:
                break
        else:  # too few even with every pixel
            return None
        s = slope[idx]
        m = _median(s)
        mad2 = (1.482602218505602 * _median(np.abs(s - m))) ** 2
        mp = max(m, 0.0)
        noise = _median(np.broadcast_to(_take(var_rnoise, idx) + mp * _take(var_per_rate, idx),
                                        idx.shape))  # (the variances may be numbers)
        return cls(m, mp, max(mad2 - noise, 0.0))

    def rates(self, x, var_rnoise, var_per_rate, out):
        """The expected rates of slopes ``x`` (a flat float64 piece, whose variances are
        ``var_rnoise`` and ``var_per_rate``: float64 pieces or numbers) into ``out``; a
        piece of `RATE_PIECE` pixels stays in cache through the dozen element-wise
        steps."""
        self._rates(x, var_rnoise, var_per_rate, out)
        return out

    def _rates(self, x, var_rnoise, var_per_rate, out):
        """`rates` into ``out``; returns whether the piece was clean (every slope and
        variance finite, every spread positive: each rate is then finite and >= 0)."""
        m, mp, tau2 = self.m, self.mp, self.tau2
        half = OWN_RATE_SIGMA ** 2 / 2
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            spread = np.multiply(mp, var_per_rate, out=np.empty(x.size))  # each slope's
            spread += var_rnoise  # noise at the bulk's rate, and the rates' spread
            spread += tau2
            # clean: three reductions (a NaN or inf makes a sum non-finite, a min not > 0)
            clean = bool(x.size and spread.min() > 0 and np.isfinite(spread.sum())
                         and np.isfinite(x.sum()))
            if not clean:  # a variance NaN or inf, or a slope: the pixel's own rate
                ok = np.isfinite(spread)
                ok &= np.isfinite(x)
                pos = spread > 0  # else 0 / 0: masked divisions (slower)
            d = x - m
            far = d * d
            if tau2 > 0:  # the rates spread: shrink the slope toward the bulk's
                shrunk = d * tau2
                if clean:
                    shrunk /= spread
                else:
                    shrunk = np.divide(shrunk, spread, out=np.zeros_like(d), where=pos)
            spread *= 2
            if clean:
                far /= spread
            else:
                far = np.divide(far, spread, out=np.full_like(d, np.inf), where=pos)
            # the logistic weight 1 / (1 + exp(half - far)) (scipy's expit takes 3x
            # as long); far = inf (spread 0) gives 1, a huge exp 0
            np.subtract(half, far, out=far)
            np.exp(far, out=far)
            far += 1.0
            np.reciprocal(far, out=far)
            # (1 - far) (m + shrunk) + far x = m + shrunk + far (d - shrunk), >= 0
            if tau2 > 0:
                d -= shrunk
                d *= far
                d += shrunk
            else:  # a flat bulk: every pixel's expected rate is the bulk's
                d *= far
            d += m
            if clean:
                np.maximum(d, 0.0, out=out)
            else:  # a pixel's own max(x, 0) where not ok
                np.maximum(d, 0.0, out=d)
                np.maximum(x, 0.0, out=out)
                np.copyto(out, d, where=ok)
        return clean


def expected_errors(slope, var_rnoise, var_per_rate, err, bulk=None, threads=1):
    """Uncertainties from the read noise and the shot noise of each pixel's expected rate.

    ``err`` (written in place: the caller's own array) becomes ``sqrt(var_rnoise +
    rate * var_per_rate)`` for the `expected_rates` ``rate``, where ``err`` is
    finite (a pixel not fitted keeps its NaN) and that variance finite and
    non-negative.  The rates are never held whole: each piece of `RATE_PIECE`
    pixels goes from slopes to uncertainties in cache, the pieces on ``threads``
    threads (each pixel's number is its own, whatever the pieces and threads).

    Parameters
    ----------
    slope : `numpy.ndarray`
        Slopes (data unit / s), NaN where not fitted.
    var_rnoise, var_per_rate : `numpy.ndarray`
        The slopes' variance at zero rate ((data unit / s)**2) and per unit rate
        (data unit / s), of ``slope``'s shape.
    err : `numpy.ndarray`
        Uncertainties (data unit / s) of ``slope``'s shape, C-ordered; rewritten.
    bulk : `numpy.ndarray` of bool, optional
        As `expected_rates`.
    threads : int
        Threads the pieces are worked on.

    Returns
    -------
    bool
        False (``err`` untouched) with too few pixels to see the bulk.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.expected_rates import expected_errors
    >>> slope = 0.01 + 0.04 * np.random.default_rng(0).standard_normal(10000)
    >>> err = np.full(10000, 1.0)
    >>> expected_errors(slope, np.full(10000, 0.0016), np.full(10000, 0.01), err)
    True
    >>> round(float(err[1]), 3)  # sqrt(0.0016 + 0.01 * 0.01): the bulk's rate, ~0.01
    0.041
    """
    bulk = RateBulk.measure(slope, var_rnoise, var_per_rate, bulk)
    if bulk is None:
        return False
    if not err.flags.c_contiguous:
        raise ValueError("err must be C-ordered (it is written through a flat view)")
    slope, var_rnoise, var_per_rate = bulk.flat(slope, var_rnoise, var_per_rate)
    flat = err.reshape(-1)

    def piece(lo):
        cut = slice(lo, lo + RATE_PIECE)
        x, rnoise, per_rate = slope[cut], _take(var_rnoise, cut), _take(var_per_rate, cut)
        var = np.empty(x.size)
        clean = bulk._rates(x, rnoise, per_rate, var)
        var *= per_rate
        var += rnoise
        redo = np.isfinite(flat[cut])  # (not fitted: kept)
        if not (clean and var.min() >= 0):  # (else every variance is finite and >= 0)
            with np.errstate(invalid="ignore"):
                redo &= var >= 0
            redo &= np.isfinite(var)
        np.sqrt(var, out=flat[cut], where=redo)

    for _ in in_threads(range(0, flat.size, RATE_PIECE), piece, threads,
                        name="spherex-reduce-err"):
        pass
    return True
