"""``fit_ramp``: least-squares slopes of ramps, a consumer of bands of rows.

The step's one implementation is `RampFit`, a `~spherex_reduce.reduce.step.Consumer`:
the executor (`spherex_reduce.reduce.executor`) hands it bands of rows of every frame,
from several threads at once, and it fits each band where it lies in the
output (`~spherex_reduce.reduce.steps.fit_ramp.least_squares.LeastSquares`).  Each
pixel's slope depends on its own reads only, so a ramp fitted in one band or
in many, on any number of threads, gives the same numbers bit for bit.
`fit_ramp` on an exposure in memory is `FitRampStep.run`: the executor on the
whole exposure, cut into bands fitted on ``threads`` threads.
"""

import threading

import numpy as np
from astropy import units as u
from astropy.table import Column, Table

from ....core import dq
from ....core.errors import SpherexReduceError, StepSkipped
from ....core.exposure import Exposure, ReferenceReads
from ....core.parameters import OPTIONAL_NUMBER, Parameter, validate_parameters
from ...hookspecs import hookimpl
from ...noise_effect import NoiseEffect
from ...options import RunOptions
from ...step import Consumer, Step
from ..pixel_maps import MAP_TYPES, PixelMap, adu_gain
from .expected_rates import expected_errors
from .least_squares import LeastSquares, RampMaps, RampSolution
from .segments import RampNoise

__all__ = ["WEIGHTINGS", "FitRampStep", "RampFit", "fit_ramp"]

#: values of the ``weighting`` parameter
WEIGHTINGS = ("uniform", "optimal")


def fit_ramp(exposure, *, weighting="uniform", read_noise=None, gain=1.0, dark_current=0.0,
             saturation=None, jump_prior=None):
    """Least-squares slope of every pixel's ramp, segment by segment around jumps.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps ``(frames, rows or reads, columns)`` in readout or physical
        order, in any unit (typically electrons).
    weighting : {'uniform', 'optimal'}
        ``'uniform'``: ordinary least squares (the paper).  ``'optimal'``:
        generalised least squares for white read noise ``read_noise`` plus the
        shot noise of the pixel's signal (estimated by a first uniform fit;
        pixels with equal ``rate / read_noise**2`` to 0.02 dex share weights),
        on each pixel's own usable reads.
    read_noise : float, array or str, optional
        Read noise per read, in the data unit: one number, a 2-D map
        ``(nrows, ncols)`` of the stored image (as the files hold the pixels,
        whatever the channel layout), or (YAML) the path of a FITS image
        (``path[EXT]`` for an extension; its ``BUNIT``, if any, converted to
        the data unit: ``reduce/steps/pixel_maps.py``).  Given, the
        uncertainty is the model ``read_noise**2 sum(w**2)`` plus the shot
        noise of the pixel's expected rate given the exposure's slopes
        (`~spherex_reduce.reduce.steps.fit_ramp.expected_rates.expected_rates`;
        data unit = electrons / ``gain``; header ``ERRRATE``); not
        given, it comes from the fit residuals, ``chi2 / (n - 2) * sum(w**2)``
        (NaN for two reads).
    gain : float, array or str
        Electrons per data unit, for the shot-noise term (1 for electrons);
        a number or a map, as ``read_noise``.
    dark_current : float, array or str
        Dark current already subtracted from the ramps (e.g. by
        ``subtract_dark``), in data unit / s; its shot noise is added to the
        variance.  A number or a map, as ``read_noise``.
    saturation : float, optional
        Reads above this level (data unit) end the usable ramp, like a read
        flagged `~spherex_reduce.core.dq.SATURATED` in the input.
    jump_prior : float, optional
        Probability (dimensionless, in (0, 0.5]) that a ramp holds a jump.  Given
        (with ``read_noise`` and uniform weighting), the slope and uncertainty of
        every ramp fitted whole where a step is plausible (every ramp of fewer
        than 16 reads; longer ones where a step reaches 3 sigma) are the
        posterior mean and standard deviation over "no jump" and "a step at
        read k", the step's amplitude a prior over 1-1000 (and 1e6) read-noise
        sigmas (`~spherex_reduce.reduce.steps.fit_ramp.step_posterior`): a step too
        small for ``detect_jumps`` to flag widens the error instead of biasing
        the slope unseen.  A ramp whose one flag is a ``JUMP`` is weighed
        over the read its step may be at (amplitude free), except on 3 reads,
        where a step after the first read and one after the second fit alike:
        it is fitted around the search's read as without it.  The variance it
        adds is in ``var_rnoise``.  Ramps with several jumps or a masked read
        are fitted segment by segment as without it; reads of unequal weight
        (groups of different sizes) are refused.  None (default): the line's
        slope and error.

    Returns
    -------
    `~spherex_reduce.Exposure`
        A 2-D exposure: slope (float64) as `~astropy.nddata.CCDData` in
        ``unit / s`` with the fit uncertainty; DQ flags (``exposure.dq``):
        `~spherex_reduce.core.dq.FEW_READS` (slope NaN, do not use) when no
        segment has two usable reads; `~spherex_reduce.core.dq.SATURATED`
        (informs) whenever saturation cut the ramp;
        `~spherex_reduce.core.dq.JUMP` (informs) when the slope was fitted
        around jumps; and the flags set on every read of a pixel.  The table
        ``RAMPFIT`` has one row per image row and vector columns ``nreads``
        (reads used), ``njumps`` and ``nsegments`` (segments fitted); with
        ``read_noise`` also ``var_rnoise`` (the slope's read-noise variance,
        (unit / s)**2) and ``var_per_rate`` (its shot-noise variance per unit
        of rate, unit / s), from which integrations are combined without bias.
        Phantom values and reference reads are fitted the same way, so that
        `subtract_phantom` and `correct_reference` work on the slopes.

    Raises
    ------
    SpherexReduceError
        ``weighting='optimal'`` without a positive ``read_noise``.

    Notes
    -----
    If the input is already a 2-D image the step is skipped, stpipe style:
    the input comes back with ``S_RAMPFT = 'SKIPPED'`` and the reason recorded.

    Read times come from the schedule; within a frame each pixel's time is a
    fixed offset, which cancels from the slope, so the frame start times set
    the weights.  For groups of averaged frames (``readout:``
    ``frames_per_group``/``group_gap`` or ``groups``) each group's time is its
    reads' mean, its read-noise variance ``read_noise**2 / n`` and the shot
    noise the covariance of the groups' mean charges
    (`spherex_reduce.ReadoutSchedule.shot_covariance`).

    A read is not used when it is not finite or flagged (any bit but
    ``JUMP``, ``REFERENCE`` and ``NO_REFERENCE``); the first read above
    ``saturation`` or flagged ``SATURATED`` ends the usable ramp.  A read
    flagged ``JUMP`` (by `~spherex_reduce.detect_jumps`) starts a new segment:
    each segment of two or more usable reads is fitted, and the segments'
    slopes are averaged with inverse-variance weights whose shot noise comes
    from the rate pooled over the segments (as stcal does; see
    `spherex_reduce.reduce.steps.fit_ramp.segments`).  The input is never
    modified.  Bands of rows are fitted on
    `~spherex_reduce.reduce.options.default_threads` threads; the
    numbers do not depend on the bands or the threads.

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
    return FitRampStep()(exposure, weighting=weighting, read_noise=read_noise, gain=gain,
                         dark_current=dark_current, saturation=saturation,
                         jump_prior=jump_prior)


def _validated(params):
    """``params`` checked against `FitRampStep.parameters`, defaults filled in (a new dict).

    Raises `~spherex_reduce.core.errors.ConfigError` for an unknown name or a
    wrong value, `~spherex_reduce.core.errors.SpherexReduceError` for
    ``weighting='optimal'`` without a positive ``read_noise``.  Maps are
    checked once the array's geometry is known (`RampFit`).
    """
    params = validate_parameters(params, FitRampStep.parameters, FitRampStep.name)
    read_noise = params["read_noise"]
    if params["weighting"] == "optimal" and (
            read_noise is None or (isinstance(read_noise, (int, float)) and not read_noise > 0)):
        raise SpherexReduceError("weighting='optimal' needs read_noise > 0 (in the data unit), "
                                 f"got {read_noise!r}")
    if params["jump_prior"] is not None:
        if read_noise is None:
            raise SpherexReduceError("fit_ramp.jump_prior needs read_noise: the steps a ramp "
                                     "may hold are weighed against it")
        if params["weighting"] != "uniform":
            raise SpherexReduceError("fit_ramp.jump_prior is for weighting='uniform' (the "
                                     f"line it weighs steps against), got {params['weighting']!r}")
    return params


def _maps(params, context):
    """The calibration parameters as `PixelMap` objects: maps of the stored image brought to
    the readout frame, in the data unit (read noise), per second (dark current) and electrons
    per data unit (gain); see `~spherex_reduce.reduce.steps.pixel_maps`."""
    name = FitRampStep.name
    optimal = params["weighting"] == "optimal"
    g, unit = context.schedule.geometry, context.unit
    gain = PixelMap.of(params["gain"], f"{name}.gain", g, positive=True,
                       unit=None if unit is None else u.electron / unit)
    known = adu_gain(unit, context.header, g, gain)
    rn = params["read_noise"]
    return (None if rn is None else PixelMap.of(rn, f"{name}.read_noise", g, minimum=0,
                                                 positive=optimal, unit=unit, gain=known),
            gain,
            PixelMap.of(params["dark_current"], f"{name}.dark_current", g, gain=known,
                        unit=None if unit is None else unit / u.s))


def _rows(index):
    """``index`` as a slice when it is a run of consecutive rows (outputs are then views)."""
    index = np.asarray(index)
    if index.size and index[-1] - index[0] == index.size - 1 and (
            index.size == 1 or (np.diff(index) == 1).all()):
        return slice(int(index[0]), int(index[-1]) + 1)
    return index


class RampFit(Consumer):
    """The slopes of the bands of a ramp (the consumer of `FitRampStep`).

    `band` fits a band in the calling thread and writes it at its rows of the
    output; bands may come from several threads at once (they never share
    rows).  `finish` fits the reference reads and returns the 2-D exposure.

    Parameters
    ----------
    context : `~spherex_reduce.core.block.Context`
        The bands' schedule, row order, unit and whether they carry phantom values.
    **params
        ``weighting``, ``read_noise``, ``gain``, ``dark_current``,
        ``saturation``, ``jump_prior``: as `fit_ramp` (declared, with their defaults, by
        `FitRampStep.parameters`).
    """

    def __init__(self, context, **params):
        params = _validated(params)
        self.context = context
        self.weighting = params["weighting"]
        s = context.schedule
        times = s.frame_starts.to_value(u.s)
        # calibration: each band's values (`_band_maps`, numbers or arrays) go to `fit`
        self.read_noise, self.gain, self.dark = _maps(params, context)
        noise = RampNoise.from_schedule(s)
        self.solver = LeastSquares(times, weighting=params["weighting"],
                                   saturation=params["saturation"], noise=noise,
                                   jump_prior=params["jump_prior"])
        self.phantom_solver = LeastSquares(times, want_var=False, noise=noise)
        self.reference_solver = LeastSquares(times, saturation=params["saturation"],
                                             want_var=False, noise=noise)
        nrows = s.n_reads if context.order == "readout" else s.geometry.nrows
        # every row comes in exactly one band (the executor's bands cover the input);
        # ``var`` holds the standard deviations once a band is fitted
        self.fit = RampSolution((nrows, s.geometry.ncols), parts=self.read_noise is not None)
        self.phantom = (np.full((nrows, s.geometry.nchannels), np.nan) if context.has_phantom
                        else None)
        self._local = threading.local()  # a work buffer per thread
        self._lock = threading.Lock()
        # pixels with fewer than 2 usable reads, with jumps, cut by saturation, so far
        self._few = self._jumped = self._saturated = 0

    def _buffer(self, data):
        """The calling thread's work buffer for blocks like ``data``."""
        buf = getattr(self._local, "buf", None)
        solver = self.solver
        if buf is None or buf.dtype != solver.work_type(data.dtype):
            buf = self._local.buf = solver.buffer(data.shape[-1], data.dtype)
        return buf

    def band(self, block):
        """Fit the ramps of ``block`` (a `~spherex_reduce.core.block.Block`) into the output."""
        if block.nframes != self.solver.nf:
            raise ValueError(f"a band of {block.nframes} frames for a fit of "
                             f"{self.solver.nf}")
        rows = _rows(block.index)
        buf = self._buffer(block.data)
        part = self.fit.rows(rows) if isinstance(rows, slice) else None
        part = self.solver.fit(block.data, block.dq, out=part, buf=buf,
                               maps=self._band_maps(block))
        # uncertainties and the count of unfitted pixels here, in the band's thread
        np.sqrt(part.var, out=part.var)
        jumped = int(np.count_nonzero(part.njumps))
        cut = part.flags & (dq.FEW_READS | dq.SATURATED)  # (rare: counted where set)
        few = saturated = 0
        if cut.any():
            few = int(np.count_nonzero(cut & dq.FEW_READS))
            saturated = int(np.count_nonzero(cut & dq.SATURATED))
        if not isinstance(rows, slice):
            self.fit.put(rows, part)
        with self._lock:
            self._few += few
            self._jumped += jumped
            self._saturated += saturated
        if self.phantom is not None and block.phantom is not None:
            self.phantom[rows] = self.phantom_solver.fit(block.phantom).slope

    def _band_maps(self, block):
        """The calibration of the pixels of ``block`` (`RampMaps` of numbers or arrays)."""
        s, order = self.context.schedule, self.context.order
        rn = None if self.read_noise is None else self.read_noise.rows(block.index, order, s)
        return RampMaps(read_noise=rn,
                        pscale=None if rn is None else 1.0 / self.gain.rows(block.index, order, s),
                        dark=self.dark.rows(block.index, order, s))

    def finish(self, reference, header, tables):
        """The 2-D exposure of slopes (once every band was fitted).

        ``reference`` (the input's `~spherex_reduce.ReferenceReads` after the
        kernels before this step, or None) is fitted too when it holds ramps.
        """
        fit = self.fit
        header = header.copy()
        if self.read_noise is not None:
            # the shot noise of each pixel's expected rate, given the exposure's slopes, not
            # of its own slope clipped at 0 (which overstates a dark's uncertainties)
            s = self.context.schedule
            bulk = ~s.geometry.reference_pixel_mask()  # not the reference pixels
            if self.context.order == "readout":
                bulk = bulk[s.rows]
            expected = expected_errors(fit.slope, fit.var_rnoise, fit.var_per_rate, fit.var,
                                       bulk, RunOptions(threads=self.context.threads)
                                       .thread_count())
            # (else too few pixels: each pixel's own slope)
            header["ERRRATE"] = ("expected" if expected else "own",
                                 "rates of ERR's shot noise (fit_ramp)")
        if reference is not None and np.ndim(reference.data) == 3:
            rfit = self.reference_solver.fit(reference.data, reference.dq)
            rphant = (None if reference.phantom is None
                      else self.phantom_solver.fit(reference.phantom).slope)
            reference = ReferenceReads(data=rfit.slope, rows=reference.rows,
                                       reads=reference.reads, phantom=rphant, dq=rfit.flags)
        tables = dict(tables)
        columns = {"nreads": fit.nreads, "njumps": fit.njumps, "nsegments": fit.nsegments}
        if self.read_noise is not None:  # the variance's parts: integrations combine on them
            rate = (self.context.unit or u.one) / u.s
            columns["var_rnoise"] = Column(fit.var_rnoise, unit=rate**2, description=(
                "slope variance at zero rate: read noise and dark-current shot noise"
                + ("; and the unflagged steps' (jump_prior)" if self.solver.steps is not None
                   else "")))
            columns["var_per_rate"] = Column(fit.var_per_rate, unit=rate, description=(
                "slope variance per unit of rate (shot noise)"))
        tables["RAMPFIT"] = Table(columns, copy=False,
                                  meta={"order": self.context.order,
                                        "comments": ["reads used, jumps and segments fitted, "
                                                     "one row per image row"]})
        header["NFEWRDS"] = (self._few, "pixels with fewer than 2 usable reads")
        header["NJUMPPX"] = (self._jumped, "pixels fitted around jumps")
        header["NSATPX"] = (self._saturated,
                            "pixels whose ramp saturation cut")
        header["RAMPWGT"] = (self.weighting, "ramp-fit weighting")
        return Exposure.from_arrays(fit.slope, self.context.schedule,
                                    unit=(self.context.unit or u.one) / u.s, uncertainty=fit.var,
                                    mask=fit.flags, phantom=self.phantom,
                                    order=self.context.order, header=header, tables=tables,
                                    reference=reference)


class FitRampStep(Step):
    """Least-squares slopes (`~spherex_reduce.fit_ramp`)."""

    name, keyword = "fit_ramp", "S_RAMPFT"
    parameters = (
        Parameter("weighting", "uniform", (str,), "uniform (paper) or optimal",
                  choices=WEIGHTINGS),
        Parameter("read_noise", None, (*MAP_TYPES, type(None)), "read noise per read (data "
                  "unit; a number or a FITS image of the array); null: "
                  "uncertainty from the fit residuals", minimum=0),
        Parameter("gain", 1.0, MAP_TYPES, "electrons per data unit (shot noise; a number or a "
                  "FITS image)", minimum=0, exclusive_minimum=True),
        Parameter("dark_current", 0.0, MAP_TYPES, "dark current already subtracted (data unit "
                  "/ s; a number or a FITS image): its shot noise is in the variance",
                  minimum=0),
        Parameter("saturation", None, OPTIONAL_NUMBER, "reads above this level are not used "
                  "(data unit)"),
        Parameter("jump_prior", None, OPTIONAL_NUMBER, "probability that a ramp holds a jump: "
                  "slopes and errors weigh the steps no search flagged (needs read_noise); "
                  "null: not", minimum=0, exclusive_minimum=True, maximum=0.5,
                  quiet_default=True),
    )
    #: linear with uniform weights (optimal weights depend on the signal) and every read
    #: used (a saturation level drops reads)
    noise_effect = NoiseEffect("slope_fit", linear={"weighting": ("uniform",),
                                                    "saturation": (None,),
                                                    "jump_prior": (None,)})

    def consumer(self, context, **params):
        params = _validated(params)  # wrong parameters are an error even for an image
        if not context.ramp:
            raise StepSkipped("the input is already a 2-D image (slopes)")
        if context.schedule.nframes < 2:  # every slope would be NaN
            raise SpherexReduceError(
                f"fit_ramp needs ramps of at least 2 frames; this one has "
                f"{context.schedule.nframes} (a single image: store it 2-D, or leave fit_ramp "
                f"out)")
        return RampFit(context, **params)


@hookimpl
def register_steps():
    return [FitRampStep]
