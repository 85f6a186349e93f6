"""Master darks: combine reduced exposures and subtract them (paper §5.3, Fig. 12a)."""

import os
import warnings
from pathlib import Path

import numpy as np
from astropy.nddata import CCDData, StdDevUncertainty

from ...core import dq
from ...core.errors import ConfigError, SpherexReduceError
from ...core.exposure import Exposure, as_dq
from ...core.parameters import Parameter, validate_parameters
from ...io import read
from ..hookspecs import hookimpl
from ..step import Step

__all__ = ["combine_darks", "subtract_dark"]

COMBINE_METHODS = ("average", "median", "sum")
#: The parameters of `combine_darks` (and of the ``combine`` command), with their defaults.
COMBINE_PARAMETERS = (
    Parameter("method", "average", (str,), "ccdproc.combine method", choices=COMBINE_METHODS),
    Parameter("sigma", 3.0, (float,), "clip each pixel at this many standard deviations "
              "across the inputs (0: no clipping)", minimum=0),
)


def _as_exposure(item, what):
    if isinstance(item, Exposure):
        return item
    if isinstance(item, (str, Path)):
        return read(item)
    raise SpherexReduceError(f"{what}: expected an Exposure or a FITS path, got "
                             f"{type(item).__name__}")


def _check_image(e, what):
    if e.is_ramp:
        raise SpherexReduceError(f"{what} is ramps ({e.shape}); darks are combined and "
                                 "subtracted as 2-D images: fit the ramps first (fit_ramp)")


def combine_darks(exposures, *, method="average", sigma=3.0):
    """Combine reduced exposures into a master dark with ccdproc's `~ccdproc.Combiner`.

    Parameters
    ----------
    exposures : sequence of `~spherex_reduce.Exposure` or paths
        At least two 2-D images (e.g. slope images from `fit_ramp`) of the
        same geometry, row order, shape and convertible units; never
        modified.  A value is usable if it is finite and not masked (its
        flags only informational, `~spherex_reduce.core.dq.image_usable`).
    method : {'average', 'median', 'sum'}
        `ccdproc.combine` method, over the usable values of each pixel
        (``sum`` adds only those, as ccdproc does).
    sigma : float
        σ-clipping of each pixel across its usable values (median centre,
        spread from the median absolute deviation, robust with few inputs);
        0 disables it.

    Returns
    -------
    `~spherex_reduce.Exposure`
        The master dark in the first input's unit, the first input's
        schedule and header, and ``NCOMBINE``.  Its uncertainty is what
        ccdproc propagates (std of the values used over ``sqrt(n)`` for
        average), except where one value is left: the pixel is that value
        and its uncertainty that input's own (NaN if it has none), where
        the spread of one value would say 0.  A pixel with no usable value
        left (every input masked, NaN or clipped) is NaN, flagged
        `~spherex_reduce.core.dq.DO_NOT_USE` and the flags of its inputs;
        the header counts both kinds (``NCOMB1``, ``NCOMB0``).  The
        reference pixels are combined like the others and flagged
        `~spherex_reduce.core.dq.REFERENCE`.

    Notes
    -----
    Every statistic is per pixel, across the inputs (the clipping's median
    and spread included): no pixel's value enters another's, so reference
    pixels never weigh on the light-sensitive ones.  A masked value enters
    neither the clip's centre nor its spread (``ccdproc.combine`` reads the
    values under the mask there: two masked zeros of three clip the third).

    Raises
    ------
    SpherexReduceError
        Fewer than two inputs, ramps, or inputs that disagree; a
        `~spherex_reduce.core.errors.ConfigError` for a ``method`` or
        ``sigma`` that `COMBINE_PARAMETERS` does not allow.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, combine_darks
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=1), skip=1, ref_mode="none",
    ...                     phantom_reads=0, nframes=2)
    >>> darks = [Exposure.from_arrays(np.full((4, 4), v), s) for v in (1.0, 2.0, 3.0)]
    >>> float(combine_darks(darks, sigma=0).data.data[0, 0])
    2.0
    """
    params = validate_parameters({"method": method, "sigma": sigma}, COMBINE_PARAMETERS,
                                 "combine_darks")
    method, sigma = params["method"], params["sigma"]
    items = [_as_exposure(e, f"input {i + 1}") for i, e in enumerate(exposures)]
    if len(items) < 2:
        raise SpherexReduceError(f"combine needs at least two exposures, got {len(items)}")
    first = items[0]
    for i, e in enumerate(items):
        _check_image(e, f"input {i + 1}")
        if e.geometry != first.geometry or e.order != first.order or e.shape != first.shape:
            raise SpherexReduceError(
                f"input {i + 1} disagrees with input 1: geometry, row order or shape "
                f"({e.order} {e.shape} vs {first.order} {first.shape})")
        if not e.unit.is_equivalent(first.unit):
            raise SpherexReduceError(f"input {i + 1} is in {e.unit}, input 1 in {first.unit}")
    values, sigmas, flags = (np.stack(a) for a in zip(*(_usable(e, first.unit) for e in items),
                                                        strict=True))
    master, used = _ccdproc_combine(values, first.unit, method, sigma)
    count = used.sum(axis=0)
    data = np.asarray(master.data, np.float64)
    unc = master.uncertainty.represent_as(StdDevUncertainty).array
    # one input left: its value, and its own uncertainty (the spread of one value is no error)
    one = count == 1
    unc = np.where(one, np.where(used, sigmas, 0.0).sum(axis=0), unc)
    none = count == 0
    data = np.where(none, np.nan, data)
    unc = np.where(none, np.nan, unc)
    dqs = np.where(none, np.bitwise_or.reduce(flags, axis=0) | dq.DO_NOT_USE, 0)
    header = first.header.copy()
    for e in items[1:]:  # an input read despite a bad checksum: the master says so too
        if "SXRCKBAD" in e.header:
            bad = ",".join(filter(None, [str(header.get("SXRCKBAD", "")), e.header["SXRCKBAD"]]))
            header["SXRCKBAD"] = (bad[:68], e.header.comments["SXRCKBAD"])
            for line in e.header.get("HISTORY", []):
                if "read anyway" in line:
                    header.add_history(line)
    header["NCOMBINE"] = (len(items), "exposures combined into this master dark")
    header["COMBMETH"] = (method, "ccdproc.combine method")
    header["NCOMB1"] = (int(one.sum()), "pixels from one usable input")
    header["NCOMB0"] = (int(none.sum()), "pixels with no usable input (NaN, DO_NOT_USE)")
    out = first.replace(data=data, uncertainty=unc, dq=dqs.astype(dq.DQ_TYPE),
                        header=header, tables={}, phantom=None, reference=None)
    return out.with_reference_flags()


def _usable(e, unit):
    """An input's values in ``unit`` (a new array: NaN where flagged or not finite), their
    standard deviations (NaN without an uncertainty) and its flags."""
    scale = e.unit.to(unit)
    values = np.array(e.data.data, np.float64) * scale
    if e.data.mask is not None:
        values[np.asarray(e.data.mask, bool)] = np.nan
    unc = e.data.uncertainty
    sigma = (np.full(e.shape, np.nan) if unc is None
             else unc.represent_as(StdDevUncertainty).array * scale)
    flags = np.zeros(e.shape, dq.DQ_TYPE) if e.dq is None else e.dq
    return values, sigma, flags


def _ccdproc_combine(values, unit, method, sigma):
    """``ccdproc`` 's combine of ``values`` (inputs, rows, columns; NaN: not usable) and which
    input values it used (neither NaN nor clipped).

    The flagged values are NaN before the clip, so that they enter neither its centre nor
    its spread: ccdproc's clip reads the data under the mask (two flagged zeros of three
    made the median 0 and the spread 0, clipping the one good value).  numpy's warnings
    about pixels with no value left ("Mean of empty slice" ...) are the counts of
    `combine_darks` instead.
    """
    import ccdproc
    from astropy.stats import mad_std

    combiner = ccdproc.Combiner([CCDData(v, unit=unit) for v in values], dtype=np.float64)
    with warnings.catch_warnings():
        for text in _EMPTY_PIXEL_WARNINGS:
            warnings.filterwarnings("ignore", message=text)
        if sigma:
            combiner.sigma_clipping(low_thresh=sigma, high_thresh=sigma, func=np.ma.median,
                                    dev_func=mad_std)
        master = getattr(combiner, f"{method}_combine")()
    used = ~np.ma.getmaskarray(combiner.data_arr) & np.isfinite(values)
    return master, used


#: The messages of numpy's and astropy's warnings on a pixel left with no value or one.
_EMPTY_PIXEL_WARNINGS = ("Mean of empty slice", "Degrees of freedom <= 0", "All-NaN slice",
                         "invalid value encountered", "Input data contains invalid values")


def subtract_dark(exposure, dark):
    """Subtract a master dark image (paper §5.3: a low-noise long exposure, Fig. 12a).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A 2-D image (e.g. slopes).
    dark : `~spherex_reduce.Exposure`, `~astropy.nddata.CCDData` or path
        The master dark: same shape (and row order for an Exposure), a unit
        convertible to the exposure's (e.g. from `combine_darks`, or an
        ``N = 386`` exposure reduced the same way).  Its number of frames
        need not match.

    Returns
    -------
    `~spherex_reduce.Exposure`
        ``exposure - dark`` with uncertainties added in quadrature, masks
        combined, and the dark's file name in ``DARKFILE`` when given a path.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.nddata import CCDData
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, subtract_dark
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=1), skip=1, ref_mode="none",
    ...                     phantom_reads=0, nframes=2)
    >>> e = Exposure.from_arrays(np.full((4, 4), 5.0), s)
    >>> float(subtract_dark(e, CCDData(np.full((4, 4), 2.0), unit="electron")).data.data[1, 1])
    3.0
    """
    if isinstance(dark, (str, os.PathLike)):
        return SubtractDarkStep()(exposure, dark=str(dark))
    return SubtractDarkStep().apply_to(exposure, {}, inputs={"dark": dark})


def _subtract_dark(exposure, dark):
    """`subtract_dark` itself (its step's run), ``dark`` an Exposure or CCDData."""
    _check_image(exposure, "the exposure")
    if isinstance(dark, CCDData):
        d_data, d_unit, d_unc, d_order = dark.data, dark.unit, dark.uncertainty, exposure.order
        d_flags = None if dark.mask is None else as_dq(dark.mask)
    else:
        d = _as_exposure(dark, "dark")
        _check_image(d, "the dark")
        d_data, d_unit, d_unc, d_order = d.data.data, d.unit, d.data.uncertainty, d.order
        d_flags = d.dq
    if d_order != exposure.order or np.shape(d_data) != exposure.shape:
        raise SpherexReduceError(
            f"the dark ({d_order}, shape {np.shape(d_data)}) does not match the exposure "
            f"({exposure.order}, shape {exposure.shape})")
    unit = exposure.unit
    if d_unit is not None and unit is not None and d_unit != unit:
        if not d_unit.is_equivalent(unit):
            raise SpherexReduceError(f"the dark is in {d_unit}, the exposure in {unit}")
        scale = d_unit.to(unit)
    else:
        scale = 1.0
    data = np.asarray(exposure.data.data)
    out = data - np.asarray(d_data) * scale
    out = out.astype(np.result_type(data.dtype, np.float32), copy=False)
    ue = exposure.data.uncertainty
    unc = None
    if ue is not None or d_unc is not None:
        ve = 0.0 if ue is None else ue.represent_as(StdDevUncertainty).array ** 2
        vd = 0.0 if d_unc is None else (d_unc.represent_as(StdDevUncertainty).array
                                        * scale) ** 2
        unc = np.sqrt(ve + vd) * np.ones(out.shape)
    flags = exposure.dq
    if d_flags is not None:
        flags = (np.zeros(out.shape, np.uint32) if flags is None else flags) | d_flags
    return exposure.replace(data=out, uncertainty=unc, dq=flags)


class SubtractDarkStep(Step):
    """Subtract a master dark image (`~spherex_reduce.subtract_dark`).

    ``dark`` names the master dark's FITS file, a declared input read before
    the step runs; its name goes into ``DARKFILE``.
    """

    name, keyword = "subtract_dark", "S_DARK"
    inputs = ("dark",)
    parameters = (
        Parameter("dark", None, (str, type(None)), "FITS file of the master dark (e.g. from "
                  "spherex-reduce combine)"),
    )

    def run(self, exposure, dark):
        if dark is None:
            raise ConfigError("subtract_dark.dark: give the master dark's FITS file")
        return _subtract_dark(exposure, dark)

    def input_card(self, name, label):
        return ("DARKFILE", Path(label).name[:68], "master dark subtracted")


@hookimpl
def register_steps():
    return [SubtractDarkStep]
