"""Telegraph reference pixels: found from their reads over the exposure, left out.

The paper (§6) finds the large-scale stability of the real array limited by
random telegraph noise in the reference pixels: a pixel that jumps between two
levels moves the mean of its channel's reference pixels each time it switches.
Over an exposure every reference pixel is read many times (each frame, and a
reference row several times per frame with distributed reference reads), so
such a pixel shows in its own history.

The test (`find_telegraph`): from every reference read, remove what all
pixels of that read share, the median of its channel's pixels of the same
sample parity (offsets, drift, alternating column noise); the variance of each
pixel's residuals over the exposure (its samples: frames times the reads of its
row) is then its own noise plus ``A² q (1 - q)`` from a telegraph of step
``A`` spending a fraction ``q`` of the time in its upper state.  A pixel is
telegraph when the logarithm of that variance lies more than ``sigma`` robust
standard deviations (1.4826 median absolute deviations) above the median of
its channel's reference pixels.  The population sets the scale, so pixels
with more reads, a noisier channel or real pixel-to-pixel differences need no
noise model.

False alarms: on telegraph-free noise the logarithm of a sample variance of
``n`` values is near normal with a short upper tail (standard deviation
``sqrt(2 / (n - 1))``), so the default ``sigma = 5`` flags fewer than the
Gaussian ``3e-7`` of a channel's pixels; measured on the paper's case
(``benchmarks/bench_telegraph.py``), none of the 16 384 reference-row pixels
of 5 telegraph-free full-size exposures.  Pixels with fewer than
`MIN_SAMPLES` usable samples (a slope image has one frame) and channels with
fewer than `MIN_PIXELS` testable pixels are not tested.
"""

import warnings
from dataclasses import dataclass

import numpy as np
from astropy.table import Table

from ...core.parameters import Parameter

__all__ = ["MIN_PIXELS", "MIN_SAMPLES", "TELEGRAPH_PARAMETERS", "TelegraphSearch",
           "drop_telegraph", "find_telegraph"]

#: Fewest usable samples (frames x reads of its row) a pixel needs to be tested.
MIN_SAMPLES = 16
#: Fewest testable reference pixels a channel needs for its population statistics.
MIN_PIXELS = 16
_MAD_TO_SIGMA = 1.4826

#: The reference strategies' parameters of the search (``mean``, ``acn``, ``wiener``).
TELEGRAPH_PARAMETERS = (
    Parameter("telegraph", "auto", (str,), "auto: leave out the reference pixels whose reads "
              "over the exposure are telegraph-like; keep: use every reference pixel",
              choices=("auto", "keep")),
    Parameter("telegraph_sigma", 5.0, (float,), "threshold of the telegraph test: robust "
              "standard deviations above the channel's reference pixels", minimum=0,
              exclusive_minimum=True),
)


@dataclass(frozen=True)
class TelegraphSearch:
    """What `find_telegraph` found.

    Attributes
    ----------
    reads : `numpy.ndarray`
        ``(k, ncols)`` bool: True at every read of a telegraph pixel (the
        values' reads and columns).
    rows, columns, channels : `numpy.ndarray`
        Physical row, column and channel of every telegraph pixel.
    score : `numpy.ndarray`
        Its log-variance above the channel's median, in robust standard
        deviations.
    count, tested : `numpy.ndarray`
        ``(nchannels,)``: telegraph pixels found, and pixels tested, per channel.
    sigma : float
        The threshold.
    """

    reads: np.ndarray
    rows: np.ndarray
    columns: np.ndarray
    channels: np.ndarray
    score: np.ndarray
    count: np.ndarray
    tested: np.ndarray
    sigma: float

    def table(self):
        """The ``REFTELEG`` table: ``row column channel score`` of every pixel left out."""
        t = Table({"row": self.rows, "column": self.columns, "channel": self.channels,
                   "score": self.score.astype(np.float32)},
                  meta={"sigma": self.sigma, "tested": int(self.tested.sum())})
        t["score"].description = ("log-variance of the pixel's reads above its channel's "
                                  "reference pixels (robust standard deviations)")
        return t

    def combine(self, other):
        """This search and ``other`` (another set of reads) together."""
        return TelegraphSearch(self.reads, *(np.concatenate([getattr(self, n), getattr(other, n)])
                                             for n in ("rows", "columns", "channels", "score")),
                               self.count + other.count, self.tested + other.tested, self.sigma)


def find_telegraph(values, rows, geometry, sigma=5.0):
    """Reference pixels whose reads over the exposure are telegraph-like.

    Parameters
    ----------
    values : `numpy.ndarray`
        ``(L, k, ncols)`` float: ``k`` reads of reference pixels in each of
        ``L`` frames (any unit); NaN where unusable.  Columns never to be
        tested may be NaN throughout.
    rows : array_like of int
        ``(k,)``: the physical row of each read; a pixel's samples are those of
        every read of its row in every frame.
    geometry : `~spherex_reduce.DetectorGeometry`
    sigma : float
        Threshold, in robust standard deviations of the channel's pixels.

    Returns
    -------
    `TelegraphSearch`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.reduce.steps.telegraph import find_telegraph
    >>> g = DetectorGeometry(16, 64, 2, ref_border=2)
    >>> rng = np.random.default_rng(0)
    >>> v = rng.normal(0, 1, (40, 4, 64))          # 40 frames, reads of rows 0, 1, 14, 15
    >>> v[:, [0, 2], 5] += 3 * (rng.random((40, 1)) < 0.5)   # pixel (row 0, column 5)
    >>> found = find_telegraph(v, [0, 15, 0, 14], g)
    >>> found.rows.tolist(), found.columns.tolist(), found.count.tolist()
    ([0], [5], [1, 0])
    """
    values = np.asarray(values, dtype=np.float64)
    rows = np.asarray(rows, dtype=int)
    nch, ncols = geometry.nchannels, geometry.ncols
    resid = _residuals(values, geometry)
    uniq, inverse = np.unique(rows, return_inverse=True)
    var = np.full((uniq.size, ncols), np.nan)
    with warnings.catch_warnings():  # pixels without usable samples: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        for i in range(uniq.size):
            x = resid[:, inverse == i].reshape(-1, ncols)
            n = np.isfinite(x).sum(axis=0)
            v = np.nanvar(x, axis=0, ddof=1)
            var[i] = np.where(n >= MIN_SAMPLES, v, np.nan)
        logv = np.where(var > 0, np.log(np.where(var > 0, var, 1.0)), np.nan)
    channel = geometry.channel_of_column()
    score = np.full(logv.shape, np.nan)
    tested = np.zeros(nch, dtype=np.int64)
    for ch in range(nch):
        own = logv[:, channel == ch]
        ok = np.isfinite(own)
        if ok.sum() < MIN_PIXELS:
            continue
        med = np.median(own[ok])
        spread = _MAD_TO_SIGMA * np.median(np.abs(own[ok] - med))
        if spread > 0:
            score[:, channel == ch] = (own - med) / spread
            tested[ch] = ok.sum()
    with np.errstate(invalid="ignore"):
        found = score > sigma
    r, c = np.nonzero(found)
    return TelegraphSearch(found[inverse], uniq[r], c, channel[c], score[r, c],
                           np.bincount(channel[c], minlength=nch), tested, float(sigma))


def _residuals(values, geometry):
    """Each read minus the median of its channel's pixels of the same sample parity."""
    width = geometry.channel_width
    if width % 2 == 0:  # the sample parities are the even and odd columns of a channel
        v = values.reshape(*values.shape[:2], geometry.nchannels, width // 2, 2)
        med = _median_last(np.moveaxis(v, 3, -1))[:, :, :, None, :]
        return (v - med).reshape(values.shape)
    group = geometry.channel_of_column() * 2 + geometry.column_offsets() % 2
    out = np.empty_like(values)
    for gid in np.unique(group):
        cols = np.flatnonzero(group == gid)
        out[:, :, cols] = values[:, :, cols] - _median_last(values[:, :, cols])[..., None]
    return out


def _median_last(a):
    """Median along the last axis, NaN ignored (NaN where all are): sorting a few tens of
    values is several times faster than `numpy.nanmedian`."""
    s = np.sort(a, axis=-1)  # NaN last
    n = np.isfinite(s).sum(axis=-1, keepdims=True)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0), axis=-1)[..., 0]
    hi = np.take_along_axis(s, np.maximum(n // 2, 0).clip(max=s.shape[-1] - 1), axis=-1)[..., 0]
    return np.where(n[..., 0] > 0, 0.5 * (lo + hi), np.nan)


def drop_telegraph(values, rows, geometry, sigma=5.0):
    """``values`` with the reads of telegraph pixels NaN (a new array), and the search.

    Parameters and ``values`` as `find_telegraph`.

    Returns
    -------
    values : `numpy.ndarray`
    found : `TelegraphSearch`
    """
    found = find_telegraph(values, rows, geometry, sigma)
    out = np.array(values, dtype=np.float64)
    out[:, found.reads] = np.nan
    return out, found
