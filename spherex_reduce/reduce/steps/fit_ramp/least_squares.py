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
sums are accumulated in float64.  Where only the slope is wanted (a read-noise
model gives the variance; no saturation level, no ``jump_prior``) and the read
times are symmetric about their mean (equal spacing, equal groups), ``w`` is
antisymmetric and the slope is ``sum_(f < n/2) w_(n-1-f) (y_(n-1-f) - y_f)``:
half as many differences, each as exact as a read less the first, and half the
float32 sums (the fit of 74 reads took 0.65 of the time).  Bright ramps whose
float32 sums are too coarse for the slope (with a read-noise model) are summed
again in float64 with the same weights, from their reads minus the first in
float64.  Pixels with a
NaN, saturated or flagged read (a masked read, a jump), and the few whose
residuals are too small to be computed from float32 sums, are refitted in
float64 on their usable reads, segment by segment
(`~spherex_reduce.reduce.steps.fit_ramp.segments.fit_segments`), all those of a
call to `LeastSquares.fit` together.

Read noise, gain and dark current may differ from pixel to pixel: `RampMaps`
holds a band's values, numbers or arrays of the band's shape.

Every pixel's numbers depend on its own reads only, never on the other pixels
of the block or on where the block starts: numpy's ``einsum``, and its
reduction over the first axis of a C-ordered array, add the frames of each
column one after another (a product, then a sum, each rounded), and the
float64 paths fit each column alone (a weighted sum over the reads of a float64
copy in Fortran order is each column's own dot product).  So a ramp cut into
bands of rows and fitted band by band, on any number of threads, gives the fit
of the whole cube bit for bit.
"""

from dataclasses import dataclass

import numpy as np

from ....core import dq
from ....core.errors import SpherexReduceError
from ....core.exposure import as_dq
from .segments import RATIO_BINS, RampNoise, fit_segments
from .step_model import StepModel
from .step_posterior import WEIGH_ALL_READS, WEIGH_FROM, step_posterior

__all__ = ["GROUP", "LeastSquares", "RampMaps", "RampSolution", "ramp_weights"]

GROUP = 32  #: frames per float32 partial sum; the groups are summed in float64
#: bytes of a block of the work buffer, one row per frame and one for sums: 2**15 pixels of 74
#: float32 frames (the symmetric reads' differences use half; 2**14 pixels was 4-6 %
#: slower, 2**16-2**17 no faster); longer ramps or float64 take fewer pixels
BLOCK_BYTES = 75 * 4 << 15
#: pixels fitted segment by segment at once (74 frames: 4.8 MB for each float64 copy)
REFIT_PIXELS = 1 << 13


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
    >>> from spherex_reduce.reduce.steps.fit_ramp.least_squares import ramp_weights
    >>> w = ramp_weights([0.0, 1.0, 2.0])
    >>> w.tolist()
    [-0.5, 0.0, 0.5]
    >>> float(w @ [3.0, 5.0, 7.0])
    2.0
    """
    t = np.asarray(times, dtype=np.float64)
    tc = t - t.mean()
    return tc / (tc @ tc)


@dataclass(frozen=True)
class RampMaps:
    """Calibration of a band's pixels: each a number or an array ``(rows, columns)``.

    Attributes
    ----------
    read_noise : float or `numpy.ndarray` or None
        Read noise per read (data unit); None: variance from the residuals.
    pscale : float or `numpy.ndarray`
        1 / gain (data unit per electron) for the shot noise; None given: no shot noise
        (kept as 0).
    dark : float or `numpy.ndarray`
        Dark current already subtracted from the reads (data unit / s).
    """

    read_noise: object = None
    pscale: object = None
    dark: object = 0.0

    def __post_init__(self):
        if self.pscale is None:  # every use is arithmetic: no shot noise is a zero factor
            object.__setattr__(self, "pscale", 0.0)

    def rows(self, rows):
        """The maps of rows ``rows`` (a slice) of the band, flattened to pixels."""
        return self._cut(lambda v: np.ravel(v[rows]))

    def pixels(self, index):
        """The maps of the (flattened) pixels ``index``."""
        return self._cut(lambda v: v[index])

    def _cut(self, cut):
        """``cut`` applied to the arrays (numbers stay as they are)."""
        return RampMaps(*(cut(v) if isinstance(v, np.ndarray) else v
                          for v in (self.read_noise, self.pscale, self.dark)))


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
    njumps, nsegments : `numpy.ndarray` of int8
        Jumps that split usable reads (a JUMP flag on a usable read after another), and
        segments fitted.
    var_rnoise, var_per_rate : `numpy.ndarray` of float32, or None
        With ``parts`` (a read-noise model): the slope's variance at zero rate
        (read noise and the dark current's shot noise) and its shot-noise
        variance per unit of rate (data unit / s); ``var`` is ``var_rnoise +
        rate * var_per_rate`` for the pixel's rate.  None without ``parts``.
    flags : `numpy.ndarray` of uint32
        `~spherex_reduce.core.dq.FEW_READS`, `~spherex_reduce.core.dq.SATURATED`,
        `~spherex_reduce.core.dq.JUMP` and the flags set on every read of the pixel.
    """

    ARRAYS = ("slope", "var", "nreads", "njumps", "nsegments", "flags", "var_rnoise",
              "var_per_rate")

    def __init__(self, shape, parts=False):
        self.slope = np.empty(shape, np.float64)
        self.var = np.empty(shape, np.float64)
        self.nreads = np.empty(shape, np.int16)
        # zero pages until a pixel with a jump or a masked read is written
        self.njumps = np.zeros(shape, np.int8)
        self.nsegments = np.empty(shape, np.int8)
        self.flags = np.empty(shape, np.uint32)
        self.var_rnoise = np.full(shape, np.nan, np.float32) if parts else None
        self.var_per_rate = np.full(shape, np.nan, np.float32) if parts else None

    @property
    def arrays(self):
        """Names of the arrays this solution holds."""
        return [name for name in self.ARRAYS if getattr(self, name) is not None]

    def rows(self, rows):
        """A solution viewing rows ``rows`` (a slice) of this one."""
        view = RampSolution.__new__(RampSolution)
        for name in self.ARRAYS:
            a = getattr(self, name)
            setattr(view, name, None if a is None else a[rows])
        return view

    def put(self, rows, part):
        """Write ``part`` (a `RampSolution`) at rows ``rows`` (indices or a slice)."""
        for name in self.arrays:
            getattr(self, name)[rows] = getattr(part, name)


def _relative_reads(block, idx):
    """The reads of the pixels ``idx`` (flat indices of ``block``, ``(frames, rows,
    columns)``) minus their first read, in float64: exact, where a float32 difference is not
    once a read is more than twice the first (a bright ramp on a pedestal)."""
    rr, cc = np.divmod(idx, block.shape[2])
    # Fortran order: a weighted sum over the reads is then each pixel's own dot product, the
    # same whichever pixels come with it
    y = np.asarray(block[:, rr, cc], dtype=np.float64, order="F")
    return y - y[0]


def _group_sums(w):
    """The groups of at most `GROUP` rows that float32 partial sums with weights ``w`` are
    formed over (slices), and ``w`` in each work type."""
    return ([slice(g, min(g + GROUP, w.size)) for g in range(0, w.size, GROUP)],
            {work: w.astype(work) for work in (np.float32, np.float64)})


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
        Frame (or group mean) times (s), ``(nframes,)``.
    weighting : {'uniform', 'optimal'}
        ``'optimal'`` needs a read noise (the `RampMaps` given to `fit`).
    saturation : float, optional
        Reads above this level end the usable ramp.
    want_var : bool
        False: no variances (NaN), e.g. for phantom values.
    noise : `~spherex_reduce.reduce.steps.fit_ramp.segments.RampNoise`, optional
        Read-noise factors and shot-noise covariance of the reads (groups of
        averaged frames); those of single reads at ``times`` if None.
    jump_prior : float, optional
        Probability that a ramp holds a jump: the slopes and variances of the ramps
        fitted whole (uniform weights, a read-noise model) weigh the steps they may
        hold (`~spherex_reduce.reduce.steps.fit_ramp.step_posterior`); None: not.
    """

    def __init__(self, times, *, weighting="uniform", saturation=None, want_var=True,
                 noise=None, jump_prior=None):
        self.times = t = np.asarray(times, dtype=np.float64)
        self.nf = nf = t.size
        self.noise = RampNoise(t) if noise is None else noise
        self.weighting, self.saturation = weighting, saturation
        self.want_var = want_var
        self.maps = RampMaps()  # no calibration unless `fit` is given the band's
        self.w = ramp_weights(t) if nf >= 2 else np.zeros(nf)
        tc = t - t.mean()
        self.stt = float(tc @ tc)
        self.sumw2 = float(self.w @ self.w)
        self.sumw2f = float(self.w @ (self.w * self.noise.read_factors))  # read-noise factor
        self.wmax = float(np.abs(self.w).max()) if nf else 0.0
        self.pfactor = float(self.w @ self.noise.shot @ self.w) if nf >= 2 else 0.0
        self._sums = _group_sums(self.w)  # (groups of rows, weights by work type)
        # read times symmetric about their mean (equal spacing, equal groups): w_f = -w_(n-1-f),
        # and the slope is sum_(f < n/2) w_(n-1-f) (y_(n-1-f) - y_f), half as many
        # differences as the reads less the first (`_block`, where only the slope is wanted)
        self.pairs = None
        if nf >= 2 and np.all(np.abs(tc + tc[::-1]) <= 1e-9 * np.abs(tc).max()):
            half = nf // 2
            wpair = (self.w[::-1][:half] - self.w[:half]) / 2
            self.pairs = (half, *_group_sums(wpair))
        self.jump_prior = jump_prior
        weigh = jump_prior is not None and weighting == "uniform" and want_var and nf >= 3
        factors = self.noise.read_factors
        if weigh and np.ptp(factors) > 0:  # (the posterior is exact for equal weights only)
            raise SpherexReduceError(
                "fit_ramp.jump_prior needs reads of equal weight (single reads or equal "
                f"groups); these groups average {1 / factors.max():g} to "
                f"{1 / factors.min():g} frames: leave jump_prior out")
        self.steps = StepModel(t, factors, self.noise.shot) if weigh else None

    def work_type(self, dtype):
        """The type sums are formed in for pixels of ``dtype``: float64 or float32."""
        # by type, not byte order: big-endian float64 (as FITS stores it) is float64 too
        return np.float64 if np.dtype(dtype).newbyteorder("=") == np.float64 else np.float32

    def rows_per_block(self, ncols, dtype=np.float32):
        """Rows of a block of the work buffer for ``ncols`` columns of pixels of ``dtype``
        (about `BLOCK_BYTES`, at least one row)."""
        size = (self.nf + 1) * np.dtype(self.work_type(dtype)).itemsize * max(ncols, 1)
        return max(1, BLOCK_BYTES // size)

    def buffer(self, ncols, dtype):
        """A work buffer for blocks of ``ncols`` columns of pixels of ``dtype``.

        One row per frame (the reads minus the first read) and one for partial sums.
        """
        return np.empty((self.nf + 1, self.rows_per_block(ncols, dtype) * ncols),
                        self.work_type(dtype))

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

    def fit(self, cube, mask=None, out=None, buf=None, maps=None):
        """Fit every ramp of ``cube``.

        Parameters
        ----------
        cube : `numpy.ndarray`
            Reads ``(nframes, n, m)`` (any real type; never written).
        mask : array_like, optional
            Flags of every read, shape of ``cube`` (`~spherex_reduce.core.dq`
            bits: ``JUMP`` starts a segment, ``SATURATED`` ends the ramp, the
            others mask the read).
        out : `RampSolution`, optional
            Where to write (C-ordered ``(n, m)`` arrays); a new one if None.
        buf : `numpy.ndarray`, optional
            A work buffer from `buffer` (one per thread).
        maps : `RampMaps`, optional
            Read noise, 1 / gain and dark current of these pixels (numbers or
            ``(n, m)`` arrays); those given to the constructor if None.

        Returns
        -------
        `RampSolution`
        """
        nf, n, m = cube.shape
        maps = self.maps if maps is None else maps
        if out is None:
            out = RampSolution((n, m), parts=maps.read_noise is not None)
        elif not all(getattr(out, k).flags.c_contiguous for k in out.arrays):
            raise ValueError("out must hold C-ordered arrays (they are written through views)")
        if (buf is None or buf.dtype != self.work_type(cube.dtype) or buf.shape[0] != nf + 1
                or buf.shape[1] < m):
            rows = min(self.rows_per_block(m, cube.dtype), max(n, 1))
            buf = np.empty((nf + 1, rows * m), self.work_type(cube.dtype))
        per = max(1, min(buf.shape[1] // max(m, 1), n))
        # every ramp whole until a block finds otherwise (one call each for the band)
        out.nreads[:] = nf
        out.nsegments[:] = 1 if nf >= 2 else 0
        out.flags[:] = 0
        mask = None if mask is None else np.asarray(mask)
        refit = []  # flat indices of the pixels fitted segment by segment, block by block
        for r0 in range(0, n, per):
            r1 = min(n, r0 + per)
            rows = slice(r0, r1)
            refit.append(r0 * m + self._block(cube[:, rows], None if mask is None
                                              else mask[:, rows], out.rows(rows), buf,
                                              maps.rows(rows)))
        # together: a few calls for the whole band (a pixel's fit does not depend on the
        # others), in parts that bound their float64 copies
        refit = np.concatenate(refit) if refit else np.zeros(0, np.int64)
        if refit.size:
            flat = maps.rows(slice(None))
            for i in range(0, refit.size, REFIT_PIXELS):
                self._refit(cube, mask, refit[i:i + REFIT_PIXELS], out, flat)
        return out

    def _block(self, block, rmask, fit, buf, maps):
        """Fit ``block`` (nframes, rows, m) into ``fit`` (views of the output rows); ``maps``
        are the block's pixels' calibration, flattened.  Returns the flat indices of the
        pixels to fit segment by segment (`_refit`)."""
        nf, nr, m = block.shape
        npx = nr * m
        work = buf.dtype.type
        x = buf[:nf, :npx]
        slope = fit.slope.reshape(npx)
        var = fit.var.reshape(npx)
        saturation = self.saturation
        resid = self.want_var and maps.read_noise is None
        kcrit = self._kcrit(work)
        imprecise = None  # pixels whose float32 sums are too coarse for a uniform slope
        if nf >= 2:
            pairs = (self.pairs is not None and not resid and saturation is None
                     and self.steps is None)
            if pairs:
                # the slope alone is wanted (no residuals, saturation or steps): from the
                # differences of symmetric reads, half as many as the reads less the first
                half, groups, weights = self.pairs
                b = block.reshape(nf, npx)
                np.subtract(b[:nf - 1 - half:-1], b[:half], out=x[:half], dtype=work)
            else:
                # one pass: reads minus the first read, into a buffer that stays in cache
                groups, weights = self._sums
                if block.dtype == work and block.dtype.isnative:
                    b = block.reshape(nf, npx)
                    np.subtract(b, b[0], out=x)
                else:
                    np.copyto(x.reshape(nf, nr, m), block, casting="unsafe")
                    x -= x[0].copy()
            # float32 partial sums over groups of frames, accumulated in float64; each
            # adds the frames in order (einsum, and a reduction over the first axis)
            part = buf[nf, :npx]
            sumd = np.empty(npx) if resid else None
            for i, g in enumerate(groups):
                np.einsum("f,fp->p", weights[work][g], x[g], out=part)
                _accumulate(slope, part, i)
                if resid:
                    _accumulate(sumd, np.add.reduce(x[g], axis=0, out=part), i)
            bad = ~np.isfinite(slope)  # pixels with an unusable read, then imprecise ones
            if pairs and nf % 2:  # the middle read weighs nothing; usable, the ramp is whole
                bad |= ~np.isfinite(b[half])
            if saturation is not None:
                with np.errstate(invalid="ignore"):
                    bad |= np.max(x, axis=0) + np.asarray(block[0]).reshape(npx) > saturation
            if resid:
                ss = np.einsum("fp,fp->p", x, x, out=part).astype(np.float64)
                chi2 = np.multiply(sumd, sumd, out=sumd)
                chi2 /= nf
                np.subtract(ss, chi2, out=chi2)
                sq = np.multiply(slope, slope)
                sq *= self.stt
                chi2 -= sq
                if nf > 2:
                    with np.errstate(invalid="ignore"):
                        bad |= chi2 <= np.multiply(ss, kcrit, out=ss)
                    np.multiply(chi2, self.sumw2 / (nf - 2), out=var)
                else:  # two reads: a line through both, no residual to lose (nor variance);
                    var[:] = np.nan  # the test would send every pixel to the refit
            elif self.want_var:
                self._model_variance(slope, var, maps, fit)
                if work is np.float32 and nf > 2:
                    # the sum of squares nf (slope span)**2 times kcrit / (nf - 2) sum(w**2)
                    # above the variance
                    amp = np.square(slope)
                    amp *= (nf * (self.times[-1] - self.times[0]) ** 2 * kcrit / (nf - 2)
                            * self.sumw2)
                    with np.errstate(invalid="ignore"):
                        imprecise = amp > var
            else:
                var[:] = np.nan
        else:
            slope[:] = np.nan
            var[:] = np.nan
            bad = np.ones(npx, bool)
        one_jump = None  # ramps whose only flag is one JUMP (weighed with jump_prior)
        if rmask is not None:
            flagged = np.bitwise_or.reduce(rmask.reshape(nf, npx), axis=0)
            # (on 3 reads a step after the first read and one after the second fit alike:
            # weighing a flagged ramp over both would put half its jump in the slope, so it
            # keeps the search's read and is fitted around it)
            if self.steps is not None and maps.read_noise is not None and nf > 3:
                one_jump = np.flatnonzero((flagged == dq.JUMP) & ~bad)
                if one_jump.size:
                    count = np.count_nonzero(rmask.reshape(nf, npx)[:, one_jump] & dq.JUMP,
                                             axis=0)
                    one_jump = one_jump[count == 1]
            bad |= flagged != 0
        if self.weighting == "optimal" and nf >= 2:
            fitted = self._optimal(block, slope, var, bad, maps, fit)
            if imprecise is not None:  # their slopes are float64 sums now
                imprecise[fitted] = False
        if imprecise is not None:
            if self.weighting == "uniform":  # every read usable: the same sums in float64
                self._precise(block, np.flatnonzero(imprecise & ~bad), slope, var, maps)
            else:  # not fitted by `_optimal` (rate <= 0): generalised least squares there
                bad |= imprecise
        if self.steps is not None and maps.read_noise is not None:
            self._weigh_steps(block, x, slope, var, bad, maps, fit, rmask, one_jump)
        return np.flatnonzero(bad)

    def _model_variance(self, slope, var, maps, fit=None):
        """``var`` = read noise + shot noise of ``max(slope, 0)`` and of the dark current (uniform
        weights, every read usable), and its two parts in ``fit`` (if given)."""
        per_rate = maps.pscale * self.pfactor  # (numbers or arrays of the pixels)
        zero = np.square(maps.read_noise) * self.sumw2f + np.multiply(maps.dark, per_rate)
        np.maximum(slope, 0, out=var)
        var *= per_rate
        var += zero
        if fit is not None and fit.var_rnoise is not None:
            fit.var_per_rate.reshape(-1)[:] = per_rate
            fit.var_rnoise.reshape(-1)[:] = zero

    def _weigh_steps(self, block, x, slope, var, bad, maps, fit, rmask, one_jump):
        """The slopes and variances of the ramps fitted whole (not ``bad``) where a step is
        plausible, and of the ramps whose one flag is a JUMP after the first read (taken
        out of ``bad``), over "no jump" and "a step at read k" (``jump_prior``;
        `~spherex_reduce.reduce.steps.fit_ramp.step_posterior`); ``x`` the block's reads
        less the first, in the work type.  The variance the steps add goes to
        ``var_rnoise`` too (it is computed at the ramp's rate once: ERR's expected rate
        does not redo it)."""
        nf, npx = self.nf, slope.size
        rn2 = np.broadcast_to(np.square(maps.read_noise), (npx,))
        ok = ~bad & (rn2 > 0)
        weigh_from = None
        if nf >= WEIGH_ALL_READS:  # only where the largest step reaches WEIGH_FROM
            with np.errstate(invalid="ignore", over="ignore"):
                best, _ = self.steps.screen(x, False)
                # the float32 screen picks the candidates with a margin; the test is
                # step_posterior's, in float64 on each ramp's own reads (the float32 line of
                # a bright ramp drifts: near 3 sigma a few are missed, their ERR <= 1.2 %
                # from the weighed one)
                ok &= best >= (0.98 * WEIGH_FROM) ** 2 * rn2
            weigh_from = WEIGH_FROM
        jumped = np.zeros(npx, bool)
        if one_jump is not None and one_jump.size:
            one_jump = one_jump[rn2[one_jump] > 0]
            at = np.argmax(rmask.reshape(nf, npx)[:, one_jump] & dq.JUMP, axis=0)
            # a JUMP on the first read splits nothing: a whole ramp like the others
            first = one_jump[at == 0]
            bad[first] = False
            ok[first] = True  # (weighed if a step is plausible)
            one_jump, at = one_jump[at > 0], at[at > 0]
            # the line through every read, in float64 (their float32 sums were not checked
            # for precision), then weighed over the reads the flagged step may be at
            self._precise(block, np.concatenate([first, one_jump]), slope, var, maps)
            ok[one_jump] = jumped[one_jump] = True
            bad[one_jump] = False
            fit.njumps.reshape(-1)[one_jump] = 1
            # segments of two reads or more, as `fit_segments` counts them
            fit.nsegments.reshape(-1)[one_jump] = (at >= 2).astype(np.int8) + (nf - at >= 2)
            fit.flags.reshape(-1)[one_jump] |= dq.JUMP
        idx = np.flatnonzero(ok)
        if not idx.size:
            return
        px = maps.pixels(idx)
        shift, extra, _ = step_posterior(
            self.steps, _relative_reads(block, idx), rn2[idx], self.jump_prior,
            pscale=px.pscale, dark=px.dark, jumped=jumped[idx], weigh_from=weigh_from)
        slope[idx] += shift
        # the line's variance at the posterior's slope (its shot noise: not at a slope through
        # a step), then the steps'
        line = np.empty(idx.size)
        self._model_variance(slope[idx], line, px)
        var[idx] = line + extra
        if fit.var_rnoise is not None:
            rnoise = fit.var_rnoise.reshape(-1)
            rnoise[idx] = rnoise[idx] + extra

    def _precise(self, block, idx, slope, var, maps):
        """Slopes of the pixels ``idx`` (flat indices of ``block``, every read usable) summed
        in float64, and their model variance: where float32 sums are too coarse (a bright
        ramp), the same weights, frames added one by one as in `_optimal`."""
        if not idx.size:
            return
        slope[idx] = np.einsum("f,fp->p", self.w, _relative_reads(block, idx))
        if self.want_var:
            v = np.empty(idx.size)
            self._model_variance(slope[idx], v, maps.pixels(idx))
            var[idx] = v

    def _optimal(self, block, slope, var, bad, maps, fit):
        """Generalised least squares for the pixels with every read usable (not ``bad``);
        returns their flat indices."""
        rn2 = np.square(maps.read_noise)
        rate = (np.maximum(np.where(bad, 0, slope), 0) + maps.dark) * maps.pscale
        # quantise rate / read_noise**2 (0.02 dex): pixels in a bin share weights
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = rate / rn2
            q = np.where(ratio > 1e-6, np.round(np.log10(ratio) * RATIO_BINS), -np.inf)
        weighed = np.isfinite(q)
        if np.ptp(self.noise.read_factors) > 0:  # reads of unequal weight (groups of different
            # sizes): at no rate the weights are the read noise's alone (key -inf: ratio 0),
            # not the uniform ones the other ramps keep
            weighed |= (q == -np.inf) & np.isfinite(ratio)
        idx = np.flatnonzero(~bad & weighed)
        if not idx.size:
            return idx
        keys, inv = np.unique(q[idx], return_inverse=True)
        rn2 = np.broadcast_to(rn2, slope.shape)
        pscale = np.broadcast_to(maps.pscale, slope.shape)
        dark = np.broadcast_to(maps.dark, slope.shape)
        parts = fit.var_rnoise is not None
        if parts:
            rnoise, per_rate = fit.var_rnoise.reshape(-1), fit.var_per_rate.reshape(-1)
        for k, key in enumerate(keys):
            wk, vk = self.noise.gls_weights(10 ** (key / RATIO_BINS))
            cols = idx[inv == k]
            # frames added one by one in float64 (a BLAS product's order depends on
            # the other columns)
            slope[cols] = np.einsum("f,fp->p", wk, _relative_reads(block, cols))
            if self.want_var:
                var[cols] = rn2[cols] * vk
            if parts:
                pf = float(wk @ self.noise.shot @ wk)
                per_rate[cols] = pscale[cols] * pf
                rnoise[cols] = (rn2[cols] * float(wk @ (wk * self.noise.read_factors))
                                + dark[cols] * pscale[cols] * pf)
        return idx

    def _refit(self, block, rmask, bidx, fit, maps):
        """Pixels ``bidx`` (flat indices of the block, ``(nframes, rows, m)``, and its flags
        ``rmask``) fitted segment by segment on their usable reads
        (`~spherex_reduce.reduce.steps.fit_ramp.segments.fit_segments`); ``maps``, ``fit``:
        the block's, flattened and C-ordered."""
        m = block.shape[2]
        rr, cc = np.divmod(bidx, m)
        y = np.asarray(block[:, rr, cc], dtype=np.float64)
        flags = None if rmask is None else as_dq(rmask[:, rr, cc])
        px = maps.pixels(bidx)
        seg = fit_segments(y, flags, self.noise, saturation=self.saturation,
                           read_noise=px.read_noise if self.want_var else None,
                           pscale=px.pscale, dark=px.dark, weighting=self.weighting,
                           want_var=self.want_var)
        for name in fit.arrays:
            getattr(fit, name).reshape(-1)[bidx] = getattr(seg, name)
