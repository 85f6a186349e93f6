"""Interim fit_ramp consumer (replaced by the ramp module of the band executor)."""

import numpy as np
from astropy import units as u

from ..errors import StepSkipped
from ..exposure import Exposure, ReferenceReads
from ..hookspecs import hookimpl
from ..parameters import Parameter
from ..step import Consumer, Step
from .ramp import WEIGHTINGS, _check_params, _Fit, _fit_cube, _result

_OPT_NUM = (int, float, type(None))


def fit_ramp(exposure, *, weighting="uniform", read_noise=None, gain=1.0, saturation=None):
    """Least-squares slope of every pixel's ramp (see `spherex_reduce.steps.ramp`)."""
    return FitRampStep()(exposure, weighting=weighting, read_noise=read_noise, gain=gain,
                         saturation=saturation)


class RampFit(Consumer):
    def __init__(self, context, **kw):
        self.context, self.kw = context, kw
        s = context.schedule
        self.times = s.frame_starts.to_value(u.s)
        n = s.n_reads if context.order == "readout" else s.geometry.nrows
        self.fit = _Fit((n, s.geometry.ncols), np.float64)
        self.phantom = None

    def band(self, block):
        f = _fit_cube(block.data, self.times, mask=block.dq, threads=1, **self.kw)
        self.fit.slope[block.index] = f.slope
        self.fit.var[block.index] = f.var
        self.fit.nreads[block.index] = f.nreads
        self.fit.flags[block.index] = f.flags
        if block.phantom is not None:
            if self.phantom is None:
                s = self.context.schedule
                self.phantom = np.full((self.fit.slope.shape[0], s.geometry.nchannels), np.nan)
            self.phantom[block.index] = _fit_cube(block.phantom, self.times, want_var=False,
                                                  threads=1).slope

    def finish(self, reference, header, tables):
        if reference is not None and np.ndim(reference.data) == 3:
            rfit = _fit_cube(reference.data, self.times, mask=reference.dq,
                             saturation=self.kw["saturation"], want_var=False)
            rphant = (None if reference.phantom is None
                      else _fit_cube(reference.phantom, self.times, want_var=False).slope)
            reference = ReferenceReads(data=rfit.slope, rows=reference.rows,
                                       reads=reference.reads, phantom=rphant, dq=rfit.flags)
        c = self.context
        template = Exposure.from_arrays(np.zeros(self.fit.slope.shape), c.schedule, unit=c.unit,
                                        header=header, order=c.order, tables=tables)
        return _result(template, c.schedule, self.fit, self.phantom, reference,
                       self.kw["weighting"])


class FitRampStep(Step):
    """Least-squares slopes (`~spherex_reduce.fit_ramp`)."""

    name, keyword = "fit_ramp", "S_RAMPFT"
    parameters = (
        Parameter("weighting", "uniform", (str,), "uniform (paper) or optimal",
                  choices=WEIGHTINGS),
        Parameter("read_noise", None, _OPT_NUM, "read noise per read (data unit); null: "
                  "uncertainty from the fit residuals", minimum=0),
        Parameter("gain", 1.0, (float,), "electrons per data unit (shot noise)", minimum=0,
                  exclusive_minimum=True),
        Parameter("saturation", None, _OPT_NUM, "reads above this level are not used "
                  "(data unit)"),
    )

    def consumer(self, context, **params):
        _check_params(params["weighting"], params["read_noise"])
        if not context.ramp:
            raise StepSkipped("the input is already a 2-D image (slopes)")
        return RampFit(context, **params)


@hookimpl
def register_steps():
    return [FitRampStep]
