"""Readout order to physical order, and back."""

import numpy as np

from .. import dq
from ..errors import StepSkipped
from ..exposure import ReferenceReads

__all__ = ["rechop", "unchop"]


def _physical_index(schedule):
    """Read index feeding each physical row (first read), and rows read several times."""
    first = schedule.read_of_row()
    counts = np.bincount(schedule.rows, minlength=schedule.geometry.nrows)
    return first, np.flatnonzero(counts > 1)


def _to_physical(values, schedule, first, repeated, flags=None):
    """Gather ``values`` (..., n_reads, m) into (..., nrows, m); NaN for unread rows.

    A re-read row gets the mean of its usable reads (finite, not flagged in
    ``flags``); NaN if none is usable.
    """
    if values is None:
        return None
    out = np.take(values, np.maximum(first, 0), axis=-2)
    if not np.issubdtype(out.dtype, np.floating):
        out = out.astype(np.float64)
    if (first < 0).any():
        out[..., first < 0, :] = np.nan
    for row in repeated:
        out[..., row, :] = _reread_mean(values, schedule, row, flags)
    return out


def _reread_mean(values, schedule, row, flags=None):
    """Mean (float64) of the usable reads of physical ``row``: ``(..., m)``, NaN if none."""
    return _mean_of_reads(values, np.flatnonzero(schedule.rows == row), flags)


def _mean_of_reads(values, idx, flags=None):
    """Mean (float64) of the usable reads ``idx`` of ``values (..., reads, m)``."""
    reads = np.take(values, idx, axis=-2).astype(np.float64)
    if flags is not None:
        reads[np.take(flags, idx, axis=-2) != 0] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        count = np.isfinite(reads).sum(axis=-2)
        return np.where(count > 0, np.nansum(reads, axis=-2) / count, np.nan)


def _reread_sigma(values, sigma, schedule, row, flags=None):
    """Standard deviation of `_reread_mean`: ``sqrt(sum sigma_i^2) / n`` over the usable reads."""
    idx = np.flatnonzero(schedule.rows == row)
    good = np.isfinite(np.take(values, idx, axis=-2))
    if flags is not None:
        good &= np.take(flags, idx, axis=-2) == 0
    sig = np.take(sigma, idx, axis=-2).astype(np.float64)
    n = good.sum(axis=-2)
    var = np.where(good, sig * sig, 0.0).sum(axis=-2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(var) / n, np.nan)


def _flags_to_physical(flags, schedule, first, repeated):
    """Flags in physical order; a re-read row is usable where any of its reads is."""
    out = np.take(flags, np.maximum(first, 0), axis=-2)
    for row in repeated:
        reads = np.take(flags, np.flatnonzero(schedule.rows == row), axis=-2)
        usable = (reads == 0).any(axis=-2)
        out[..., row, :] = np.where(usable, 0, np.bitwise_or.reduce(reads, axis=-2))
    return out


def unchop(exposure):
    """Put the rows of an exposure into physical order (paper §2.3).

    Every active row is read once per frame and goes to its physical place.
    Reference reads are kept aside, with their read indices (hence their
    times), as ``exposure.reference``; each physical reference row of the
    image holds the mean of its usable reads (finite, not flagged), with the
    uncertainty of that mean.  Rows the schedule never reads are NaN
    and flagged `~spherex_reduce.dq.NOT_READ`.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        In readout order: ramps ``(frames, reads, columns)`` or slopes
        ``(reads, columns)``, any unit.

    Returns
    -------
    `~spherex_reduce.Exposure`
        A new exposure in physical order (rows ``(..., nrows, ncols)``); the
        input is not modified.

    Raises
    ------
    StepSkipped
        The exposure is already in physical order.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, unchop
    >>> s = ReadoutSchedule(DetectorGeometry(8, 4, 1, ref_border=1), skip=3, ref_reads=2,
    ...                     phantom_reads=0, nframes=1)
    >>> s.rows.tolist()
    [0, 1, 4, 2, 7, 5, 3, 6]
    >>> raw = Exposure.from_arrays(s.rows[:, None] * np.ones((1, 4)), s)  # value = its row
    >>> unchop(raw).data.data[:, 0].tolist()
    [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    """
    if exposure.order == "physical":
        raise StepSkipped("the exposure is already in physical order")
    schedule = exposure.schedule
    first, repeated = _physical_index(schedule)
    nd = exposure.data
    data = _to_physical(nd.data, schedule, first, repeated, exposure.dq)
    unc = None
    if nd.uncertainty is not None:
        unc = _to_physical(nd.uncertainty.array, schedule, first, ())
        for row in repeated:  # the error of the mean of its usable reads
            unc[..., row, :] = _reread_sigma(nd.data, nd.uncertainty.array, schedule, row,
                                             exposure.dq)
    flags = (None if exposure.dq is None
             else _flags_to_physical(exposure.dq, schedule, first, repeated))
    unread = first < 0
    if unread.any():
        flags = np.zeros(data.shape, np.uint16) if flags is None else flags.copy()
        flags[..., unread, :] |= dq.NOT_READ
    ref_idx = schedule.reference_read_indices
    reference = ReferenceReads(
        data=np.take(nd.data, ref_idx, axis=-2),
        rows=schedule.rows[ref_idx],
        reads=ref_idx,
        phantom=None if exposure.phantom is None else np.take(exposure.phantom, ref_idx, axis=-2),
        dq=None if exposure.dq is None else np.take(exposure.dq, ref_idx, axis=-2),
    )
    phantom = _to_physical(exposure.phantom, schedule, first, repeated)
    return exposure.replace(data=data, uncertainty=unc, dq=flags, phantom=phantom,
                            order="physical", reference=reference)


def rechop(exposure):
    """Put a physical-order exposure back into readout order (inverse of `unchop`).

    Active rows go back to their reads; reference reads come from
    ``exposure.reference``.  Used to check un-chopping and to write simulated
    images as an instrument would deliver them.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        In physical order, with the reference reads kept aside by `unchop`
        (if the schedule has reference reads).

    Returns
    -------
    `~spherex_reduce.Exposure`
        A new exposure in readout order.
    """
    if exposure.order == "readout":
        raise StepSkipped("the exposure is already in readout order")
    schedule = exposure.schedule
    ref_idx = schedule.reference_read_indices
    ref = exposure.reference
    if ref_idx.size and (ref is None or not np.array_equal(ref.reads, ref_idx)):
        raise ValueError("rechop needs the reference reads kept aside by unchop")

    def back(values, refvalues):
        if values is None:
            return None
        out = np.take(values, schedule.rows, axis=-2)
        if ref_idx.size:
            out[..., ref_idx, :] = refvalues
        return out

    nd = exposure.data
    data = back(nd.data, None if ref is None else ref.data)
    phantom = back(exposure.phantom, None if ref is None else ref.phantom)
    flags = None if exposure.dq is None else np.take(exposure.dq, schedule.rows, axis=-2)
    return exposure.replace(data=data, dq=flags, uncertainty=None, phantom=phantom,
                            order="readout", reference=None)
