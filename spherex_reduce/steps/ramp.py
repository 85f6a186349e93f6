"""Least-squares slopes of ramps (``fit_ramp``).

The fast path
-------------
Frames are read at ``t_f = frame_start_f + tau``, where ``tau`` is the time of
the pixel within its frame (its read's start, plus its sample within the
channel's row).  ``tau`` differs from pixel to pixel but is the same for every
frame, so it only shifts each pixel's time axis: the least-squares slope with
an intercept does not depend on it, and the slope of a pixel whose reads are
all usable is ``sum_f w_f (y_f - y_0)`` with one weight vector ``w`` (centred
times over their sum of squares) shared by every pixel.  The cube is streamed
in blocks of rows: each block is copied once into a native buffer, the first
read is subtracted (exact in float32 for values within a factor two of each
other, e.g. a 6e4 pedestal), and the weighted sums are formed by a
matrix product in groups of frames whose partial sums are accumulated in
float64.  Pixels with a NaN, saturated or flagged read (and the few whose
residuals are too small to be computed from float32 sums) are refitted on a
vectorised float64 path that uses only their usable reads.
The fused reduction of a raw file (`spherex_reduce.fused`) runs the same code
on one band of image rows of every frame at a time (`RampAccumulator.fit_bands`),
so its result is, pixel by pixel, the fit of the whole cube.
"""

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from astropy import units as u
from astropy.table import Table

from .. import dq
from ..errors import SpherexReduceError, StepSkipped
from ..exposure import ReferenceReads, as_dq

FrameAccumulator = object  # interim: the ramp module is being rewritten

__all__ = ["RampAccumulator", "fit_ramp", "ramp_weights"]

_GROUP = 32  # frames per float32 partial sum; the groups are summed in float64
_THREADS = max(1, min(4, os.cpu_count() or 1))  # threads over blocks of rows
_STREAM_GROUP = 4  # frames per buffer of the frame-by-frame accumulator (two buffers)
_ASYNC_PIXELS = 1 << 20  # from this size on, a full buffer is summed in the background
_BLOCK_PIXELS = 1 << 15  # pixels per block (74 frames x 32768 x 4 B = 9.7 MB): fewer calls
_PARALLEL_SIZE = 1 << 22  # values from which a fit runs on several threads
_BAND_PIXELS = 1 << 17  # pixels per band of _fit_bands (74 frames x 131072 x 4 B = 39 MB)
WEIGHTINGS = ("uniform", "optimal")


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
    >>> from spherex_reduce.steps.ramp import ramp_weights
    >>> w = ramp_weights([0.0, 1.0, 2.0])
    >>> w.tolist()
    [-0.5, 0.0, 0.5]
    >>> float(w @ [3.0, 5.0, 7.0])
    2.0
    """
    t = np.asarray(times, dtype=np.float64)
    tc = t - t.mean()
    return tc / (tc @ tc)


def _gls_weights(times, read_noise, rate):
    """Generalised least-squares slope weights and variance for read noise + shot noise.

    Covariance of reads ``i, j``: ``read_noise**2 delta_ij + rate * min(t_i, t_j)``
    (all in the data unit; ``rate`` is the expected accumulation per second).
    """
    t = np.asarray(times, dtype=np.float64) - times[0]
    cov = read_noise**2 * np.eye(t.size) + max(rate, 0.0) * np.minimum.outer(t, t)
    design = np.stack([np.ones_like(t), t], axis=1)
    cinv_x = np.linalg.solve(cov, design)
    fisher_inv = np.linalg.inv(design.T @ cinv_x)
    w = (cinv_x @ fisher_inv)[:, 1]
    return w, fisher_inv[1, 1]


def _poisson_factor(times, w):
    """``w^T min(t_i, t_j) w``: slope variance per unit of accumulation rate."""
    t = np.asarray(times, dtype=np.float64) - times[0]
    return float(w @ np.minimum.outer(t, t) @ w)


class _Fit:
    """Results of fitting one family of ramps (pixels, phantoms, reference reads)."""

    def __init__(self, shape, dtype, slope=None, var=None):
        self.slope = np.empty(shape, dtype) if slope is None else slope.reshape(shape)
        self.var = np.empty(shape, np.float64) if var is None else var.reshape(shape)
        self.nreads = np.empty(shape, np.int16)
        self.flags = np.zeros(shape, np.uint16)


def _fit_masked(y, good, times, read_noise, poisson_scale):
    """Vectorised float64 least squares on the usable reads of some pixels.

    ``y`` and ``good`` have shape ``(nframes, m)``; returns slope, variance
    (NaN where undefined) and the number of reads used, each ``(m,)``.  A
    pixel's numbers do not depend on the other pixels fitted with it: numpy
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


def _fit_cube(cube, times, *, mask=None, saturation=None, weighting="uniform", read_noise=None,
              gain=1.0, want_var=True, threads=None, buf=None):
    """Fit every ramp of ``cube`` (nframes, n, m) read at ``times`` (nframes,).

    ``mask`` is None, or an integer/bool array of the cube's shape (per read)
    or of ``(n, m)`` (per pixel).  ``threads`` caps the threads (default: by
    size); ``buf``, a work buffer ``(nframes, >= _BLOCK_PIXELS)`` of the work
    type, is used when one thread runs.  Returns a `_Fit` of shape ``(n, m)``.
    """
    nf, n, m = cube.shape
    work = np.float64 if cube.dtype == np.float64 else np.float32
    fit = _Fit((n, m), np.float64)  # float64 slopes: a float32 one rounds at high SNR
    times = np.asarray(times, dtype=np.float64)
    w = ramp_weights(times) if nf >= 2 else np.zeros(nf)
    tc = times - times.mean()
    stt = float(tc @ tc)
    sumw2 = float(w @ w)
    wmax = float(np.abs(w).max()) if nf else 0.0
    pscale = None if read_noise is None else 1.0 / gain
    pfactor = _poisson_factor(times, w) if nf >= 2 else 0.0
    wwork = w.astype(work)
    ones = np.ones(nf, dtype=work)
    groups = [slice(g, min(g + _GROUP, nf)) for g in range(0, nf, _GROUP)]
    native = cube.dtype == work and cube.dtype.isnative
    mask_read = mask is not None and np.ndim(mask) == 3
    mask_pix = None if mask is None or mask_read else np.asarray(mask)
    rows_per_block = max(1, _BLOCK_PIXELS // max(m, 1))
    eps = np.finfo(work).eps
    gls_cache = {}
    # refit in float64 where chi2 < kcrit * sum(d^2): (a) float32 sums of squares lose
    # the residual (relative error ~ nf eps sum(d^2) / chi2 above ~1e-3); (b) float32
    # sums of w d, in error by ~eps sqrt(group) max|w| sqrt(sum(d^2)), could exceed
    # 3e-4 of the slope's sigma, sqrt(chi2 / (nf - 2) sum(w^2))
    kcrit = 1000 * nf * eps
    if work is np.float32 and nf > 2:
        kcrit = max(kcrit, (eps * np.sqrt(_GROUP) * wmax / 3e-4) ** 2 * (nf - 2) / sumw2)
    fit.nreads[...] = nf
    fit.flags[...] = 0
    resid = want_var and read_noise is None

    def run_block(r0, buf):
        r1 = min(n, r0 + rows_per_block)
        npx = (r1 - r0) * m
        x = buf[:, :npx]
        block = cube[:, r0:r1, :]
        slope = fit.slope[r0:r1].reshape(npx)
        var = fit.var[r0:r1].reshape(npx)
        if nf >= 2:
            # one pass: reads minus the first read, into a buffer that stays in cache
            if native:
                b = block.reshape(nf, npx)
                np.subtract(b, b[0], out=x)
            else:
                np.copyto(x.reshape(nf, r1 - r0, m), block, casting="unsafe")
                x -= x[0].copy()
            # float32 partial sums over groups of frames, accumulated in float64
            # (einsum, not BLAS: a threaded gemv per block is slow on a busy machine)
            slope[:] = 0
            sumd = np.zeros(npx) if resid else None
            for g in groups:
                slope += np.einsum("f,fp->p", wwork[g], x[g])
                if resid:
                    sumd += np.einsum("f,fp->p", ones[g], x[g])
            bad = ~np.isfinite(slope)
            if saturation is not None:
                with np.errstate(invalid="ignore"):
                    bad |= np.max(x, axis=0) + np.asarray(block[0]).reshape(npx) > saturation
            if resid:
                ss = np.einsum("fp,fp->p", x, x).astype(np.float64)
                chi2 = ss - sumd * sumd / nf
                chi2 -= slope * slope * stt
                with np.errstate(invalid="ignore"):
                    bad |= chi2 <= kcrit * ss
                if nf > 2:
                    np.multiply(chi2, sumw2 / (nf - 2), out=var)
                else:
                    var[:] = np.nan
            elif want_var:
                np.maximum(slope, 0, out=var)
                var *= pscale * pfactor
                var += read_noise**2 * sumw2
                if work is np.float32 and nf > 2:
                    amp = nf * (slope * (times[-1] - times[0])) ** 2
                    with np.errstate(invalid="ignore"):
                        bad |= amp * kcrit / (nf - 2) * sumw2 > var
            else:
                var[:] = np.nan
        else:
            slope[:] = np.nan
            var[:] = np.nan
            bad = np.ones(npx, bool)
        if mask_read:
            rmask = np.asarray(mask[:, r0:r1, :]).reshape(nf, npx)
            bad |= np.any(rmask != 0, axis=0)
        if mask_pix is not None:
            pmask = as_dq(mask_pix[r0:r1]).reshape(npx)
            bad |= pmask != 0
        if weighting == "optimal" and nf >= 2:
            rate = np.maximum(np.where(bad, 0, slope), 0) * pscale
            # quantise the expected rate (0.02 dex): pixels in a bin share weights
            with np.errstate(divide="ignore"):
                q = np.where(rate > 1e-6 * read_noise**2, np.round(np.log10(rate) * 50),
                             -np.inf)
            idx = np.flatnonzero(~bad & np.isfinite(q))
            if idx.size:
                keys, inv = np.unique(q[idx], return_inverse=True)
                for k, key in enumerate(keys):
                    if key not in gls_cache:
                        gls_cache[key] = _gls_weights(times, read_noise, 10 ** (key / 50))
                    wk, vk = gls_cache[key]
                    cols = idx[inv == k]
                    slope[cols] = wk @ x[:, cols]
                    if want_var:
                        var[cols] = vk
        bidx = np.flatnonzero(bad)
        if bidx.size:
            rr, cc = np.divmod(bidx, m)
            y = np.asarray(block[:, rr, cc], dtype=np.float64)
            good = np.isfinite(y)
            sat = np.zeros_like(good)
            if saturation is not None:
                with np.errstate(invalid="ignore"):
                    sat = y > saturation
                good &= ~sat
            pix_flags = np.zeros(bidx.size, np.uint16)
            if mask_read:
                rm = as_dq(rmask[:, bidx])
                good &= rm == 0
                # bits set on every read (e.g. NOT_READ rows) belong to the pixel
                pix_flags |= np.bitwise_and.reduce(rm, axis=0)
            if mask_pix is not None:
                pm = pmask[bidx]
                good &= (pm == 0)[None, :]
                pix_flags |= pm
            s, v, k = _fit_masked(y, good, times, read_noise if want_var else 0.0, pscale)
            slope[bidx] = s
            var[bidx] = v if want_var else np.nan
            few = k < 2
            pix_flags[few] |= dq.FEW_READS
            pix_flags[few & sat.any(axis=0)] |= dq.SATURATED
            fit.nreads[r0:r1].reshape(npx)[bidx] = k
            fit.flags[r0:r1].reshape(npx)[bidx] = pix_flags

    starts = list(range(0, n, rows_per_block))
    nthreads = min(_THREADS, len(starts)) if nf * n * m >= _PARALLEL_SIZE else 1
    if threads is not None:
        nthreads = min(nthreads, threads)

    def worker(part, buf=None):
        if buf is None:
            buf = np.empty((nf, rows_per_block * m), dtype=work)
        for r0 in part:
            run_block(r0, buf)

    if nthreads <= 1:
        worker(starts, buf)
    else:  # numpy releases the GIL in these loops: blocks run on every core
        with ThreadPoolExecutor(nthreads) as pool:
            list(pool.map(worker, [starts[k::nthreads] for k in range(nthreads)]))
    return fit


def _fit_bands(shape, times, fill, order, dtype, progress=None, **kw):
    """Fit ramps of every pixel of an image ``shape`` whose frames are written, a
    band of rows at a time, by ``fill(rows, out)`` (``out``: frames x rows x columns).

    ``order`` lists every row once; consecutive rows of it form a band (whatever
    keeps ``fill``'s reads together).  Each band is fitted by `_fit_cube`, so the
    result is, pixel by pixel, the fit of the whole cube; bands run on
    ``_THREADS`` threads (numpy releases the GIL), each with its own buffers.
    ``kw`` goes to `_fit_cube`; ``progress`` (a tqdm bar) counts the bands.
    Returns the `_Fit` and the fraction of the threads' time ``fill`` took.
    """
    n, m = shape
    nf = len(times)
    fit = _Fit(shape, np.float64)
    per = max(1, _BAND_PIXELS // max(m, 1))
    bands = [order[i:i + per] for i in range(0, len(order), per)]
    nthreads = min(_THREADS, len(bands)) if nf * n * m >= _PARALLEL_SIZE else 1
    work = np.float64 if dtype == np.float64 else np.float32
    filling = []
    if progress is not None:
        progress.reset(total=len(bands))

    stop = threading.Event()  # set when a band failed: the other threads stop too

    def worker(mine):
        cube = np.empty(nf * per * m, dtype)
        buf = np.empty((nf, min(per, max(1, _BLOCK_PIXELS // max(m, 1))) * m), work)
        start = time.perf_counter()
        try:
            spent = fit_all(mine, cube, buf)
        except BaseException:
            stop.set()
            raise
        filling.append((spent, time.perf_counter() - start))

    def fit_all(mine, cube, buf):
        spent = 0.0
        for rows in mine:
            if stop.is_set():
                break
            band = cube[: nf * rows.size * m].reshape(nf, rows.size, m)
            t0 = time.perf_counter()
            fill(rows, band)
            spent += time.perf_counter() - t0
            part = _fit_cube(band, times, threads=1, buf=buf, **kw)
            fit.slope[rows], fit.var[rows] = part.slope, part.var
            fit.nreads[rows], fit.flags[rows] = part.nreads, part.flags
            if progress is not None:
                progress.update(1)
        return spent

    if nthreads <= 1:
        worker(bands)
    else:
        with ThreadPoolExecutor(nthreads, thread_name_prefix="spherex-reduce-bands") as pool:
            futures = [pool.submit(worker, bands[k::nthreads]) for k in range(nthreads)]
            try:
                for future in futures:
                    future.result()
            except BaseException:  # a band failed, or the caller was interrupted
                stop.set()
                raise
    return fit, sum(f for f, _ in filling) / max(sum(t for _, t in filling), 1e-12)


def fit_ramp(exposure, *, weighting="uniform", read_noise=None, gain=1.0, saturation=None):
    """Least-squares slope of every pixel's ramp (paper: uniform weights).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps ``(frames, rows or reads, columns)`` in readout or physical
        order, in any unit (typically electrons).
    weighting : {'uniform', 'optimal'}
        ``'uniform'``: ordinary least squares (the paper).  ``'optimal'``:
        generalised least squares for white read noise ``read_noise`` plus the
        shot noise of the pixel's signal (estimated by a first uniform fit;
        pixels with equal signal to 0.02 dex share weights).  Ramps with
        masked reads are fitted with uniform weights on their usable reads.
    read_noise : float, optional
        Read noise per read, in the data unit.  Given, the uncertainty is the
        model ``read_noise**2 sum(w**2)`` plus the slope's shot noise (data
        unit = electrons / ``gain``); not given, it comes from the fit
        residuals, ``chi2 / (n - 2) * sum(w**2)`` (NaN for two reads).
    gain : float
        Electrons per data unit, for the shot-noise term (1 for electrons).
    saturation : float, optional
        Reads above this level (data unit) are not used.

    Returns
    -------
    `~spherex_reduce.Exposure`
        A 2-D exposure: slope (float64) as `~astropy.nddata.CCDData` in
        ``unit / s`` with the fit uncertainty; DQ flags (``exposure.dq``):
        `~spherex_reduce.dq.FEW_READS` (slope NaN) for fewer than two usable
        reads, with `~spherex_reduce.dq.SATURATED` if saturation caused it,
        and the flags set on every read of a pixel; the table ``RAMPFIT``
        (one row per image row, vector column ``nreads``: the reads used).
        Phantom values and reference reads are fitted the same way, so that
        `subtract_phantom` and `correct_reference` work on the slopes.

    Raises
    ------
    StepSkipped
        The input is already a 2-D image.

    Notes
    -----
    Read times come from the schedule; within a frame each pixel's time is a
    fixed offset, which cancels from the slope, so the frame start times set
    the weights.  Reads are masked when not finite, above ``saturation``, or
    flagged in the input mask.  The input is never modified.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, fit_ramp
    >>> s = ReadoutSchedule(DetectorGeometry(8, 4, 1, ref_border=1), skip=1, ref_reads=0,
    ...                     ref_mode="none", phantom_reads=0, nframes=5, frame_time=2.0)
    >>> ramps = 6e4 + 3.0 * (2.0 * np.arange(5))[:, None, None] * np.ones((5, 8, 4), "f4")
    >>> out = fit_ramp(Exposure.from_arrays(ramps.astype("f4"), s))
    >>> float(out.data.data[0, 0]), out.unit
    (3.0, Unit("electron / s"))
    """
    _check_params(weighting, read_noise)
    if not exposure.is_ramp:
        raise StepSkipped("the input is already a 2-D image (slopes)")
    schedule = exposure.schedule
    times = schedule.frame_starts.to_value(u.s)
    kw = dict(saturation=saturation, weighting=weighting, read_noise=read_noise, gain=gain)
    flags = exposure.dq if exposure.dq is not None else exposure.data.mask
    fit = _fit_cube(exposure.data.data, times, mask=flags, **kw)
    phantom = None
    if exposure.phantom is not None:
        phantom = _fit_cube(exposure.phantom, times, want_var=False).slope
    reference = exposure.reference
    if reference is not None and np.ndim(reference.data) == 3:
        rfit = _fit_cube(reference.data, times, mask=reference.dq, saturation=saturation,
                         want_var=False)
        rphant = (None if reference.phantom is None
                  else _fit_cube(reference.phantom, times, want_var=False).slope)
        reference = ReferenceReads(data=rfit.slope, rows=reference.rows, reads=reference.reads,
                                   phantom=rphant, dq=rfit.flags)
    return _result(exposure, schedule, fit, phantom, reference, weighting)


def _check_params(weighting, read_noise):
    if weighting not in WEIGHTINGS:
        raise SpherexReduceError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    if weighting == "optimal" and (read_noise is None or not read_noise > 0):
        raise SpherexReduceError("weighting='optimal' needs read_noise > 0 (in the data unit), "
                                 f"got {read_noise!r}")


def _result(template, schedule, fit, phantom, reference, weighting):
    """The 2-D exposure of slopes, shared by `fit_ramp` and the streaming accumulator."""
    tables = dict(template.tables)
    tables["RAMPFIT"] = Table({"nreads": fit.nreads},
                              meta={"comments": ["reads used, one row per image row"]})
    header = template.header.copy()
    header["NFEWRDS"] = (int(np.count_nonzero(fit.flags & dq.FEW_READS)),
                         "pixels with fewer than 2 usable reads")
    header["RAMPWGT"] = (weighting, "ramp-fit weighting")
    unc = np.sqrt(fit.var, out=fit.var)  # the variance is not needed any more
    return template.replace(data=fit.slope, unit=(template.unit or u.one) / u.s,
                            uncertainty=unc, dq=fit.flags, phantom=phantom,
                            reference=reference, tables=tables, header=header,
                            schedule=schedule)


def _line(d, t):
    """Least-squares line ``a + g t`` through the finite values of each column of ``d``.

    ``d`` is ``(n, m)``, ``t`` ``(n,)``; computed in float64.  Where the line is
    undefined ``g = 0``, and ``a = 0`` if no value is finite.  Returns ``g, a``,
    the number of finite values of each column and the time of its first one.
    """
    db = np.asarray(d, dtype=np.float64)
    good = np.isfinite(db)
    db = np.where(good, db, 0.0)
    nb = good.sum(axis=0)
    t = np.asarray(t, dtype=np.float64)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        tm = (good * t).sum(axis=0) / nb
        tcb = np.where(good, t - tm, 0.0)
        g = (tcb * db).sum(axis=0) / (tcb * tcb).sum(axis=0)
        g = np.where(np.isfinite(g), g, 0.0)
        a = db.sum(axis=0) / nb - g * tm
    return g, np.where(np.isfinite(a), a, 0.0), nb, t[np.argmax(good, axis=0), 0]


class _StreamFit:
    """Least-squares sums of one family of ramps, fed one frame at a time.

    Frames are copied into a buffer of ``_STREAM_GROUP`` frames.  When it is full it
    is reduced block by block (blocks that stay in cache): minus a first usable
    read, detrended by a line fitted to the first group, and summed by float32
    products over the group whose results are accumulated in float64
    (``A = sum w d``, ``B = sum d``, ``C = sum d**2``).  Unusable reads (NaN,
    saturated, flagged) contribute zero and are recorded sparsely, so the exact
    least-squares fit on each pixel's usable reads follows from the sums.
    """

    _STEP = 1 << 16  # pixels per block of the buffer

    def __init__(self, shape, times, *, saturation=None, read_noise=None, gain=1.0):
        self.shape = shape
        self.npx = int(np.prod(shape))
        self.times = np.asarray(times, dtype=np.float64)
        self.tc = self.times - self.times.mean()
        self.stt = float(self.tc @ self.tc)
        self.w = self.tc / self.stt if self.stt > 0 else np.zeros_like(self.tc)
        self.saturation, self.read_noise, self.gain = saturation, read_noise, gain
        self.bufs = [None, None]  # filled in turn: one takes frames while the other is summed
        self.cur = 0  # the buffer taking frames
        self.busy = [None, None]  # the summing of each buffer (a Future), if under way
        self.pool = None  # one thread that sums full buffers (large images only)
        self.ks = []
        self.flagged = []  # per buffered frame: pixel indices flagged or saturated
        self.ref = None
        self.no_ref = None
        self.pending = None  # pixels whose line waits for a second usable read
        self.anchor = None
        self.g = None
        self.a = None
        self.A = np.zeros(self.npx)
        self.B = np.zeros(self.npx)
        self.C = np.zeros(self.npx)
        self.bad_reads = []  # (frame, pixel indices)
        self.sat_any = np.zeros(self.npx, bool)
        self.all_flags = None

    @property
    def buf(self):
        """The buffer taking frames (None before the first frame)."""
        return self.bufs[self.cur]

    def add(self, k, values, flags=None, dtype=None):
        """Frame ``k``: ``values``, an array or ``fill(out)`` writing the frame into the
        flat buffer row ``out`` (then ``dtype`` is the frame's type, and no
        saturation level can be checked), and optional per-pixel ``flags``."""
        fill = values if callable(values) else None
        if fill is None:
            y = np.asarray(values).reshape(self.npx)
            dtype = y.dtype
        elif self.saturation is not None:
            raise ValueError("frames given by a fill function cannot be checked for saturation")
        if self.buf is None:
            work = np.float64 if dtype == np.float64 else np.float32
            shape = (min(_STREAM_GROUP, self.times.size), self.npx)
            self.bufs[0] = np.empty(shape, dtype=work)
            if self.npx >= _ASYNC_PIXELS and self.times.size > shape[0]:
                self.bufs[1] = np.empty(shape, dtype=work)
                self.pool = ThreadPoolExecutor(1, thread_name_prefix="spherex-reduce-sums")
        if not self.ks:
            self._wait(self.cur)
        marked = np.zeros(0, dtype=np.intp)
        if flags is not None and (self.all_flags is None or self.all_flags.any()
                                  or np.any(flags)):
            f = as_dq(flags).reshape(self.npx)
            marked = np.flatnonzero(f)
            self.all_flags = f.copy() if self.all_flags is None else self.all_flags & f
        elif self.all_flags is None or self.all_flags.any():
            self.all_flags = np.zeros(self.npx, np.uint16)
        if self.saturation is not None:
            with np.errstate(invalid="ignore"):
                sat = y > self.saturation
            self.sat_any |= sat
            marked = np.union1d(marked, np.flatnonzero(sat))
        if fill is None:
            np.copyto(self.buf[len(self.ks)], y, casting="unsafe")
        else:
            fill(self.buf[len(self.ks)])
        self.flagged.append(marked)
        self.ks.append(k)
        if len(self.ks) == self.buf.shape[0]:
            self._submit()

    def _wait(self, i):
        """Wait until buffer ``i`` has been summed (raising what the summing raised)."""
        if self.busy[i] is not None:
            future, self.busy[i] = self.busy[i], None
            future.result()

    def _submit(self):
        """Sum the full buffer: in the background if there is a second buffer to fill."""
        if not self.ks:
            return
        ks, flagged, buf = np.asarray(self.ks), self.flagged, self.buf
        self.ks, self.flagged = [], []
        if self.pool is None:
            self._flush(ks, flagged, buf)
            return
        self.busy[self.cur] = self.pool.submit(self._flush, ks, flagged, buf)
        self.cur = 1 - self.cur

    def _drain(self):
        """Sum what is buffered and wait for every summing; release the thread."""
        self._submit()
        for i in (0, 1):
            self._wait(i)
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def close(self):
        """Stop the summing thread without finishing (after a failed run)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None

    def _flush(self, ks, flagged, buf):
        """Add the frames ``ks`` held in ``buf`` to the sums (one thread at a time)."""
        nk = ks.size
        d = buf[:nk]
        for j, idx in enumerate(flagged):  # flagged reads count as unusable (NaN)
            d[j, idx] = np.nan
        tk = self.tc[ks].astype(d.dtype)
        tk64 = self.tc[ks]
        # bright: |g t| above 1e4 (data unit) somewhere, where float32 rounds g t by
        # more than 6e-4 per read (3.5e-5 of a 10 e read noise's slope sigma): 180 e/s
        # at N = 74, above the channel drifts of raw frames and a dark's noisy line
        bright_g = 1e4 / max(np.abs(self.tc).max(), 1e-30)
        first = self.ref is None
        if first:
            self.ref = np.empty(self.npx, d.dtype)
            self.g = np.zeros(self.npx, d.dtype)
            self.a = np.zeros(self.npx, d.dtype)
            self.base = np.empty(self.npx, d.dtype)  # ref + a: one subtraction per read
        tg = tk - tk.mean()
        sg = float(tg @ tg)
        wk = self.w[ks].astype(d.dtype)
        ones = np.ones(nk, d.dtype)
        step = self._STEP
        pending = self.pending is not None and self.pending.any()

        def one(p0):
            p1 = min(self.npx, p0 + step)
            sub = d[:, p0:p1]
            ref = self.ref[p0:p1]
            new_pending = []  # pixels with one usable read so far: no line yet
            if first:
                ref[:] = sub[0]
            missing = np.flatnonzero(np.isnan(ref)) if first or self.no_ref.size else ()
            if not first and not len(missing):
                sub -= self.base[p0:p1]  # every pixel of the block has its line
            if len(missing):  # first usable read of pixels that had none yet
                col = sub[:, missing]
                has = np.isfinite(col)
                j = np.argmax(has, axis=0)
                ref[missing] = np.where(has.any(axis=0), col[j, np.arange(missing.size)],
                                        np.nan)
                if not first:  # and their own line through this group (else float32
                    # sums of their undetrended squares lose the residuals)
                    g, a, n, t1 = _line(col - ref[missing], tk)
                    self.g[p0 + missing], self.a[p0 + missing] = g, a
                    lone = (n == 1).nonzero()[0]
                    new_pending.append((p0 + missing[lone], t1[lone]))
            if first or len(missing):
                sub -= ref
            if first:  # a line through the first group keeps the later squares small
                gl, al = self.g[p0:p1], self.a[p0:p1]
                if nk >= 2:
                    gl[:] = np.einsum("f,fp->p", tg / sg, sub)
                    al[:] = np.einsum("f,fp->p", ones / nk, sub) - gl * tk.mean()
                else:
                    al[:] = sub[0]
                odd = np.flatnonzero(~np.isfinite(gl) | ~np.isfinite(al))
                if odd.size:  # least squares on their usable reads, in float64
                    gl[odd], al[odd], n, t1 = _line(sub[:, odd], tk)
                    lone = (n == 1).nonzero()[0]
                    new_pending.append((p0 + odd[lone], t1[lone]))
            if first or len(missing):
                base = self.base[p0:p1]
                np.add(ref, self.a[p0:p1], out=base)
                # minus (base - ref), exact near ref: the shift of every later group too
                sub -= base - ref
            if pending and not first:
                self._anchored_lines(sub, tk, p0, p1)
            for idx, t1 in new_pending:
                if idx.size:
                    self._pend(idx, t1)
            gb = self.g[p0:p1]
            sub -= np.multiply.outer(tk, gb)
            if sub.dtype == np.float32:
                # bright ramps: g t reaches ~1e5 and its float32 rounding ~1e-3 of the
                # slope's sigma; redo their line in float64, rounded once
                bright = np.flatnonzero(np.abs(gb) > bright_g)
                if bright.size:
                    line32 = np.multiply.outer(tk, gb[bright]).astype(np.float64)
                    line64 = np.multiply.outer(tk64, gb[bright].astype(np.float64))
                    sub[:, bright] = sub[:, bright] + (line32 - line64)
            a = np.einsum("f,fp->p", wk, sub)  # einsum, not BLAS: no spinning BLAS threads
            b = np.einsum("f,fp->p", ones, sub)
            c = np.einsum("fp,fp->p", sub, sub)
            fix = np.flatnonzero(~np.isfinite(c))  # pixels with an unusable read here
            if fix.size:
                self._fix(sub, fix, p0, ks, a, b, c)
            self.A[p0:p1] += a
            self.B[p0:p1] += b
            self.C[p0:p1] += c

        starts = list(range(0, self.npx, step))
        # summed beside the caller's thread already: one thread here
        nthreads = 1 if self.pool is not None else min(_THREADS, len(starts))
        if nthreads <= 1:
            for p0 in starts:
                one(p0)
        else:  # blocks are independent; numpy releases the GIL in these loops
            with ThreadPoolExecutor(nthreads) as pool:
                list(pool.map(one, starts))
        if first or self.no_ref.size:
            self.no_ref = np.flatnonzero(np.isnan(self.ref))

    def _pend(self, idx, t1):
        """Pixels ``idx`` have one usable read, at centred time ``t1``: no line yet.

        Their read was summed as 0 (``y - ref`` with ``ref = y``); the line is fitted
        to the next group through that point (`_anchored_lines`), which keeps it 0.
        """
        if self.pending is None:
            self.pending = np.zeros(self.npx, bool)
            self.anchor = np.zeros(self.npx)
        self.pending[idx] = True
        self.anchor[idx] = t1

    def _anchored_lines(self, sub, tk, p0, p1):
        """Lines through the anchor read of the pending pixels of block ``p0:p1``.

        ``sub`` holds ``y - ref`` for them; it becomes ``y - base`` (before the
        common ``- g t``), with ``a = -g t1`` so that the anchor stays at 0.
        """
        pend = np.flatnonzero(self.pending[p0:p1])
        if not pend.size:
            return
        vals = sub[:, pend].astype(np.float64)
        good = np.isfinite(vals)
        dt = tk.astype(np.float64)[:, None] - self.anchor[p0 + pend]
        num = np.where(good, dt * vals, 0.0).sum(axis=0)
        den = np.where(good, dt * dt, 0.0).sum(axis=0)
        ok = den > 0
        sel = pend[ok]
        if not sel.size:
            return
        g = num[ok] / den[ok]
        idx = p0 + sel
        self.g[idx] = g
        self.a[idx] = -g * self.anchor[idx]
        self.base[idx] = self.ref[idx] + self.a[idx]
        sub[:, sel] -= self.base[idx] - self.ref[idx]
        self.pending[idx] = False

    def _fix(self, sub, fix, p0, ks, a, b, c):
        """Zero the unusable reads of pixels ``fix`` (block columns) and redo their sums."""
        cols = sub[:, fix]
        bad = ~np.isfinite(cols)
        rows, where = np.nonzero(bad)
        for j in np.unique(rows):
            self.bad_reads.append((int(ks[j]), fix[where[rows == j]] + p0))
        cols[bad] = 0
        sub[:, fix] = cols
        wk = self.w[ks].astype(sub.dtype)
        a[fix] = np.einsum("f,fp->p", wk, cols)
        b[fix] = cols.sum(axis=0)
        c[fix] = np.einsum("fp,fp->p", cols, cols)

    def finish(self, want_var=True):
        """The fit of every pixel (once: the sums' memory becomes the result's)."""
        if self.A is None:
            raise RuntimeError("finish() was called already: the sums became its result")
        self._drain()
        nf, npx = self.times.size, self.npx
        bad = None
        if nf >= 2 and self.bad_reads:  # their sums, before they are overwritten
            badpix = np.unique(np.concatenate([idx for _, idx in self.bad_reads]))
            bad = badpix, self.A[badpix], self.B[badpix], self.C[badpix]
        # slopes in place of A, variances in place of C: no fresh 2 x 32 MB (page faults)
        fit = _Fit(self.shape, np.float64, slope=self.A, var=self.C)
        slope = fit.slope.reshape(npx)
        var = fit.var.reshape(npx)
        # every read usable (most pixels): n, sums of t and t^2 are the full ones;
        # in blocks, so that temporaries stay small
        pf = _poisson_factor(self.times, self.w) if nf >= 2 else 0.0
        step = self._STEP
        tmp = np.empty(min(step, npx))
        for p0 in range(0, npx, step):
            p1 = min(npx, p0 + step)
            sl, v = slope[p0:p1], var[p0:p1]  # A and C of the block
            with np.errstate(invalid="ignore", divide="ignore"):
                if want_var and self.read_noise is None and nf > 2:
                    # chi2 = C - B^2/n - A^2 stt, in place
                    B, t = self.B[p0:p1], tmp[: p1 - p0]
                    np.multiply(B, B, out=t)
                    t *= -1.0 / nf
                    v += t
                    np.multiply(sl, sl, out=t)
                    t *= self.stt
                    v -= t
                    np.maximum(v, 0, out=v)
                    v *= 1 / ((nf - 2) * self.stt)
                if self.g is not None:
                    sl += self.g[p0:p1]
                if want_var and self.read_noise is not None and nf >= 2:
                    np.maximum(sl, 0, out=v)
                    v *= pf / self.gain
                    v += self.read_noise**2 / self.stt
                elif not (want_var and self.read_noise is None and nf > 2):
                    v[:] = np.nan
        self.A = self.C = None  # now the result's
        nreads = fit.nreads.reshape(npx)
        nreads[:] = nf
        flags = fit.flags.reshape(npx)
        if self.all_flags is not None:
            flags[:] = self.all_flags
        if nf < 2:
            slope[:] = np.nan
            var[:] = np.nan
            flags |= dq.FEW_READS
            flags[self.sat_any] |= dq.SATURATED
            nreads[:] = nf - np.isin(np.arange(npx), np.concatenate(
                [idx for _, idx in self.bad_reads] or [np.zeros(0, int)]))
            return fit
        if bad is None:
            return fit
        # pixels with unusable reads: least squares on their usable reads, from the sums
        badpix, a, b, c = bad
        col = np.searchsorted(badpix, np.arange(npx))  # only used at badpix
        good = np.ones((nf, badpix.size), bool)
        for k, idx in self.bad_reads:
            good[k, col[idx]] = False
        n = good.sum(axis=0).astype(np.float64)
        tcol = self.tc[:, None]
        st = (good * tcol).sum(axis=0)
        stt = (good * tcol**2).sum(axis=0)
        gb = 0.0 if self.g is None else self.g[badpix].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            sc = stt - st * st / n  # centred sum of squares of the usable times
            slope_d = (self.stt * a - st * b / n) / sc
            s_b = slope_d + gb
            if want_var and self.read_noise is None:
                chi2 = c - b * b / n - slope_d**2 * sc
                v = np.maximum(chi2, 0) / (n - 2) / sc
                v[n <= 2] = np.nan
            elif want_var:
                tcs = tcol - st / n
                wsub = np.where(good, tcs, 0) / sc
                mt = np.minimum.outer(self.times, self.times) - self.times[0]
                pf = np.einsum("im,ij,jm->m", wsub, mt, wsub)
                v = self.read_noise**2 / sc + np.maximum(s_b, 0) / self.gain * pf
            else:
                v = np.full(badpix.size, np.nan)
        few = n < 2
        s_b[few] = np.nan
        v[few] = np.nan
        slope[badpix] = s_b
        var[badpix] = v
        nreads[badpix] = n.astype(np.int16)
        fb = flags[badpix]
        fb[few] |= dq.FEW_READS
        fb[few & self.sat_any[badpix]] |= dq.SATURATED
        flags[badpix] = fb
        return fit


class RampAccumulator(FrameAccumulator):
    """`fit_ramp` frame by frame: memory near a group of frames plus the output.

    Gives the same result as `fit_ramp` on the whole ramp (to float32
    rounding).  With ``weighting='optimal'`` the weights depend on the whole
    ramp, so the frames are kept and fitted at the end.
    """

    def __init__(self, schedule, header, weighting="uniform", read_noise=None, gain=1.0,
                 saturation=None):
        _check_params(weighting, read_noise)
        self.schedule = schedule
        self.times = schedule.frame_starts.to_value(u.s)
        self.params = dict(weighting=weighting, read_noise=read_noise, gain=gain,
                           saturation=saturation)
        self.kw = dict(saturation=saturation, read_noise=read_noise, gain=gain)
        self.frames = [] if weighting == "optimal" else None
        self.fits = None
        self.last = None
        self.banded = None  # (fit, reference fit) of fit_bands

    def add(self, index, frame):
        self.last = frame
        if self.frames is not None:
            self.frames.append(frame)
            return
        if self.fits is None:
            self.fits = {"data": _StreamFit(frame.shape[-2:], self.times, **self.kw)}
            if frame.phantom is not None:
                self.fits["phantom"] = _StreamFit(frame.phantom.shape[-2:], self.times)
            ref = frame.reference
            if ref is not None and np.ndim(ref.data) == 3:
                self.fits["ref"] = _StreamFit(ref.data.shape[-2:], self.times,
                                              saturation=self.kw["saturation"])
                if ref.phantom is not None:
                    self.fits["refph"] = _StreamFit(ref.phantom.shape[-2:], self.times)
        fl = frame.dq if frame.dq is not None else frame.data.mask
        self.fits["data"].add(index, frame.data.data[0], None if fl is None else fl[0])
        if "phantom" in self.fits:
            self.fits["phantom"].add(index, frame.phantom[0])
        if "ref" in self.fits:
            rdq = frame.reference.dq
            self.fits["ref"].add(index, frame.reference.data[0], None if rdq is None else rdq[0])
        if "refph" in self.fits:
            self.fits["refph"].add(index, frame.reference.phantom[0])

    def add_fused(self, index, frame):
        """Frame ``index`` prepared by the fused path (`spherex_reduce.fused.FusedFrame`).

        Its pixels are written straight into the fit's buffer.  The first frame
        must have gone through `add` (it sets the families fitted and the
        template of the result), with uniform weights and no phantom values left.
        """
        if self.fits is None or self.frames is not None or "phantom" in self.fits:
            raise RuntimeError("add_fused needs uniform weights and a first frame, "
                               "phantom-corrected, given to add()")
        self.fits["data"].add(index, frame.fill, frame.flags, dtype=frame.dtype)
        if "ref" in self.fits:
            self.fits["ref"].add(index, frame.reference)

    def fit_bands(self, first, fill, order, reference=None, progress=None):
        """Every frame at once, a band of rows at a time (`spherex_reduce.fused`).

        For a file read by the fused path: memory stays near one band of every
        frame plus the output, and each band is fitted as `fit_ramp` fits a
        whole cube, so the result is the one of `fit_ramp` on the whole ramp.

        Parameters
        ----------
        first : `~spherex_reduce.Exposure`
            Frame 0 after the per-frame steps: the template of the result (its
            header and reference reads' rows); not given to `add`.
        fill : callable
            ``fill(rows, out)`` writes the pixels of image ``rows`` of every
            frame into ``out`` ``(frames, len(rows), columns)``, of the type of
            ``first``'s pixels.
        order : `numpy.ndarray`
            Every image row once; bands are consecutive rows of it.
        reference : `numpy.ndarray`, optional
            The reference reads of every frame ``(frames, reads, columns)``.
        progress : tqdm bar, optional
            Advanced by one per band.

        Returns
        -------
        float
            The fraction of the time spent in ``fill``.
        """
        p = self.params
        if (self.fits is not None or self.frames is not None or p["saturation"] is not None
                or p["weighting"] != "uniform" or first.phantom is not None
                or first.dq is not None):
            raise RuntimeError("fit_bands needs uniform weights, no saturation level, no flags "
                               "or phantom values, and no frame given to add()")
        self.last = first
        kw = dict(read_noise=p["read_noise"], gain=p["gain"])
        fit, filling = _fit_bands(first.shape[-2:], self.times, fill, order,
                                first.data.data.dtype, progress, **kw)
        rfit = None
        if reference is not None:
            rfit = _fit_cube(reference, self.times, want_var=False)
        self.banded = fit, rfit
        return filling

    def close(self):
        for fit in (self.fits or {}).values():
            fit.close()

    def finish(self):
        if self.frames is not None:
            return fit_ramp(_stack(self.frames, self.schedule), **self.params)
        if self.banded is not None:
            fit, rfit = self.banded
            self.banded = None
            reference = self.last.reference
            if rfit is not None:
                reference = ReferenceReads(data=rfit.slope, rows=reference.rows,
                                           reads=reference.reads, dq=rfit.flags)
            return _result(self.last, self.schedule, fit, None, reference, "uniform")
        f = self.fits
        fit = f["data"].finish()
        phantom = f["phantom"].finish(False).slope if "phantom" in f else None
        reference = self.last.reference
        if "ref" in f:
            rfit = f["ref"].finish(False)
            reference = ReferenceReads(
                data=rfit.slope, rows=reference.rows, reads=reference.reads,
                phantom=f["refph"].finish(False).slope if "refph" in f else None,
                dq=rfit.flags)
        return _result(self.last, self.schedule, fit, phantom, reference,
                       self.params["weighting"])


def _stack(frames, schedule):
    """One-frame exposures stacked back into the whole ramp."""
    first = frames[0]

    def cat(get):
        parts = [get(f) for f in frames]
        return None if parts[0] is None else np.concatenate(parts)

    unc = cat(lambda f: None if f.data.uncertainty is None else f.data.uncertainty.array)
    ref = first.reference
    if ref is not None:
        ref = ref.replace(data=cat(lambda f: f.reference.data),
                          phantom=cat(lambda f: f.reference.phantom),
                          dq=cat(lambda f: f.reference.dq))
    return first.replace(data=cat(lambda f: f.data.data), uncertainty=unc,
                         dq=cat(lambda f: f.dq), phantom=cat(lambda f: f.phantom),
                         reference=ref, schedule=schedule)
