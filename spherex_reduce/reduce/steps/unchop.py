"""Readout order to physical order, and back."""

from dataclasses import dataclass

import numpy as np

from ...core import dq
from ...core.block import Block
from ...core.errors import StepSkipped
from ..hookspecs import hookimpl
from ..noise_effect import NoiseEffect
from ..step import Kernel, Step

__all__ = ["rechop", "unchop"]


def _physical_index(schedule):
    """Read index feeding each physical row (first read), and rows read several times."""
    first = schedule.read_of_row()
    counts = np.bincount(schedule.rows, minlength=schedule.geometry.nrows)
    return first, np.flatnonzero(counts > 1)


def _mean_of_reads(values, idx, flags=None):
    """Mean (float64) of the usable reads ``idx`` of ``values (..., reads, m)``."""
    reads = np.take(values, idx, axis=-2).astype(np.float64)
    if flags is not None:
        reads[~dq.read_usable(np.take(flags, idx, axis=-2))] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        count = np.isfinite(reads).sum(axis=-2)
        return np.where(count > 0, np.nansum(reads, axis=-2) / count, np.nan)


def unchop(exposure):
    """Put the rows of an exposure into physical order (paper §2.3).

    Every active row is read once per frame and goes to its physical place.
    Reference reads are kept aside, with their read indices (hence their
    times), as ``exposure.reference``; each physical reference row of the
    image holds the mean of its usable reads (finite, not flagged), with the
    uncertainty of that mean.  Rows the schedule never reads are NaN
    and flagged `~spherex_reduce.core.dq.NOT_READ`.

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

    Notes
    -----
    When there is nothing to do (the exposure is already in physical order) the step is
    skipped, stpipe style: the input comes back unchanged, with the status
    keyword set to ``SKIPPED`` and the reason in HISTORY and ``PROVENANCE``.

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
    return UnchopStep()(exposure)


@dataclass(frozen=True)
class RowMean:
    """A physical row read more than once: the mean of its usable reads, per frame.

    Attributes
    ----------
    data : `numpy.ndarray`
        ``(frames, ncols)`` float64 mean of the usable reads (finite, not
        flagged); NaN where none is.
    phantom : `numpy.ndarray` or None
        ``(frames, nchannels)`` mean of the reads' phantom values, or None.
    uncertainty : `numpy.ndarray` or None
        ``(frames, ncols)`` standard deviation of ``data``, or None.
    flags : `numpy.ndarray` or None
        ``(frames, ncols)`` uint32: 0 where a read is usable, else the flags
        of all its reads; or None.
    """

    data: np.ndarray
    phantom: np.ndarray | None
    uncertainty: np.ndarray | None
    flags: np.ndarray | None


@dataclass(frozen=True)
class UnchopPlan:
    """What `UnchopKernel.prepare` takes from the side block: its coefficients.

    Attributes
    ----------
    means : dict
        `RowMean` of every physical row read more than once, by row.
    dtype : `numpy.dtype`
        Type of the un-chopped pixels (the input's if floating point, else
        float64).
    phantom_dtype : `numpy.dtype` or None
        Type of the phantom values; None when the input has none.
    nframes : int
        Frames of the input.
    ncols : int
        Columns of the input.
    uncertainty : bool
        Whether the input has uncertainties.
    """

    means: dict
    dtype: np.dtype
    phantom_dtype: np.dtype | None
    nframes: int
    ncols: int
    uncertainty: bool


class UnchopKernel(Kernel):
    """`unchop` on bands of reads: each read goes to its physical row.

    ``prepare`` takes, from the side block (which holds every read of the rows
    read more than once), the mean of the usable reads of each such row; a
    band of reads then gives the rows whose first read is in it, and
    `extra_rows` the rows never read (NaN, flagged
    `~spherex_reduce.core.dq.NOT_READ`).
    """

    def __init__(self, context):
        if context.order == "physical":
            raise StepSkipped("the exposure is already in physical order")
        super().__init__(context)
        s = context.schedule
        self.first, self.repeated = _physical_index(s)
        #: physical row first read by each read (-1: a later read of its row)
        self.row_of_read = np.full(s.n_reads, -1)
        read = self.first >= 0
        self.row_of_read[self.first[read]] = np.flatnonzero(read)

    @property
    def output(self):
        return self.context.replace(order="physical")

    def prepare(self, side):
        """Mean of the usable reads of every row read more than once (and its error), as an
        `UnchopPlan`."""
        s = self.context.schedule
        pos = np.full(s.n_reads, -1)
        pos[side.index] = np.arange(side.index.size)
        means = {}
        for row in self.repeated:
            idx = pos[np.flatnonzero(s.rows == row)]
            data = _mean_of_reads(side.data, idx, side.dq)
            phantom = None if side.phantom is None else _mean_of_reads(side.phantom, idx)
            unc = None
            if side.uncertainty is not None:
                unc = _sigma_of_mean(side.data, side.uncertainty, idx, side.dq)
            flags = None if side.dq is None else _usable_flags(side.dq, idx)
            means[int(row)] = RowMean(data, phantom, unc, flags)
        return UnchopPlan(means, _float_type(side.data.dtype),
                          None if side.phantom is None else side.phantom.dtype,
                          nframes=side.data.shape[0], ncols=side.data.shape[-1],
                          uncertainty=side.uncertainty is not None)

    def apply_side(self, plan, side):
        return side  # the reads stay reads: they are kept aside as the reference reads

    def apply(self, plan, block):
        rows = self.row_of_read[block.index]
        src = np.flatnonzero(rows >= 0)
        rows = rows[src]
        dtype = plan.dtype

        def gather(values, kind):
            if values is None:
                return None
            out = np.take(values, src, axis=1)
            if kind == "data" and out.dtype != dtype:
                out = out.astype(dtype)
            return out

        data = gather(block.data, "data")
        phantom = gather(block.phantom, "phantom")
        unc = gather(block.uncertainty, "unc")
        flags = gather(block.dq, "dq")
        for i in np.flatnonzero(np.isin(rows, self.repeated)):
            mean = plan.means[int(rows[i])]
            data[:, i] = mean.data
            if phantom is not None:
                phantom[:, i] = mean.phantom
            if unc is not None:
                unc[:, i] = mean.uncertainty
            if flags is not None:
                flags[:, i] = mean.flags
        return Block(data, rows, "physical", phantom=phantom, dq=flags, uncertainty=unc,
                     owned=True)

    def extra_rows(self, plan):
        """The rows the schedule never reads: NaN, flagged `~spherex_reduce.core.dq.NOT_READ`."""
        unread = np.flatnonzero(self.first < 0)
        if unread.size == 0:
            return None
        shape = (plan.nframes, unread.size, plan.ncols)
        g = self.context.geometry
        phantom = None
        if plan.phantom_dtype is not None:
            phantom = np.full((*shape[:2], g.nchannels), np.nan, plan.phantom_dtype)
        return Block(np.full(shape, np.nan, plan.dtype), unread, "physical", phantom=phantom,
                     dq=np.full(shape, dq.NOT_READ, np.uint32),
                     uncertainty=np.full(shape, np.nan) if plan.uncertainty else None,
                     owned=True)


def _float_type(dtype):
    """The type of un-chopped pixels: the input's if floating point, else float64."""
    return dtype if np.issubdtype(dtype, np.floating) else np.dtype(np.float64)


def _sigma_of_mean(values, sigma, idx, flags=None):
    """Standard deviation of `_mean_of_reads`: ``sqrt(sum sigma_i^2) / n`` over usable reads."""
    good = np.isfinite(np.take(values, idx, axis=-2))
    if flags is not None:
        good &= dq.read_usable(np.take(flags, idx, axis=-2))
    sig = np.take(sigma, idx, axis=-2).astype(np.float64)
    n = good.sum(axis=-2)
    var = np.where(good, sig * sig, 0.0).sum(axis=-2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(var) / n, np.nan)


def _usable_flags(flags, idx):
    """Flags of a row read several times: 0 where any read is usable, else all its flags."""
    reads = np.take(flags, idx, axis=-2)
    usable = dq.read_usable(reads).any(axis=-2)
    return np.where(usable, 0, np.bitwise_or.reduce(reads, axis=-2)).astype(np.uint32)


class UnchopStep(Step):
    """Readout order to physical order; reference re-reads kept aside (`unchop`)."""

    name = "unchop"
    keyword = "S_UNCHOP"
    #: a permutation of the rows: the forecast is of the image in physical row order
    noise_effect = NoiseEffect("identity")

    def kernel(self, context):
        return UnchopKernel(context)


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


@hookimpl
def register_steps():
    return [UnchopStep]
