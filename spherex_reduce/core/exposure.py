"""The one data object passed between steps."""

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData, NDData, StdDevUncertainty

from .dq import DO_NOT_USE, DQ_TYPE, REFERENCE, image_usable, read_usable
from .readout.schedule import ReadoutSchedule

__all__ = ["ORDERS", "Exposure", "ReferenceReads", "as_dq", "first_frames_schedule"]

#: Row orders of an exposure: as read (``readout``) or as on the array (``physical``).
ORDERS = ("readout", "physical")
_KEEP = object()


def expected_shape(schedule, order, ramp):
    """Pixel-array shape for ``schedule`` in ``order``: ramps ``(N, n, ncols)`` or ``(n, ncols)``.

    ``n`` is the reads per frame in readout order, the rows in physical order.
    """
    n = schedule.n_reads if order == "readout" else schedule.geometry.nrows
    shape = (n, schedule.geometry.ncols)
    return (schedule.nframes, *shape) if ramp else shape


def first_frames_schedule(schedule, n):
    """``schedule`` with its first ``n`` frames (each read alone, not grouped).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.core.exposure import first_frames_schedule
    >>> s = ReadoutSchedule(DetectorGeometry(16, 16, 2, ref_border=2), skip=4, ref_reads=4,
    ...                     nframes=6)
    >>> first_frames_schedule(s, 3).nframes
    3
    """
    n = int(n)
    if schedule.groups is not None or schedule.frames_per_group != 1:
        raise ValueError("first frames: grouped readouts (reads averaged in groups) are not "
                         "cut to their first reads")
    if not 1 <= n <= schedule.nframes:
        raise ValueError(f"first frames: {n} of a ramp of {schedule.nframes}")
    times = None if schedule.read_times is None else list(schedule.read_times)[:n]
    return schedule.replace(nframes=n, read_times=times)


def as_dq(mask):
    """Flags (uint32) from a mask: booleans become `~spherex_reduce.core.dq.DO_NOT_USE`;
    integers keep their 32 low bits (negative int32 values, as FITS stores bit 31, too)."""
    mask = np.asarray(mask)
    if mask.dtype == bool:
        return mask.astype(DQ_TYPE) * DQ_TYPE(DO_NOT_USE)
    if mask.dtype.kind not in "iu":
        raise TypeError(f"flags must be booleans or integers, got {mask.dtype.name}")
    return mask.astype(DQ_TYPE)


def _nddata(values, unit, uncertainty, flags):
    """CCDData for 2-D, NDData for 3-D; the mask: pixels (2-D) or reads (3-D) not usable."""
    if uncertainty is not None and not hasattr(uncertainty, "uncertainty_type"):
        # shared, like the values: steps never write into their inputs' arrays
        uncertainty = StdDevUncertainty(np.asarray(uncertainty), copy=False)
    if flags is None:
        mask = None
    elif values.ndim == 2:
        mask = ~image_usable(flags)
    else:  # frame by frame: no temporary of the flags' size
        mask = np.empty(np.shape(flags), bool)
        for i in range(mask.shape[0]):
            np.logical_not(read_usable(flags[i]), out=mask[i])
    cls = CCDData if values.ndim == 2 else NDData
    return cls(values, unit=unit, uncertainty=uncertainty, mask=mask)


@dataclass(frozen=True, eq=False)
class ReferenceReads:
    """Reference-row reads kept aside by `~spherex_reduce.unchop`, with their times.

    Parameters
    ----------
    data : `numpy.ndarray`
        Pixel values, shape ``(..., n, ncols)`` (frames first for ramps).
    rows : `numpy.ndarray`
        Physical row of each of the ``n`` reads.
    reads : `numpy.ndarray`
        Read index within the frame of each read (its time is
        ``schedule.start_times[reads]``).
    phantom : `numpy.ndarray` or None
        Phantom values of these reads, shape ``(..., n, nchannels)``.
    dq : `numpy.ndarray` or None
        Data-quality flags of these reads (same shape as ``data``).
    """

    data: np.ndarray
    rows: np.ndarray
    reads: np.ndarray
    phantom: np.ndarray | None = None
    dq: np.ndarray | None = None

    def replace(self, **changes):
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, eq=False)
class Exposure:
    """Pixels of one exposure with everything needed to reduce them.

    Steps take an Exposure and return a new one; they never change the
    arrays of their input (ccdproc style).

    Parameters
    ----------
    data : `~astropy.nddata.NDData` or `~astropy.nddata.CCDData`
        Ramps ``(nframes, n, ncols)`` as NDData, or a 2-D image ``(n, ncols)``
        (slopes, reduced images) as CCDData, with unit, optional uncertainty
        and mask.  ``n`` is the number of reads per frame in readout order
        and the number of rows in physical order.
    schedule : `ReadoutSchedule`
        How the pixels were read.
    header : `astropy.io.fits.Header`
        Provenance: step status keywords, parameters, history.
    phantom : `numpy.ndarray`, optional
        Phantom values (mean of the ``c`` samples) per read and channel,
        shape ``(nframes, n, nchannels)`` or ``(n, nchannels)``.
    order : {'readout', 'physical'}
        Whether rows are in the order read or in physical order.
    reference : `ReferenceReads`, optional
        The reference reads, kept aside once the exposure is un-chopped.
    tables : dict of `~astropy.table.Table`
        Tables recorded by steps (e.g. ``REFOFFS``); written as extensions.
    dq : `numpy.ndarray` of uint32, optional
        Data-quality flags (`spherex_reduce.core.dq` bits), same shape as the
        pixels.  ``data.mask`` is always the pixels (images) or reads (ramps)
        that must not be used: flags other than the informational ones
        (`~spherex_reduce.core.dq.image_usable`,
        `~spherex_reduce.core.dq.read_usable`); when only a mask is given,
        masked pixels get `~spherex_reduce.core.dq.DO_NOT_USE`.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy import units as u
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> s = ReadoutSchedule(DetectorGeometry(16, 16, 2, ref_border=2), skip=4, ref_reads=4,
    ...                     nframes=3)
    >>> e = Exposure.from_arrays(np.zeros((3, s.n_reads, 16)), s, unit=u.electron)
    >>> e.is_ramp, e.shape, e.unit
    (True, (3, 16, 16), Unit("electron"))
    """

    data: NDData
    schedule: ReadoutSchedule
    header: fits.Header = field(default_factory=fits.Header)
    phantom: np.ndarray | None = None
    order: str = "readout"
    reference: ReferenceReads | None = None
    tables: dict = field(default_factory=dict)
    dq: np.ndarray | None = None

    def __post_init__(self):
        if self.order not in ORDERS:
            raise ValueError(f"order must be one of {ORDERS}, got {self.order!r}")
        if not isinstance(self.data, NDData):
            raise TypeError("data must be an astropy NDData or CCDData; use Exposure.from_arrays")
        if self.data.data.ndim not in (2, 3):
            raise ValueError(f"data must be 2-D or 3-D, got shape {self.data.data.shape}")
        expected = self.expected_shape(self.data.data.ndim == 3)
        if self.data.data.shape != expected:
            raise ValueError(
                f"data shape {self.data.data.shape} disagrees with the schedule, which gives "
                f"{expected} in {self.order} order"
            )
        if self.dq is None and self.data.mask is not None:
            object.__setattr__(self, "dq", as_dq(self.data.mask))
        if self.dq is not None and self.dq.shape != self.data.data.shape:
            raise ValueError(f"dq shape {self.dq.shape} differs from data {self.data.data.shape}")
        if self.phantom is not None:
            pexp = (*expected[:-1], self.schedule.geometry.nchannels)
            if self.phantom.shape != pexp:
                raise ValueError(
                    f"phantom shape {self.phantom.shape} disagrees with the schedule, which "
                    f"gives {pexp}"
                )

    def expected_shape(self, ramp):
        """Shape of ``data`` that the schedule and ``order`` call for."""
        return expected_shape(self.schedule, self.order, ramp)

    @classmethod
    def from_arrays(cls, data, schedule, *, unit=u.electron, uncertainty=None, mask=None,
                    phantom=None, header=None, order="readout", **kwargs):
        """Wrap plain arrays: 3-D becomes `NDData` (ramps), 2-D `CCDData`.

        ``uncertainty`` is a standard deviation array in ``unit``.  ``mask``
        (booleans or `~spherex_reduce.core.dq` flags) has the data's shape or,
        over ramps, one frame's: a pixel mask of the array ``(nrows, ncols)``
        (in readout order, each read takes its row's flags, also when there are
        as many reads as rows) or one row per read;
        it then applies to every frame, as a 2-D ``DQ`` in a file does.

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
        >>> s = ReadoutSchedule(DetectorGeometry(4, 2, 1, ref_border=0), skip=2,
        ...                     ref_mode="none", phantom_reads=0, nframes=3)
        >>> bad = np.zeros((4, 2), bool)
        >>> bad[1, 0] = True  # physical row 1: the third read (skip 2 reads rows 0, 2, 1, 3)
        >>> e = Exposure.from_arrays(np.zeros((3, 4, 2)), s, mask=bad)
        >>> e.dq.shape, e.dq[:, 2, 0].tolist()
        ((3, 4, 2), [1, 1, 1])
        """
        data = np.asarray(data)
        flags = None if mask is None else as_dq(mask)
        if flags is not None and data.ndim == 3 and flags.ndim == 2:
            geometry = schedule.geometry
            if order == "readout" and flags.shape == (geometry.nrows, geometry.ncols):
                flags = flags[schedule.rows]  # a pixel mask, also when n_reads == nrows
            if flags.shape == data.shape[1:]:
                flags = np.broadcast_to(flags, data.shape)
        nd = _nddata(data, unit, uncertainty, flags)
        return cls(nd, schedule, header=fits.Header() if header is None else header.copy(),
                   phantom=phantom, order=order, dq=flags, **kwargs)

    # -- convenience -------------------------------------------------------
    @property
    def is_ramp(self):
        """True for frames up the ramp (3-D data)."""
        return self.data.data.ndim == 3

    @property
    def shape(self):
        """Shape of the pixel array."""
        return self.data.data.shape

    @property
    def unit(self):
        """Unit of the pixel values."""
        return self.data.unit

    @property
    def geometry(self):
        """The detector geometry of the schedule."""
        return self.schedule.geometry

    def reference_pixel_mask(self):
        """True for the reference pixels of one frame or image, in this exposure's row order.

        `DetectorGeometry.reference_pixel_mask
        <spherex_reduce.DetectorGeometry.reference_pixel_mask>` in physical
        order; in readout order each read takes the row it reads
        (``schedule.rows``), so a reference row read several times is a
        reference row at each read.  Statistics of an image leave these pixels
        out.

        Returns
        -------
        `numpy.ndarray` of bool
            ``(n, ncols)``: ``n`` the rows (physical order) or the reads of a
            frame (readout order).

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
        >>> s = ReadoutSchedule(DetectorGeometry(8, 4, 1, ref_border={"top": 1, "left": 1}),
        ...                     skip=3, ref_reads=2, phantom_reads=0, nframes=1)
        >>> s.rows.tolist()  # row 0, the reference row, is read twice
        [0, 1, 4, 7, 0, 2, 5, 3, 6]
        >>> e = Exposure.from_arrays(np.zeros((s.n_reads, 4)), s)
        >>> e.reference_pixel_mask().sum(axis=1).tolist()  # 4 in a reference row, else 1
        [4, 1, 1, 1, 4, 1, 1, 1, 1]
        """
        mask = self.geometry.reference_pixel_mask()
        return mask if self.order == "physical" else mask[self.schedule.rows]

    def with_reference_flags(self):
        """A new exposure whose image flags its reference pixels
        `~spherex_reduce.core.dq.REFERENCE` (informational: it masks nothing).

        What a reduction's output carries (`Pipeline.run
        <spherex_reduce.Pipeline.run>`, `~spherex_reduce.combine_darks`).  Ramps
        come back as they are: the flag is a property of a reduced image.

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, dq
        >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border={"left": 1}),
        ...                     ref_mode="none", phantom_reads=0, nframes=2)
        >>> e = Exposure.from_arrays(np.zeros((4, 4)), s, order="physical").with_reference_flags()
        >>> (e.dq[0] == dq.REFERENCE).tolist(), bool(e.data.mask.any())
        ([True, False, False, False], False)
        """
        if self.is_ramp:
            return self
        marked = (np.zeros(self.shape, DQ_TYPE) if self.dq is None
                  else np.array(self.dq, DQ_TYPE))  # (a copy: the input's flags stay)
        np.bitwise_or(marked, DQ_TYPE(REFERENCE), out=marked, where=self.reference_pixel_mask())
        return self.replace(dq=marked)

    def replace(self, **changes):
        """A new Exposure with some fields changed (the input is left as it was).

        ``data`` may be given as an array, which keeps the unit, uncertainty
        and flags unless ``unit``, ``uncertainty`` (std-dev array or None),
        ``dq`` (flags) or ``mask`` (bool or flags) are also given.  The header
        is copied.
        """
        arrays = {k: changes.pop(k) for k in ("unit", "uncertainty", "mask") if k in changes}
        if "mask" in arrays:
            if "dq" in changes:
                raise ValueError("give mask or dq, not both")
            changes["dq"] = None if arrays["mask"] is None else as_dq(arrays["mask"])
        data = changes.pop("data", None)
        if data is None and not arrays and "dq" not in changes:
            nd = self.data
        elif isinstance(data, NDData):
            nd = data
            changes.setdefault("dq", None if nd.mask is None else as_dq(nd.mask))
        else:
            base = self.data
            values = np.asarray(base.data if data is None else data)
            unc = arrays.get("uncertainty", _KEEP)
            if unc is _KEEP:
                unc = None if base.uncertainty is None else base.uncertainty.array
            flags = changes.get("dq", self.dq)
            changes["dq"] = flags
            nd = _nddata(values, arrays.get("unit", base.unit), unc, flags)
        header = changes.pop("header", self.header).copy()
        tables = changes.pop("tables", self.tables)
        return dataclasses.replace(self, data=nd, header=header, tables=dict(tables), **changes)

    def first_frames(self, n):
        """The ramp's first ``n`` frames, its schedule cut to them (arrays are views; the
        header is copied as it is).

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
        >>> s = ReadoutSchedule(DetectorGeometry(16, 16, 2, ref_border=2), skip=4,
        ...                     ref_reads=4, nframes=6)
        >>> e = Exposure.from_arrays(np.zeros((6, s.n_reads, 16)), s).first_frames(3)
        >>> e.schedule.nframes, e.shape
        (3, (3, 16, 16))
        """
        if not self.is_ramp:
            raise ValueError("first frames: the exposure holds an image, not ramps")
        schedule = first_frames_schedule(self.schedule, n)
        n = schedule.nframes
        unc = self.data.uncertainty
        ref = self.reference
        if ref is not None:
            ref = ref.replace(data=ref.data[:n],
                              phantom=None if ref.phantom is None else ref.phantom[:n],
                              dq=None if ref.dq is None else ref.dq[:n])
        return self.replace(
            data=self.data.data[:n], schedule=schedule, reference=ref,
            uncertainty=None if unc is None else unc.array[:n],
            dq=None if self.dq is None else self.dq[:n],
            phantom=None if self.phantom is None else self.phantom[:n])

    def to_ccddata(self):
        """The 2-D image as `~astropy.nddata.CCDData` with the header as ``meta``."""
        if self.is_ramp:
            raise ValueError("to_ccddata needs a 2-D image; fit the ramps first (fit_ramp)")
        d = self.data
        return CCDData(d.data, unit=d.unit, uncertainty=d.uncertainty, mask=d.mask,
                       meta=self.header.copy())
