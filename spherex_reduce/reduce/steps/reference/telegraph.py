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
pixel's residuals over the exposure is then its own noise plus
``A² q (1 - q)`` from a telegraph of step ``A`` spending a fraction ``q`` of
the time in its upper state.  The variance is taken at several time scales:
over every read (a telegraph switching within frames), and over the means of
blocks of 1, 2, 4 ... frames while a pixel keeps at least `MIN_SAMPLES` blocks
(averaging lowers the noise, not a slow telegraph's levels: a telegraph that
switched once or twice shows there).  At each scale a pixel's score is the
logarithm of its variance above the median of its channel's reference
pixels, in robust standard deviations (1.4826 median absolute deviations);
a pixel is telegraph when its highest score exceeds ``sigma``.  The
population sets the scale, so pixels with more reads, a noisier channel or
real pixel-to-pixel differences need no noise model.

False alarms: on telegraph-free noise the logarithm of a sample variance of
``n`` values is near normal with a short upper tail (standard deviation
``sqrt(2 / (n - 1))``), so the default ``sigma = 5`` flags fewer than the
Gaussian ``3e-7`` of a channel's pixels at each of the (at most a handful of)
scales; measured on the paper's case (``benchmarks/bench_telegraph.py``),
none of the 16 384 reference-row pixels of 10 telegraph-free full-size
exposures.  Pixels with fewer than `MIN_SAMPLES` usable values at every scale
(a slope image has one frame) and channels with fewer than `MIN_PIXELS`
testable pixels are not tested.
"""

import warnings
from dataclasses import dataclass

import numpy as np
from astropy.table import Table

from ....core.parameters import Parameter

__all__ = ["MAD_TO_SIGMA", "MIN_COMMON", "MIN_PIXELS", "MIN_SAMPLES", "TELEGRAPH_PARAMETERS",
           "TelegraphSearch", "drop_telegraph", "find_telegraph", "nanmedian"]

#: Fewest usable samples (frames x reads of its row) a pixel needs to be tested.
MIN_SAMPLES = 16
#: Fewest testable reference pixels a channel needs for its population statistics.
MIN_PIXELS = 16
#: fewest pixels of a read, channel and parity whose median is taken as their common signal
MIN_COMMON = 8
#: Robust standard deviations per median absolute deviation (a Gaussian's).
MAD_TO_SIGMA = 1.4826

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
        deviations (the highest over the time scales tested).
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


def find_telegraph(values, rows, geometry, sigma=5.0, columns=None):
    """Reference pixels whose reads over the exposure are telegraph-like.

    Parameters
    ----------
    values : `numpy.ndarray`
        ``(L, k, ncols)`` float: ``k`` reads of reference pixels in each of
        ``L`` frames, in time order (any unit); NaN where unusable.  Columns
        never to be tested may be NaN throughout.  With ``columns``, ``(L, k, m)``:
        those columns only.
    rows : array_like of int
        ``(k,)``: the physical row of each read; a pixel's samples are those of
        every read of its row in every frame.
    geometry : `~spherex_reduce.DetectorGeometry`
    sigma : float
        Threshold, in robust standard deviations of the channel's pixels.
    columns : array_like of int, optional
        ``(m,)``, increasing: the detector column of each of ``values``' columns (e.g. the
        side reference columns alone); None: every column.

    Returns
    -------
    `TelegraphSearch`
        ``reads`` has ``values``' columns; ``columns`` are detector columns.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.reduce.steps.reference.telegraph import find_telegraph
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
    nch = geometry.nchannels
    at = np.arange(geometry.ncols) if columns is None else np.asarray(columns, dtype=int)
    ncols = at.size
    resid = _residuals(values, geometry, None if columns is None else at)
    uniq, inverse = np.unique(rows, return_inverse=True)
    channel = geometry.channel_of_column()[at]
    score = np.full((uniq.size, ncols), -np.inf)
    tested = np.zeros((uniq.size, ncols), bool)
    counts = np.bincount(inverse)
    if (counts == counts[0]).all():  # as many reads of every row: all rows at once
        grouped = resid[:, np.argsort(inverse, kind="stable")].reshape(
            values.shape[0], uniq.size, counts[0], ncols)
        grouped = np.moveaxis(grouped, 1, 2).reshape(values.shape[0], counts[0], -1)

        def log_variance(scale):
            return _log_variance(grouped, scale).reshape(uniq.size, ncols)
    else:
        by_row = [resid[:, inverse == i] for i in range(uniq.size)]

        def log_variance(scale):
            return np.stack([_log_variance(part, scale) for part in by_row])
    for scale in _scales(values.shape[0], counts):
        logv = log_variance(scale)
        for ch in range(nch):
            own = logv[:, channel == ch]
            ok = np.isfinite(own)
            if ok.sum() < MIN_PIXELS:
                continue
            med = np.median(own[ok])
            spread = MAD_TO_SIGMA * np.median(np.abs(own[ok] - med))
            if spread > 0:
                z = np.where(ok, (own - med) / spread, -np.inf)
                score[:, channel == ch] = np.maximum(score[:, channel == ch], z)
                tested[:, channel == ch] |= ok
    found = score > sigma
    r, c = np.nonzero(found)
    return TelegraphSearch(found[inverse], uniq[r], at[c], channel[c], score[r, c],
                           np.bincount(channel[c], minlength=nch),
                           np.bincount(channel, weights=tested.sum(axis=0),
                                       minlength=nch).astype(np.int64), float(sigma))


def _scales(nframes, reads_per_row):
    """The time scales tested: ``None`` (every read), then blocks of 1, 2, 4 ... frames while
    a pixel keeps `MIN_SAMPLES` blocks (frames of one read each: from 2 frames)."""
    scales = [None]
    b = 1 if reads_per_row.max(initial=1) > 1 else 2
    while nframes // b >= MIN_SAMPLES:
        scales.append(b)
        b *= 2
    return scales


def _log_variance(x, frames):
    """Log of the variance of each column's values ``x (L, m, ncols)`` (NaN: unusable), over
    every value (``frames`` None) or over the means of blocks of ``frames`` frames; NaN with
    fewer than `MIN_SAMPLES` values or a zero variance."""
    finite = np.isfinite(x).all()
    mean, variance = (np.mean, np.var) if finite else (np.nanmean, np.nanvar)
    with warnings.catch_warnings():  # columns without usable values: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        if frames is None:
            x = x.reshape(-1, x.shape[-1])
        else:
            nb = x.shape[0] // frames
            x = mean(x[:nb * frames].reshape(nb, -1, x.shape[-1]), axis=1)
        n = np.full(x.shape[-1], x.shape[0]) if finite else np.isfinite(x).sum(axis=0)
        var = variance(x, axis=0, ddof=1)
    ok = (n >= MIN_SAMPLES) & (var > 0)
    return np.where(ok, np.log(np.where(ok, var, 1.0)), np.nan)


def _residuals(values, geometry, columns=None):
    """Each read minus the median of its channel's pixels of the same sample parity
    (``values``' columns: ``columns`` of the detector, or every column with None).

    Where fewer than `MIN_COMMON` pixels share a read, channel and parity (the side
    reference columns: 2 per parity), the read is left as it is: the median of so few
    would carry a telegraph pixel's steps into its partners (with 2, both residuals are
    +-(a - b) / 2), and the test against the channel's other pixels tolerates the
    common drift they all share.
    """
    width = geometry.channel_width
    if columns is None and width % 2 == 0:  # the parities: a channel's even and odd columns
        v = values.reshape(*values.shape[:2], geometry.nchannels, width // 2, 2)
        grouped = np.moveaxis(v, 3, -1)
        med = nanmedian(grouped)
        med[np.isfinite(grouped).sum(axis=-1) < MIN_COMMON] = 0.0
        return (v - med[:, :, :, None, :]).reshape(values.shape)
    group = geometry.channel_of_column() * 2 + geometry.column_offsets() % 2
    if columns is not None:
        group = group[columns]
    out = np.empty_like(values)
    for gid in np.unique(group):
        cols = np.flatnonzero(group == gid)
        med = nanmedian(values[:, :, cols])
        med[np.isfinite(values[:, :, cols]).sum(axis=-1) < MIN_COMMON] = 0.0
        out[:, :, cols] = values[:, :, cols] - med[..., None]
    return out


def nanmedian(a, axis=-1):
    """`numpy.nanmedian` of ``a`` along one short ``axis`` (a read's few tens of reference
    pixels, a channel's few side pixels, a dark's frames), the same numbers: numpy takes
    the medians of short axes through masked arrays, several times slower than this one
    sort.  NaN where the axis holds only NaN.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.reference.telegraph import nanmedian
    >>> nanmedian(np.array([[3.0, np.nan, 1.0, 2.0], [np.nan] * 4])).tolist()
    [2.0, nan]
    """
    s = np.sort(a, axis=axis)  # NaN sorted last
    count = (~np.isnan(s)).sum(axis=axis, keepdims=True)
    top = s.shape[axis] - 1
    lo = np.take_along_axis(s, np.clip((count - 1) // 2, 0, top), axis=axis)
    hi = np.take_along_axis(s, np.clip(count // 2, 0, top), axis=axis)  # = lo when odd
    with np.errstate(invalid="ignore"):  # -inf and inf in the middle: NaN, as numpy's
        med = np.where(count > 0, (lo + hi) / 2, np.nan)
    return np.squeeze(med, axis=axis)


def drop_telegraph(values, rows, geometry, sigma=5.0, columns=None):
    """``values`` with the reads of telegraph pixels NaN (a new array), and the search.

    Parameters and ``values`` as `find_telegraph`.

    Returns
    -------
    values : `numpy.ndarray`
    found : `TelegraphSearch`
    """
    found = find_telegraph(values, rows, geometry, sigma, columns)
    out = np.array(values, dtype=np.float64)
    out[:, found.reads] = np.nan
    return out, found
