"""Least-squares slopes of a block of ramps: the numerics of ``fit_ramp``.

Frames are read at ``t_f = frame_start_f + tau``, where ``tau`` is the time of
the pixel within its frame (its read's start, plus its sample within the
channel's row).  ``tau`` differs from pixel to pixel but is the same for every
frame, so it only shifts each pixel's time axis: the least-squares slope with
an intercept does not depend on it, and the slope of a pixel whose reads are
all usable is ``sum_f w_f (y_f - y_0)`` with one weight vector ``w`` (centred
times over their sum of squares, `ramp_weights`) shared by every pixel.

`LeastSquares.fit` takes a block of ramps ``(frames, rows, columns)`` and
works through it a few rows at a time (a work buffer that stays in cache): the
first read is subtracted (exact in float32 for values within a factor two of
each other, e.g. a 6e4 pedestal), and the sums ``sum w d``, ``sum d`` and
``sum d**2`` are formed in float32 over groups of `GROUP` frames whose partial
sums are accumulated in float64.  Pixels with a NaN, saturated or flagged read
(and the few whose residuals are too small to be computed from float32 sums)
are refitted on a float64 path that uses only their usable reads
(`fit_usable_reads`).

Every pixel's numbers depend on its own reads only, never on the other pixels
of the block or on where the block starts: numpy's ``einsum``, and its
reduction over the first axis of a C-ordered array, add the frames of each
column one after another (a product, then a sum, each rounded), and
the float64 paths fit each column alone.  So a ramp cut into bands of rows and
fitted band by band, on any number of threads, gives the fit of the whole cube
bit for bit.
"""

import numpy as np

from ...core import dq
from ...core.exposure import as_dq

__all__ = ["GROUP", "LeastSquares", "RampSolution", "fit_usable_reads", "gls_weights",
           "poisson_factor", "ramp_weights"]

GROUP = 32  #: frames per float32 partial sum; the groups are summed in float64
BLOCK_PIXELS = 1 << 14  #: pixels per block of the work buffer (74 frames: 4.8 MB in float32)


def ramp_weights(times):
    """Uniform least-squares slope weights for reads at ``times``.

    Parameters
    ----------
    times : array_like
        Read times (s), shape ``(n,)``, ``n >= 2``.

    Returns
    -------
    w : `numpy.ndarray`
        Weights (1/s) with ``sum(w) == 0`` and ``sum(w * times) == 1``; the
        slope of reads ``y`` is ``w @ y`` and its variance for white noise of
        standard deviation ``s`` is ``s**2 * sum(w**2)``.

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.ramp_least_squares import ramp_weights
    >>> w = ramp_weights([0.0, 1.0, 2.0])
    >>> w.tolist()
    [-0.5, 0.0, 0.5]
    >>> float(w @ [3.0, 5.0, 7.0])
    2.0
    """
    t = np.asarray(times, dtype=np.float64)
    tc = t - t.mean()
    return tc / (tc @ tc)


def gls_weights(times, read_noise, rate):
    """Generalised least-squares slope weights and variance for read noise + shot noise.

    Covariance of reads ``i, j``: ``read_noise**2 delta_ij + rate * min(t_i, t_j)``
    (all in the data unit; ``rate`` is the expected accumulation per second).

    Returns
    -------
    w : `numpy.ndarray`
        Weights (1/s): the slope is ``w @ y``.
    variance : float
        The slope's variance (data unit / s)**2.
    """
    t = np.asarray(times, dtype=np.float64) - times[0]
    cov = read_noise**2 * np.eye(t.size) + max(rate, 0.0) * np.minimum.outer(t, t)
    design = np.stack([np.ones_like(t), t], axis=1)
    cinv_x = np.linalg.solve(cov, design)
    fisher_inv = np.linalg.inv(design.T @ cinv_x)
    w = (cinv_x @ fisher_inv)[:, 1]
    return w, fisher_inv[1, 1]


def poisson_factor(times, w):
    """``w^T min(t_i, t_j) w``: slope variance per unit of accumulation rate."""
    t = np.asarray(times, dtype=np.float64) - times[0]
    return float(w @ np.minimum.outer(t, t) @ w)


class RampSolution:
    """Fit of a family of ramps, shape ``(rows, columns)``.

    Attributes
    ----------
    slope : `numpy.ndarray` of float64
        Slopes (data unit / s), NaN for fewer than two usable reads.
    var : `numpy.ndarray` of float64
        Their variances (NaN where undefined or not asked for).
    nreads : `numpy.ndarray` of int16
        Reads used.
    flags : `numpy.ndarray` of uint32
        `~spherex_reduce.core.dq.FEW_READS`, `~spherex_reduce.core.dq.SATURATED` and the
        flags set on every read of the pixel.
    """

    def __init__(self, shape):
        self.slope = np.empty(shape, np.float64)
        self.var = np.empty(shape, np.float64)
        self.nreads = np.empty(shape, np.int16)
        self.flags = np.empty(shape, np.uint32)

    def rows(self, rows):
        """A solution viewing rows ``rows`` (a slice) of this one."""
        view = RampSolution.__new__(RampSolution)
        for name in ("slope", "var", "nreads", "flags"):
            setattr(view, name, getattr(self, name)[rows])
        return view

    def put(self, rows, part):
        """Write ``part`` (a `RampSolution`) at rows ``rows`` (indices or a slice)."""
        for name in ("slope", "var", "nreads", "flags"):
            getattr(self, name)[rows] = getattr(part, name)


def fit_usable_reads(y, good, times, read_noise, poisson_scale):
    """Float64 least squares on the usable reads of some pixels (each column alone).

    Parameters
    ----------
    y, good : `numpy.ndarray`
        Reads (float64) and whether they are usable, shape ``(nframes, m)``.
    times : `numpy.ndarray`
        Read times (s), ``(nframes,)``.
    read_noise : float or None
        None: variance from the residuals; else the read-noise model (plus the
        shot noise if ``poisson_scale``, 1 / gain, is given).
    poisson_scale : float or None

    Returns
    -------
    slope, var : `numpy.ndarray`
        ``(m,)``, NaN where undefined.
    nreads : `numpy.ndarray` of int16
        Reads used.

    Notes
    -----
    A pixel's numbers do not depend on the other pixels fitted with it: numpy
    sums a lone (contiguous) column pairwise but the columns of a C-ordered
    array one frame after another, so the arrays are made C-ordered with at
    least two columns.
    """
    m = y.shape[1]
    y, good = np.ascontiguousarray(y), np.ascontiguousarray(good)
    if m == 1:
        y, good = np.repeat(y, 2, axis=1), np.repeat(good, 2, axis=1)
    g = good.astype(np.float64)
    n = g.sum(axis=0)
    t = (times - times.mean())[:, None]
    # subtract the first usable read: keeps float32 pedestals exact
    first = np.argmax(good, axis=0)
    y0 = np.take_along_axis(y, first[None], axis=0)[0]
    d = np.where(good, y - y0, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        tbar = (g * t).sum(axis=0) / n
        tc = (t - tbar) * g
        stt = (tc * tc).sum(axis=0)
        dbar = d.sum(axis=0) / n
        slope = (tc * d).sum(axis=0) / stt
        if read_noise is None:
            resid = (d - dbar - slope * tc) * g
            var = (resid * resid).sum(axis=0) / (n - 2) / stt
            var[n <= 2] = np.nan
        else:
            var = read_noise**2 / stt
            if poisson_scale:
                w = tc / stt
                mt = np.minimum.outer(times, times) - times[0]
                pf = np.einsum("im,ij,jm->m", w, mt, w)
                var = var + np.maximum(slope, 0) * poisson_scale * pf
    few = n < 2
    slope[few] = np.nan
    var[few] = np.nan
    return slope[:m], var[:m], n[:m].astype(np.int16)


def _accumulate(total, part, i):
    """``total = 0 + part`` for the first group (``i == 0``), else ``total += part``."""
    if i:
        total += part
    else:
        total[:] = part


class LeastSquares:
    """The least-squares fit of ramps read at ``times``, for blocks of any rows.

    Everything that depends only on the read times and the parameters (weights,
    thresholds, the generalised least-squares weights of ``optimal``) is
    computed once here; `fit` then fits any block of ramps, from several
    threads at once (each with its own work buffer).

    Parameters
    ----------
    times : array_like
        Frame start times (s), ``(nframes,)``.
    weighting : {'uniform', 'optimal'}
        ``'optimal'`` needs ``read_noise > 0``.
    read_noise : float, optional
        Read noise per read (data unit): the variance follows the read-noise
        and shot-noise model; None: from the fit residuals.
    gain : float
        Electrons per data unit (shot noise).
    saturation : float, optional
        Reads above this level are not used.
    want_var : bool
        False: no variances (NaN), e.g. for phantom values.
    """

    def __init__(self, times, *, weighting="uniform", read_noise=None, gain=1.0,
                 saturation=None, want_var=True):
        self.times = t = np.asarray(times, dtype=np.float64)
        self.nf = nf = t.size
        self.weighting, self.read_noise, self.saturation = weighting, read_noise, saturation
        self.want_var = want_var
        self.w = ramp_weights(t) if nf >= 2 else np.zeros(nf)
        tc = t - t.mean()
        self.stt = float(tc @ tc)
        self.sumw2 = float(self.w @ self.w)
        self.wmax = float(np.abs(self.w).max()) if nf else 0.0
        self.pscale = None if read_noise is None else 1.0 / gain
        self.pfactor = poisson_factor(t, self.w) if nf >= 2 else 0.0
        self.groups = [slice(g, min(g + GROUP, nf)) for g in range(0, nf, GROUP)]
        self._wwork = {work: self.w.astype(work) for work in (np.float32, np.float64)}
        self.resid = want_var and read_noise is None
        self._gls = {}  # quantised rate -> (weights, variance); the same for every block

    def work_type(self, dtype):
        """The type sums are formed in for pixels of ``dtype``: float64 or float32."""
        # by type, not byte order: big-endian float64 (as FITS stores it) is float64 too
        return np.float64 if np.dtype(dtype).newbyteorder("=") == np.float64 else np.float32

    def rows_per_block(self, ncols):
        """Rows of a block of the work buffer for ``ncols`` columns."""
        return max(1, BLOCK_PIXELS // max(ncols, 1))

    def buffer(self, ncols, dtype):
        """A work buffer for blocks of ``ncols`` columns of pixels of ``dtype``.

        One row per frame (the reads minus the first read) and one for partial sums.
        """
        return np.empty((self.nf + 1, self.rows_per_block(ncols) * ncols), self.work_type(dtype))

    def _kcrit(self, work):
        # refit in float64 where chi2 < kcrit * sum(d^2): (a) float32 sums of squares lose
        # the residual (relative error ~ nf eps sum(d^2) / chi2 above ~1e-3); (b) float32
        # sums of w d, in error by ~eps sqrt(group) max|w| sqrt(sum(d^2)), could exceed
        # 3e-4 of the slope's sigma, sqrt(chi2 / (nf - 2) sum(w^2))
        nf = self.nf
        eps = np.finfo(work).eps
        kcrit = 1000 * nf * eps
        if work is np.float32 and nf > 2:
            kcrit = max(kcrit,
                        (eps * np.sqrt(GROUP) * self.wmax / 3e-4) ** 2 * (nf - 2) / self.sumw2)
        return kcrit

    def fit(self, cube, mask=None, out=None, buf=None):
        """Fit every ramp of ``cube``.

        Parameters
        ----------
        cube : `numpy.ndarray`
            Reads ``(nframes, n, m)`` (any real type; never written).
        mask : array_like, optional
            Flags of every read, shape of ``cube`` (non-zero: not used).
        out : `RampSolution`, optional
            Where to write (C-ordered ``(n, m)`` arrays); a new one if None.
        buf : `numpy.ndarray`, optional
            A work buffer from `buffer` (one per thread).

        Returns
        -------
        `RampSolution`
        """
        nf, n, m = cube.shape
        if out is None:
            out = RampSolution((n, m))
        elif not all(getattr(out, k).flags.c_contiguous for k in ("slope", "var", "nreads",
                                                                   "flags")):
            raise ValueError("out must hold C-ordered arrays (they are written through views)")
        if (buf is None or buf.dtype != self.work_type(cube.dtype) or buf.shape[0] != nf + 1
                or buf.shape[1] < m):
            rows = min(self.rows_per_block(m), max(n, 1))
            buf = np.empty((nf + 1, rows * m), self.work_type(cube.dtype))
        per = max(1, min(buf.shape[1] // max(m, 1), n))
        for r0 in range(0, n, per):
            r1 = min(n, r0 + per)
            rows = slice(r0, r1)
            self._block(cube[:, rows], None if mask is None else mask[:, rows], out.rows(rows),
                        buf)
        return out

    def _block(self, block, rmask, fit, buf):
        """Fit ``block`` (nframes, rows, m) into ``fit`` (views of the output rows)."""
        nf, nr, m = block.shape
        npx = nr * m
        work = buf.dtype.type
        x = buf[:nf, :npx]
        slope = fit.slope.reshape(npx)
        var = fit.var.reshape(npx)
        nreads = fit.nreads.reshape(npx)
        flags = fit.flags.reshape(npx)
        nreads[:] = nf
        flags[:] = 0
        saturation, read_noise = self.saturation, self.read_noise
        kcrit = self._kcrit(work)
        imprecise = None  # pixels whose float32 sums are too coarse for a uniform slope
        if nf >= 2:
            # one pass: reads minus the first read, into a buffer that stays in cache
            if block.dtype == work and block.dtype.isnative:
                b = block.reshape(nf, npx)
                np.subtract(b, b[0], out=x)
            else:
                np.copyto(x.reshape(nf, nr, m), block, casting="unsafe")
                x -= x[0].copy()
            # float32 partial sums over groups of frames, accumulated in float64; each
            # adds the frames in order (einsum, and a reduction over the first axis)
            part = buf[nf, :npx]
            sumd = np.empty(npx) if self.resid else None
            for i, g in enumerate(self.groups):
                np.einsum("f,fp->p", self._wwork[work][g], x[g], out=part)
                _accumulate(slope, part, i)
                if self.resid:
                    _accumulate(sumd, np.add.reduce(x[g], axis=0, out=part), i)
            bad = ~np.isfinite(slope)  # pixels with an unusable read, then imprecise ones
            if saturation is not None:
                with np.errstate(invalid="ignore"):
                    bad |= np.max(x, axis=0) + np.asarray(block[0]).reshape(npx) > saturation
            if self.resid:
                ss = np.einsum("fp,fp->p", x, x, out=part).astype(np.float64)
                chi2 = np.multiply(sumd, sumd, out=sumd)
                chi2 /= nf
                np.subtract(ss, chi2, out=chi2)
                sq = np.multiply(slope, slope)
                sq *= self.stt
                chi2 -= sq
                with np.errstate(invalid="ignore"):
                    bad |= chi2 <= np.multiply(ss, kcrit, out=ss)
                if nf > 2:
                    np.multiply(chi2, self.sumw2 / (nf - 2), out=var)
                else:
                    var[:] = np.nan
            elif self.want_var:
                np.maximum(slope, 0, out=var)
                var *= self.pscale * self.pfactor
                var += read_noise**2 * self.sumw2
                if work is np.float32 and nf > 2:
                    amp = nf * (slope * (self.times[-1] - self.times[0])) ** 2
                    with np.errstate(invalid="ignore"):
                        imprecise = amp * kcrit / (nf - 2) * self.sumw2 > var
            else:
                var[:] = np.nan
        else:
            slope[:] = np.nan
            var[:] = np.nan
            bad = np.ones(npx, bool)
        if rmask is not None:
            rmask = np.asarray(rmask).reshape(nf, npx)
            bad |= np.any(rmask != 0, axis=0)
        if self.weighting == "optimal" and nf >= 2:
            fitted = self._optimal(x, slope, var, bad)
            if imprecise is not None:  # their slopes are float64 sums now
                imprecise[fitted] = False
        if imprecise is not None:
            bad |= imprecise
        bidx = np.flatnonzero(bad)
        if bidx.size:
            self._refit(block, rmask, bidx, slope, var, nreads, flags)

    def _optimal(self, x, slope, var, bad):
        """Generalised least squares for the pixels with every read usable (not ``bad``);
        returns their flat indices."""
        rate = np.maximum(np.where(bad, 0, slope), 0) * self.pscale
        # quantise the expected rate (0.02 dex): pixels in a bin share weights
        with np.errstate(divide="ignore"):
            q = np.where(rate > 1e-6 * self.read_noise**2, np.round(np.log10(rate) * 50),
                         -np.inf)
        idx = np.flatnonzero(~bad & np.isfinite(q))
        if not idx.size:
            return idx
        keys, inv = np.unique(q[idx], return_inverse=True)
        for k, key in enumerate(keys):
            weights = self._gls.get(key)
            if weights is None:
                weights = self._gls.setdefault(
                    key, gls_weights(self.times, self.read_noise, 10 ** (key / 50)))
            wk, vk = weights
            cols = idx[inv == k]
            # frames added one by one in float64 (a BLAS product's order depends on
            # the other columns)
            slope[cols] = np.einsum("f,fp->p", wk, x[:, cols].astype(np.float64))
            if self.want_var:
                var[cols] = vk
        return idx

    def _refit(self, block, rmask, bidx, slope, var, nreads, flags):
        """Least squares on the usable reads of pixels ``bidx`` (flat indices of the block)."""
        m = block.shape[2]
        rr, cc = np.divmod(bidx, m)
        y = np.asarray(block[:, rr, cc], dtype=np.float64)
        good = np.isfinite(y)
        sat = np.zeros_like(good)
        if self.saturation is not None:
            with np.errstate(invalid="ignore"):
                sat = y > self.saturation
            good &= ~sat
        pix_flags = np.zeros(bidx.size, np.uint32)
        if rmask is not None:
            rm = as_dq(rmask[:, bidx])
            good &= rm == 0
            # bits set on every read (e.g. NOT_READ rows) belong to the pixel
            pix_flags |= np.bitwise_and.reduce(rm, axis=0)
        s, v, k = fit_usable_reads(y, good, self.times,
                                   self.read_noise if self.want_var else 0.0, self.pscale)
        slope[bidx] = s
        var[bidx] = v if self.want_var else np.nan
        few = k < 2
        pix_flags[few] |= dq.FEW_READS
        pix_flags[few & sat.any(axis=0)] |= dq.SATURATED
        nreads[bidx] = k
        flags[bidx] = pix_flags
