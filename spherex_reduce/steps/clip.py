"""Outlier clipping and pair differencing of measured darks (paper §5.3)."""

import json
import re
import warnings

import numpy as np
from astropy.nddata import StdDevUncertainty
from astropy.stats import SigmaClip
from astropy.table import Table

from .. import dq
from ..errors import SpherexReduceError

__all__ = ["pair_difference", "recorded_steps", "sigma_clip"]


def sigma_clip(exposure, *, sigma=5.0, sigma_lower=None, sigma_upper=None, maxiters=None,
               cenfunc="median", stdfunc="std"):
    """Iteratively clip hot (and cold) pixels of an image into its mask (paper §5.3).

    Exactly the pixels `astropy.stats.sigma_clip` masks with the same
    settings (the clipping is done by `astropy.stats.SigmaClip`) over the
    unmasked, finite pixels of the image.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A 2-D image (e.g. slopes from `fit_ramp`).
    sigma : float
        Threshold in standard deviations (5, as the paper).
    sigma_lower, sigma_upper : float, optional
        Separate thresholds below and above the centre (default ``sigma``).
    maxiters : int or None
        Iteration limit; None (default) iterates until no pixel is clipped.
    cenfunc, stdfunc : str
        ``'median'``/``'mean'`` and ``'std'``/``'mad_std'`` as in astropy.

    Returns
    -------
    `~spherex_reduce.Exposure`
        The same pixels with the clipped ones flagged `~spherex_reduce.dq.HOT`
        (so masked); header
        ``NHOTPIX`` (pixels clipped) and table ``HOTPIX`` (``row``,
        ``column``, ``value`` of each).

    Raises
    ------
    SpherexReduceError
        The input is ramps (fit them first with `fit_ramp`).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, sigma_clip
    >>> s = ReadoutSchedule(DetectorGeometry(16, 16, 2, ref_border=1), skip=1,
    ...                     ref_mode="none", phantom_reads=0, nframes=1)
    >>> img = np.random.default_rng(0).normal(0, 1, (16, 16))
    >>> img[5, 7] = 100.0
    >>> out = sigma_clip(Exposure.from_arrays(img, s))
    >>> bool(out.data.mask[5, 7]), out.header["NHOTPIX"]
    (True, 1)
    """
    if exposure.is_ramp:
        raise SpherexReduceError("sigma_clip works on 2-D images: fit the ramps first (fit_ramp)")
    nd = exposure.data
    data = np.asarray(nd.data)
    flags = np.zeros(data.shape, np.uint16) if exposure.dq is None else exposure.dq
    old = flags != 0
    usable = ~old & np.isfinite(data)
    clipper = SigmaClip(sigma=sigma, sigma_lower=sigma_lower, sigma_upper=sigma_upper,
                        maxiters=maxiters, cenfunc=cenfunc, stdfunc=stdfunc)
    hot = np.zeros(data.shape, bool)
    if usable.any():
        # the usable pixels as one column: astropy clips along an axis with its
        # compiled code (same iterations, ~3x faster than its axis=None path);
        # its bounds then select the same pixels (tested against sigma_clip)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            _, lower, upper = clipper(data[usable][:, None], axis=0, masked=False,
                                      return_bounds=True, copy=False)
        with np.errstate(invalid="ignore"):
            hot = usable & ((data < lower[0]) | (data > upper[0]))
        if np.array_equal(hot, usable):
            # everything clipped (thresholds below 1 sigma): astropy's axis=None path
            # goes on to NaN bounds there and keeps every pixel; follow it exactly
            clipped = clipper(np.ma.MaskedArray(data, mask=~usable), masked=True, copy=True)
            hot = np.ma.getmaskarray(clipped) & usable
    rows, cols = np.nonzero(hot)
    tables = dict(exposure.tables)
    tables["HOTPIX"] = Table({"row": rows, "column": cols, "value": data[rows, cols]})
    header = exposure.header.copy()
    header["NHOTPIX"] = (int(hot.sum()), "pixels clipped by sigma_clip")
    return exposure.replace(dq=flags | np.where(hot, np.uint16(dq.HOT), np.uint16(0)),
                            tables=tables, header=header)


def _differences(a, b):
    """Why two exposures cannot be differenced, or an empty list."""
    problems = []
    if a.schedule != b.schedule:
        da = {**a.schedule.geometry.to_dict(), **a.schedule.to_dict()}
        db = {**b.schedule.geometry.to_dict(), **b.schedule.to_dict()}
        diff = [f"{k}: {da[k]!r} vs {db.get(k)!r}" for k in da if da[k] != db.get(k)]
        problems.append("readout parameters differ (" + (", ".join(diff) or "frame time")
                        + ")")
    if a.order != b.order:
        problems.append(f"row order differs ({a.order} vs {b.order})")
    if a.shape != b.shape:
        problems.append(f"shapes differ ({a.shape} vs {b.shape}): reduce both to the same stage")
    if (a.unit or None) != (b.unit or None):
        problems.append(f"units differ ({a.unit} vs {b.unit})")
    return problems


def pair_difference(a, b):
    """Difference of two exposures scaled by 1/√2 (paper §5.3, measured darks).

    Subtracting a second exposure taken the same way removes the dark current
    and fixed pattern; the factor ``1/sqrt(2)`` keeps the noise per exposure.

    Parameters
    ----------
    a, b : `~spherex_reduce.Exposure`
        Same readout parameters, row order, shape (both ramps or both images)
        and unit.

    Returns
    -------
    `~spherex_reduce.Exposure`
        ``(a - b) / sqrt(2)`` with uncertainty ``sqrt(ua**2 + ub**2) / sqrt(2)``,
        the union of the masks, phantom values and reference reads differenced
        the same way (when both have them) and ``a``'s header (``PAIRDIFF``).

    Raises
    ------
    SpherexReduceError
        The readout parameters, order, shape or unit differ (all reasons are
        listed).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce import pair_difference
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=1), skip=1, ref_mode="none",
    ...                     phantom_reads=0, nframes=1)
    >>> a = Exposure.from_arrays(np.full((4, 4), 3.0), s)
    >>> b = Exposure.from_arrays(np.full((4, 4), 1.0), s)
    >>> bool(pair_difference(a, b).data.data[0, 0] == 2 / np.sqrt(2))
    True
    """
    problems = _differences(a, b)
    if problems:
        raise SpherexReduceError("pair_difference: cannot difference these exposures: "
                                 + "; ".join(problems))
    root2 = np.sqrt(2.0)
    da, db = np.asarray(a.data.data), np.asarray(b.data.data)
    dtype = np.result_type(da.dtype, db.dtype, np.float32)
    data = ((da - db) / dtype.type(root2)).astype(dtype, copy=False)
    ua, ub = a.data.uncertainty, b.data.uncertainty
    unc = None
    if ua is not None or ub is not None:
        va = 0.0 if ua is None else ua.represent_as(StdDevUncertainty).array ** 2
        vb = 0.0 if ub is None else ub.represent_as(StdDevUncertainty).array ** 2
        unc = (np.sqrt(va + vb) / root2).astype(dtype)
    if a.dq is None and b.dq is None:
        flags = None
    else:
        flags = (np.zeros(data.shape, np.uint16) if a.dq is None else a.dq) | (
            np.zeros(data.shape, np.uint16) if b.dq is None else b.dq)
    phantom = None
    if a.phantom is not None and b.phantom is not None:
        phantom = (a.phantom - b.phantom) / root2
    reference = None
    ra, rb = a.reference, b.reference
    if ra is not None and rb is not None and np.shape(ra.data) == np.shape(rb.data):
        rph = None
        if ra.phantom is not None and rb.phantom is not None:
            rph = (ra.phantom - rb.phantom) / root2
        reference = ra.replace(data=(np.asarray(ra.data) - rb.data) / root2, phantom=rph)
    header = a.header.copy()
    header["PAIRDIFF"] = (True, "pair difference (a - b)/sqrt(2)")
    return a.replace(data=data, uncertainty=unc, dq=flags, phantom=phantom,
                     reference=reference, tables={}, header=header)


_RECORD = re.compile(r"([A-Za-z_][A-Za-z0-9_]*) (complete|skipped) in [0-9.eE+-]+ s: ")


def recorded_steps(header):
    """``[(name, status, params), ...]`` of the steps recorded in a header's HISTORY.

    Reads the provenance the pipeline writes after every step
    (``"<step> complete in <t> s: {json parameters}"``), rejoining HISTORY
    cards that FITS split at 72 characters.
    """
    values = [str(v) for v in header.get("HISTORY", [])]
    text = "".join(v + ("" if len(v) >= 72 else "\n") for v in values)
    decoder = json.JSONDecoder()
    steps = []
    for match in _RECORD.finditer(text):
        try:
            params, _ = decoder.raw_decode(text, match.end())
        except json.JSONDecodeError:
            continue
        steps.append((match.group(1), match.group(2).upper(), params))
    return steps
