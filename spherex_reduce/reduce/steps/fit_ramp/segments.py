"""Ramps that are not whole: masked reads, saturation, jumps (the float64 path of ``fit_ramp``).

Most pixels of an exposure have every read usable and are fitted by one
weight vector shared by all (`~spherex_reduce.reduce.steps.fit_ramp.least_squares`).
The others come here, each fitted on its own reads, in float64:

1. **Usable reads**: finite, no flag but ``JUMP``, ``REFERENCE`` and
   ``NO_REFERENCE`` (`~spherex_reduce.core.dq.read_usable`), and before the
   first saturated read: a read above ``saturation`` or flagged ``SATURATED``
   ends the usable ramp (as in the JWST pipeline), since every later read of
   that pixel is saturated too.
2. **Segments**: a read flagged ``JUMP`` starts a new segment (the charge
   stepped between it and the read before).  Each segment with at least two
   usable reads is fitted by least squares (uniform weights, or generalised
   least squares for ``weighting='optimal'``); a one-read segment carries no
   slope.
3. **Combination**: the segments' slopes are averaged with inverse-variance
   weights, as stcal does.  A segment's variance is its read noise,
   ``read_noise**2 sum_f w_f**2 a_f`` (``a_f``: the read-noise variance of
   read ``f`` in units of one read's, 1/n for a group of n averaged frames),
   plus the shot noise of the pixel's rate pooled over its segments,
   ``rate / gain * w^T M w`` (``M``: the covariance of the accumulated charge
   per unit rate, `RampNoise.shot`); the rate is first the read-noise-weighted
   mean of the segments, then the result of the first combination.  Without
   ``read_noise`` the variance comes from the residuals of all the pixel's
   segments pooled: ``chi2 / (n - 2 n_segments)``.

The rate that sets the shot noise is never a segment's own measured slope
(that would weigh low slopes up: the bias stcal avoids the same way).
"""

from dataclasses import dataclass, field

import numpy as np

from ....core import dq
from ....core.limits import check_size

__all__ = ["RATIO_BINS", "RampNoise", "SegmentFit", "accumulate_reads", "fit_segments",
           "usable_reads"]

#: Bins per decade of ``rate / read_noise**2`` whose pixels share GLS weights (0.02 dex).
RATIO_BINS = 50
#: Most jumps (segments - 1) a pixel's fit handles; more, and its reads after are not used.
MAX_SEGMENTS = 64
#: pixels from which `accumulate_reads` works row by row
ROW_BY_ROW = 1024


def accumulate_reads(ufunc, x, dtype=None):
    """``ufunc.accumulate(x, axis=0, dtype=dtype)``: each read combined with the result of
    the reads before it, in that order, so the same numbers.

    numpy accumulates over the first axis column by column, with strided steps: for
    more than `ROW_BY_ROW` pixels a read a numpy call per read is several times faster
    (74 reads of 3000 float64 pixels: 0.3 ms against 1.1 ms; 16384 pixels: 1.3 against
    12 ms).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.segments import accumulate_reads
    >>> x = np.arange(6.0).reshape(3, 2)
    >>> accumulate_reads(np.add, x).tolist()
    [[0.0, 1.0], [2.0, 4.0], [6.0, 9.0]]
    """
    if x.ndim < 2 or x[0].size < ROW_BY_ROW or x.shape[0] < 2:
        return ufunc.accumulate(x, axis=0, dtype=dtype)
    out = np.empty(x.shape, x.dtype if dtype is None else dtype)
    out[0] = x[0]
    for i in range(1, x.shape[0]):
        ufunc(out[i - 1], x[i], out=out[i])
    return out


@dataclass(frozen=True, eq=False)
class RampNoise:
    """The noise of a ramp's reads: read times, read-noise factors, shot-noise covariance.

    Parameters
    ----------
    times : `numpy.ndarray`
        Read (or group mean) times (s), ``(nframes,)``.
    read_factors : `numpy.ndarray`, optional
        Variance of each read's read noise in units of one read's (1/n for a
        group of n averaged frames); ones if None.
    shot : `numpy.ndarray`, optional
        Covariance of the accumulated charge of reads ``i, j`` per unit rate
        (s), ``(nframes, nframes)``; ``min(t_i, t_j) - t_0`` if None.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.segments import RampNoise
    >>> n = RampNoise(np.array([0.0, 1.0, 2.0]))
    >>> n.shot.tolist()
    [[0.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, 2.0]]
    >>> w, var = n.gls_weights(0.0)  # white read noise: ordinary least squares
    >>> np.round(w, 12).tolist(), round(var, 12)
    ([-0.5, 0.0, 0.5], 0.5)
    """

    times: np.ndarray
    read_factors: np.ndarray | None = None
    shot: np.ndarray | None = None
    _gls: dict = field(default_factory=dict, repr=False)
    _steps: object = field(default=None, repr=False)

    def __post_init__(self):
        t = np.asarray(self.times, dtype=np.float64)
        check_size(self.nbytes(t.size), f"fit_ramp: the covariance of {t.size} reads")
        object.__setattr__(self, "times", t)
        if self.read_factors is None:
            object.__setattr__(self, "read_factors", np.ones(t.size))
        # single reads: min(t_i, t_j) - t_0 is a sum of the steps dt_k up to min(i, j), so
        # w^T M w = sum_k dt_k (sum_{i >= k} w_i)**2 (`shot_variance`: no nframes**2 work)
        steps = None
        if self.shot is None:
            rel = t - (t[0] if t.size else 0.0)
            object.__setattr__(self, "shot", np.minimum.outer(rel, rel))
            if t.size and (np.diff(t) >= 0).all():
                steps = np.diff(rel, prepend=0.0)[:, None]
        object.__setattr__(self, "_steps", steps)

    @staticmethod
    def nbytes(n):
        """Bytes the noise of ``n`` reads needs at once: the ``n x n`` shot covariance and,
        for a generalised least-squares fit, the covariance, its copy and the copy
        `numpy.linalg.solve` factorises (checked before any is made)."""
        return 8.0 * 4 * float(n) * n

    @classmethod
    def from_schedule(cls, schedule):
        """The noise of a schedule's reads or groups of averaged reads (its
        ``read_noise_factors`` and ``shot_covariance``)."""
        check_size(cls.nbytes(schedule.nframes),
                   f"fit_ramp: the covariance of {schedule.nframes} reads")
        times = schedule.frame_starts.to_value("s")
        reads = schedule.group_reads
        if all(len(r) == 1 and r[0] == g for g, r in enumerate(reads)):
            return cls(times)  # one read per frame: `shot_variance` from tail sums
        return cls(times, np.asarray(schedule.read_noise_factors, np.float64),
                   schedule.shot_covariance())

    def shot_variance(self, w):
        """``w[:, p] @ shot @ w[:, p]`` for every column ``p`` of ``w`` (nframes, m): the
        shot-noise variance of weighted sums per unit rate, each column summed in an order
        that does not depend on the other columns (no BLAS)."""
        if self._steps is not None:
            tail = accumulate_reads(np.add, w[::-1])[::-1]  # sum_{i >= k} w_i
            return (self._steps * tail * tail).sum(axis=0)
        mw = np.zeros_like(w)  # groups: nframes**2 work per pixel, no larger temporary
        for j in range(w.shape[0]):
            mw += self.shot[:, j:j + 1] * w[j]
        return (w * mw).sum(axis=0)

    def gls_weights(self, ratio, reads=None):
        """Generalised least-squares slope weights for ``rate / read_noise**2 == ratio``.

        Covariance (in units of one read's read-noise variance):
        ``diag(read_factors) + ratio * shot``, over ``reads`` (indices; all if None).

        Returns
        -------
        w : `numpy.ndarray`
            Weights (1/s) over ``reads``: the slope is ``w @ y[reads]``.
        variance : float
            The slope's variance in units of ``read_noise**2`` (1/s**2).
        """
        key = (ratio, None if reads is None else tuple(reads))
        found = self._gls.get(key)
        if found is not None:
            return found
        idx = slice(None) if reads is None else np.asarray(reads)
        t = self.times[idx]
        cov = np.diag(self.read_factors[idx]) + max(ratio, 0.0) * self.shot[np.ix_(
            np.arange(self.times.size)[idx], np.arange(self.times.size)[idx])]
        design = np.stack([np.ones_like(t), t - t[0]], axis=1)
        cinv_x = np.linalg.solve(cov, design)
        fisher_inv = np.linalg.inv(design.T @ cinv_x)
        found = ((cinv_x @ fisher_inv)[:, 1], float(fisher_inv[1, 1]))
        if len(self._gls) < 100_000:  # bounded: ratios are quantised, patterns are few
            self._gls[key] = found
        return found


@dataclass
class SegmentFit:
    """The fits of some pixels' ramps, each ``(m,)``.

    Attributes
    ----------
    slope, var : `numpy.ndarray` of float64
        Combined slope (data unit / s) and its variance (NaN: fewer than two
        usable reads in every segment, or not asked for).
    nreads : `numpy.ndarray` of int16
    njumps, nsegments : `numpy.ndarray` of int8
        Usable reads, jumps that split usable reads (flagged on a usable read
        after another), and segments fitted.
    flags : `numpy.ndarray` of uint32
        ``FEW_READS``, ``SATURATED`` (saturation cut the ramp), ``JUMP``
        (fitted around jumps), and the flags set on every read.
    var_rnoise, var_per_rate : `numpy.ndarray` of float64
        With ``read_noise``: the variance at zero rate (read noise and the dark
        current's shot noise) and the shot-noise variance per unit of rate, of
        the combination with the final weights (segments' shot noises are
        independent: they come from disjoint intervals).  NaN otherwise.
    """

    slope: np.ndarray
    var: np.ndarray
    nreads: np.ndarray
    njumps: np.ndarray
    nsegments: np.ndarray
    flags: np.ndarray
    var_rnoise: np.ndarray
    var_per_rate: np.ndarray


def usable_reads(y, flags, saturation):
    """``(usable, saturated_pixel)``: reads to fit (finite, not flagged, before the first
    read flagged ``SATURATED`` or above ``saturation``), and pixels whose ramp saturation
    cut.  ``y`` and ``flags`` (or None) are ``(reads, pixels)``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.segments import usable_reads
    >>> y = np.array([[1.0, 1.0], [2.0, np.nan], [9.0, 3.0], [4.0, 4.0]])
    >>> usable, saturated = usable_reads(y, None, saturation=5.0)
    >>> usable.T.astype(int).tolist(), saturated.tolist()
    ([[1, 1, 0, 0], [1, 0, 1, 1]], [True, False])
    """
    usable = np.isfinite(y)
    sat = None
    if saturation is not None:
        with np.errstate(invalid="ignore"):
            sat = y > saturation
    present = 0 if flags is None else np.bitwise_or.reduce(flags, axis=None)  # bits set
    if present & dq.SATURATED:
        flagged = (flags & dq.SATURATED) != 0
        sat = flagged if sat is None else sat | flagged
    if present & ~dq.DQ_TYPE(dq.READ_INFORMATIONAL):
        usable &= dq.read_usable(flags)
    if sat is None:
        return usable, np.zeros(y.shape[1:], bool)
    if sat.any():  # the first saturated read and every later one
        usable &= ~accumulate_reads(np.logical_or, sat)
    return usable, sat.any(axis=0)


def _weights(good, t, noise, shot):
    """Least-squares weights of the reads ``good`` (``(nframes, k)``, ``k >= 2``, a column
    each): ``(tbar, stt, rvar, pf)``, the mean of their times ``t``, ``sum tc**2`` (``tc``:
    times less the mean, 0 off the reads), ``sum w**2 a`` (``w = tc / stt``: the slope's
    weights; ``a``: the read-noise factors) and ``w^T M w`` (`RampNoise.shot_variance`;
    None unless ``shot``)."""
    g = good.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        tbar = (g * t).sum(axis=0) / g.sum(axis=0)
        tc = (t - tbar) * g
        stt = (tc * tc).sum(axis=0)
        w = tc / stt
        rvar = (w * w * noise.read_factors[:, None]).sum(axis=0)
        return tbar, stt, rvar, noise.shot_variance(w) if shot else None


def _fit_segment(y, good, cols, n, a, b, t, noise, work, shot, residuals):
    """Least squares of one segment of the pixels ``cols`` (columns of ``y``): their reads
    ``good``, ``n`` (two or more) of them, between reads ``a`` and ``b - 1``.  Returns
    ``(slope, stt, rvar, pf, chi2)`` of those pixels (`_weights`; ``chi2``, the sum of
    squared residuals, None unless ``residuals``).

    Every column is summed on its own, read after read (C-ordered, two columns or more), so
    a pixel's numbers do not depend on the others: the weights are computed once per
    pattern of reads (most a run ``a..b-1``), and the slopes on every column of ``y`` when
    most pixels have the segment (no gather; ``work``: a float64 buffer of two ``y``).
    """
    nf, m = y.shape
    k = cols.size
    part = np.flatnonzero(n != b - a)  # reads missing (masked, saturated): the first, last
    if part.size:
        some = good[:, cols[part]]
        a[part] = np.argmax(some, axis=0)
        b[part] = nf - np.argmax(some[::-1], axis=0)
    run = n == b - a
    found, inverse = np.unique(a[run] * (nf + 1) + b[run], return_inverse=True)
    holes = np.flatnonzero(~run)  # each its own pattern
    pat = np.empty(k, np.intp)
    pat[run] = inverse.ravel()
    pat[holes] = found.size + np.arange(holes.size)
    rows = np.arange(nf)[:, None]
    pats = np.concatenate([(rows >= found // (nf + 1)) & (rows < found % (nf + 1)),
                           good[:, cols[holes]]], axis=1)
    tbar, stt, rvar, pf = (None if v is None else v[pat] for v in _weights(
        pats if pats.shape[1] > 1 else np.repeat(pats, 2, axis=1), t, noise, shot))
    if 2 * k >= m:
        yw, gw, at = y, good, cols
    else:
        pick = cols if k > 1 else np.repeat(cols, 2)
        yw, gw, at = y[:, pick], good[:, pick], np.arange(k)
    kw = yw.shape[1]
    first, tw, sw = np.zeros(kw, np.intp), np.zeros(kw), np.ones(kw)
    first[at], tw[at], sw[at] = a, tbar, stt
    chi2 = None
    with np.errstate(invalid="ignore", divide="ignore"):
        # reads minus the pixel's first read of the segment (float32 pedestals stay exact),
        # 0 off the segment (+0.0: all bits cleared); times less their mean
        d = np.subtract(yw, yw[first, np.arange(kw)], out=work[:nf * kw].reshape(nf, kw))
        np.bitwise_and(d.view(np.int64), np.negative(gw.view(np.int8)), out=d.view(np.int64))
        tc = np.subtract(t, tw, out=work[nf * m:nf * (m + kw)].reshape(nf, kw))
        if residuals:
            g = gw.astype(np.float64)
            tc *= g
            slope = (tc * d).sum(axis=0) / sw
            nw = np.ones(kw)
            nw[at] = n
            resid = (d - d.sum(axis=0) / nw - slope * tc) * g
            chi2 = (resid * resid).sum(axis=0)[at]
        else:  # (off the segment (t - tbar) * 0.0: the product of the masked tc)
            slope = np.multiply(tc, d, out=tc).sum(axis=0) / sw
    return slope[at], stt, rvar, pf, chi2


def fit_segments(y, flags, noise, *, saturation=None, read_noise=None, pscale=None, dark=0.0,
                 weighting="uniform", want_var=True):
    """Fit the usable segments of some pixels' ramps and combine them (see the module).

    Parameters
    ----------
    y : `numpy.ndarray`
        Reads ``(nframes, m)``, float64.
    flags : `numpy.ndarray` or None
        uint32 flags of every read, ``(nframes, m)``.
    noise : `RampNoise`
    saturation : float, optional
        Reads above this level (data unit) end the usable ramp.
    read_noise : float or `numpy.ndarray` or None
        Read noise per read (data unit), one or ``(m,)``; None: variance from
        the residuals.
    pscale : float or `numpy.ndarray` or None
        1 / gain (shot noise; None or 0: none, in the weights too).
    dark : float or `numpy.ndarray`
        Dark current already subtracted from the reads (data unit / s), whose
        shot noise the variance includes.
    weighting : {'uniform', 'optimal'}
    want_var : bool

    Returns
    -------
    `SegmentFit`

    Examples
    --------
    A ramp of slope 2 with a jump of 50 before read 3: one slope from its two
    segments, fitted around the jump.

    >>> import numpy as np
    >>> from spherex_reduce import dq
    >>> from spherex_reduce.reduce.steps.fit_ramp.segments import RampNoise, fit_segments
    >>> t = np.arange(6.0)
    >>> y = (2.0 * t + 50.0 * (t >= 3))[:, None].repeat(2, axis=1)
    >>> flags = np.zeros(y.shape, np.uint32)
    >>> flags[3, 0] = dq.JUMP  # the second pixel's jump is not flagged
    >>> fit = fit_segments(y, flags, RampNoise(t), read_noise=1.0)
    >>> fit.slope.round(6).tolist(), fit.nsegments.tolist(), dq.describe(fit.flags[0])
    ([2.0, 14.857143], [2, 1], ['JUMP'])
    """
    m = y.shape[1]
    if m == 1:  # numpy sums a lone column pairwise, C-ordered columns frame after frame:
        # two columns keep a pixel's numbers those of the same pixel among many
        fit = fit_segments(np.repeat(y, 2, axis=1),
                           None if flags is None else np.repeat(flags, 2, axis=1), noise,
                           saturation=saturation, read_noise=_two(read_noise),
                           pscale=_two(pscale), dark=_two(dark), weighting=weighting,
                           want_var=want_var)
        return SegmentFit(*(getattr(fit, k)[:1] for k in SegmentFit.__dataclass_fields__))
    y = np.ascontiguousarray(y)
    nf = y.shape[0]
    pscale = 0.0 if pscale is None else pscale  # no shot noise: a zero factor
    usable, saturated = usable_reads(y, flags, saturation)
    jumps = np.zeros(y.shape, bool) if flags is None else (flags & dq.JUMP) != 0
    # the segment of each read: the jumps up to it (the reads after MAX_SEGMENTS unused);
    # segment s of a pixel: reads starts[s] to starts[s + 1] - 1
    itype = np.int16 if nf < 1 << 15 else np.intp
    seg = accumulate_reads(np.add, jumps, itype)
    usable &= seg <= MAX_SEGMENTS
    nseg_max = min(int(seg.max(initial=0)), MAX_SEGMENTS) + 1
    jr, jc = np.divmod(np.flatnonzero(jumps), m)
    js = seg[jr, jc]
    starts = np.full((nseg_max + 1, m), nf)
    starts[0] = 0
    starts[js[js <= nseg_max], jc[js <= nseg_max]] = jr[js <= nseg_max]
    cum = np.concatenate([np.zeros((1, m), itype), accumulate_reads(np.add, usable, itype)])
    counts = np.diff(np.take_along_axis(cum, starts, axis=0), axis=0)  # usable reads
    # a jump counts (njumps, the JUMP flag) where it splits usable reads: on a usable read
    # with usable reads before it (a JUMP on a read that is not used, or on the first
    # usable read, changes nothing in the fit)
    njumps = np.bincount(jc[usable[jr, jc] & (cum[jr, jc] > 0)], minlength=m)
    t = (noise.times - noise.times.mean())[:, None]  # centred times
    rn2 = None if read_noise is None else np.broadcast_to(np.asarray(read_noise) ** 2, (m,))

    # each segment fitted on the pixels where it has two usable reads (its reads' numbers do
    # not depend on the other pixels); elsewhere it carries no slope
    slopes, rvars, pfs, stts = np.full((4, nseg_max, m), np.nan)
    chi2s, ns = np.zeros((nseg_max, m)), np.zeros((nseg_max, m))
    work = np.empty(2 * y.size)
    for s in range(nseg_max):
        cols = np.flatnonzero(counts[s] >= 2)
        if not cols.size:
            continue
        n = counts[s, cols]
        slope, stt, rvar, pf, chi2 = _fit_segment(
            y, usable & (seg == s), cols, n, starts[s, cols], starts[s + 1, cols], t, noise,
            work, rn2 is not None, rn2 is None)
        slopes[s, cols], stts[s, cols], rvars[s, cols], ns[s, cols] = slope, stt, rvar, n
        if pf is not None:  # (a residual variance needs no shot noise)
            pfs[s, cols] = pf
        if chi2 is not None:
            chi2s[s, cols] = chi2
    nseg = np.array(ns).astype(bool).sum(axis=0)
    nreads = cum[-1]
    fitted = np.isfinite(slopes)

    rate_used = None  # the rate of the GLS weights (optimal): it sets the shot noise too
    if weighting == "optimal" and rn2 is not None:
        slopes, rvars, pfs, rate_used = _optimal_segments(y, usable, seg, noise, slopes, rvars,
                                                          pfs, fitted, rn2, pscale, dark)

    rnoise = per_rate = np.full(m, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        if rn2 is None:  # pooled residual variance of all segments
            dof = nreads - 2 * nseg
            s2 = np.where(dof > 0, np.sum(chi2s, axis=0) / dof, np.nan)
            # one variance s2 for every read: the segments' weights are their sum(tc**2)
            slope, var = _combine(slopes, 1.0 / stts, fitted)
            var = var * s2
        else:
            seg_var = rn2 * rvars  # read noise alone first
            slope, var = _combine(slopes, seg_var, fitted)
            if rate_used is not None:
                seg_var = rn2 * rvars + rate_used * pscale * pfs
                slope, var = _combine(slopes, seg_var, fitted)
            elif np.any(pscale):
                for _ in range(2):  # pooled rate -> shot noise of every segment -> again
                    rate = np.maximum(np.where(np.isfinite(slope), slope, 0.0), 0.0) + dark
                    seg_var = rn2 * rvars + rate * pscale * pfs
                    slope, var = _combine(slopes, seg_var, fitted)
            a = np.where(fitted, (1.0 / seg_var) * var, 0.0)  # the final weights
            shot = pscale * np.where(fitted, pfs, 0.0)
            per_rate = (a * a * shot).sum(axis=0)
            rnoise = (a * a * np.where(fitted, rn2 * rvars, 0.0)).sum(axis=0) + dark * per_rate
    few = nseg == 0
    slope[few] = np.nan
    var[few] = np.nan
    if not want_var:
        var[:] = np.nan
    pix = np.zeros(m, dq.DQ_TYPE)
    if flags is not None:
        pix |= np.bitwise_and.reduce(flags, axis=0) & ~dq.DQ_TYPE(dq.JUMP)
    pix[few] |= dq.FEW_READS
    pix[saturated] |= dq.SATURATED
    pix[njumps > 0] |= dq.JUMP
    return SegmentFit(slope, var, nreads.astype(np.int16), njumps.astype(np.int8),
                      nseg.astype(np.int8), pix, rnoise, per_rate)


def _two(value):
    """A per-pixel value of one pixel repeated for two (a number as it is)."""
    return np.repeat(value, 2) if isinstance(value, np.ndarray) and value.ndim else value


def _combine(slopes, variances, fitted):
    """Inverse-variance mean over segments (axis 0) of the fitted ones, and its variance.

    Segments of zero variance (no read noise, no signal) outweigh the others: a pixel
    that has some is the plain mean of those, with variance 0.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        exact = fitted & ~(variances > 0)
        w = np.where(exact.any(axis=0), exact.astype(float), np.where(fitted, 1.0 / variances,
                                                                        0.0))
        total = w.sum(axis=0)
        mean = (w * np.where(fitted, slopes, 0.0)).sum(axis=0) / total
        return mean, np.where(exact.any(axis=0), 0.0, 1.0 / total)


def _optimal_segments(y, usable, seg, noise, slopes, rvars, pfs, fitted, rn2, pscale, dark):
    """GLS slopes of the fitted segments, weights shared by pixels with the same usable reads
    and the same ``rate / read_noise**2`` (quantised); ``(slopes, rvars, pfs)`` replaced, and
    the quantised rate (dark included) of each pixel's weights."""
    slopes, rvars, pfs = slopes.copy(), rvars.copy(), pfs.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        pooled, _ = _combine(slopes, rvars, fitted)
        rate = np.maximum(np.where(np.isfinite(pooled), pooled, 0.0), 0.0) + dark
        ratio = rate * pscale / rn2
        key = np.where(ratio > 1e-6, np.round(np.log10(ratio) * RATIO_BINS), -np.inf)
    for s in range(slopes.shape[0]):
        good = usable & (seg == s)
        cols = np.flatnonzero(fitted[s])
        if not cols.size:
            continue
        patterns = np.packbits(good[:, cols], axis=0).T
        codes = np.concatenate([patterns.view(np.uint8).reshape(cols.size, -1),
                                key[cols, None].view(np.uint8).reshape(cols.size, -1)], axis=1)
        _, first, inverse = np.unique(codes, axis=0, return_index=True, return_inverse=True)
        for k, i in enumerate(first):
            members = cols[inverse.ravel() == k]
            reads = np.flatnonzero(good[:, cols[i]])
            q = key[cols[i]]
            at = 10 ** (q / RATIO_BINS) if np.isfinite(q) else 0.0
            w, _ = noise.gls_weights(at, tuple(reads))
            slopes[s, members] = np.einsum("f,fp->p", w, y[reads][:, members])
            rvars[s, members] = float((w * w * noise.read_factors[reads]).sum())
            pfs[s, members] = float(w @ noise.shot[np.ix_(reads, reads)] @ w)
    with np.errstate(invalid="ignore"):
        used = np.where(np.isfinite(key), 10 ** (key / RATIO_BINS), 0.0) * rn2
    pscale = np.broadcast_to(pscale, used.shape)  # (no shot noise: the weights' rate is 0)
    return slopes, rvars, pfs, np.divide(used, pscale, out=np.zeros(used.shape),
                                         where=pscale > 0)
