"""Master darks: combine reduced exposures and subtract them (paper §5.3, Fig. 12a)."""

import os
from pathlib import Path

import numpy as np
from astropy.nddata import CCDData, StdDevUncertainty

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
    """Combine reduced exposures into a master dark with `ccdproc.combine`.

    Parameters
    ----------
    exposures : sequence of `~spherex_reduce.Exposure` or paths
        At least two 2-D images (e.g. slope images from `fit_ramp`) of the
        same geometry, row order, shape and convertible units.
    method : {'average', 'median', 'sum'}
        `ccdproc.combine` method.
    sigma : float
        σ-clipping of each pixel across the inputs (median centre, spread
        from the median absolute deviation, robust with few inputs); 0
        disables it.

    Returns
    -------
    `~spherex_reduce.Exposure`
        The master dark in the first input's unit, with the uncertainty
        ccdproc propagates (std of the inputs over ``sqrt(n)`` for average),
        the first input's schedule and header, and ``NCOMBINE``.  Its flags:
        `~spherex_reduce.core.dq.DO_NOT_USE` where ccdproc masked the pixel
        (every input masked or clipped), and
        `~spherex_reduce.core.dq.REFERENCE` on the reference pixels, which are
        combined like the others.

    Notes
    -----
    Every statistic is per pixel, across the inputs (the clipping's median
    and spread included): no pixel's value enters another's, so reference
    pixels never weigh on the light-sensitive ones.

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
    import ccdproc
    from astropy.stats import mad_std

    params = validate_parameters({"method": method, "sigma": sigma}, COMBINE_PARAMETERS,
                                 "combine_darks")
    method, sigma = params["method"], params["sigma"]
    items = [_as_exposure(e, f"input {i + 1}") for i, e in enumerate(exposures)]
    if len(items) < 2:
        raise SpherexReduceError(f"combine needs at least two exposures, got {len(items)}")
    first = items[0]
    ccds = []
    for i, e in enumerate(items):
        _check_image(e, f"input {i + 1}")
        if e.geometry != first.geometry or e.order != first.order or e.shape != first.shape:
            raise SpherexReduceError(
                f"input {i + 1} disagrees with input 1: geometry, row order or shape "
                f"({e.order} {e.shape} vs {first.order} {first.shape})")
        if not e.unit.is_equivalent(first.unit):
            raise SpherexReduceError(f"input {i + 1} is in {e.unit}, input 1 in {first.unit}")
        ccd = e.to_ccddata()
        if e.unit != first.unit:
            ccd = ccd.convert_unit_to(first.unit)
        ccd.mask = None if ccd.mask is None else np.asarray(ccd.mask, bool)
        ccd.meta = {}
        ccds.append(ccd)
    kwargs = {}
    if sigma:
        kwargs = dict(sigma_clip=True, sigma_clip_low_thresh=sigma, sigma_clip_high_thresh=sigma,
                      sigma_clip_func=np.ma.median, sigma_clip_dev_func=mad_std)
    master = ccdproc.combine(ccds, method=method, dtype=np.float64, **kwargs)
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
    unc = master.uncertainty
    unc = None if unc is None else unc.represent_as(StdDevUncertainty).array
    mask = None if master.mask is None else np.asarray(master.mask, bool)
    out = first.replace(data=CCDData(master.data, unit=first.unit,
                                     uncertainty=None if unc is None else StdDevUncertainty(unc),
                                     mask=mask),
                        header=header, tables={}, phantom=None, reference=None)
    return out.with_reference_flags()


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
