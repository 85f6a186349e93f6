"""Write exposures as FITS files: whole (`write`) or streamed frame by frame (`write_frames`).

Both write the layout of `spherex_reduce.io.layout`, the same bytes for the
same exposure (the times in the comments of ``CHECKSUM`` and ``DATASUM``
aside), to a temporary file in the target directory, with FITS checksums and
``NEXTEND`` (the number of extensions) in the primary header; the file is
renamed into place only when complete, and an existing file is kept unless
``overwrite=True``.
"""

import collections
import datetime
import io
import tempfile
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.io.fits.verify import VerifyWarning
from astropy.nddata import StdDevUncertainty
from astropy.table import Table

from ..core.channel_layout import check_stored_order
from .atomic import atomic_output
from .fits_structure import FITS_BLOCK, DataSum, checksum_text
from .header_text import header_text
from .layout import RESERVED, unit_string

__all__ = ["table_hdu", "write", "write_frames"]


def _image(data, name, unit=None):
    hdu = fits.ImageHDU(data, name=name)
    if unit is not None:
        hdu.header["BUNIT"] = unit_string(unit)
    return hdu


def _readout_cards(schedule, order):
    """The readout keywords and ``ORDER``, as the primary header has them, for ``SCI``'s own
    header: tools that read one extension (astropy's ``CCDData.read(path, hdu='SCI')``,
    ccdproc) see how the image was read.  `read` takes them from the primary header."""
    header = schedule.to_header()
    header["ORDER"] = (order.upper(), "row order of SCI: READOUT or PHYSICAL")
    return header


def _stored(values, dtype):
    """``values`` as an image stores them: floating point as ``dtype`` (float32 unless it
    cannot hold a finite value, which keeps the image float64: never an inf), integers as
    they are."""
    values = np.asarray(values)
    if values.dtype.kind != "f" or values.dtype == dtype:
        return values
    with np.errstate(over="ignore"):
        out = values.astype(dtype)
    if np.isinf(out).any() and np.any(np.isinf(out) & np.isfinite(values)):
        return values.astype(np.float64)  # beyond float32's 3.4e38: at full precision
    return out


def _primary(schedule, header, order, unit, nextend):
    """The primary HDU: readout keywords, ``ORDER``, ``BUNIT`` and ``NEXTEND`` after
    ``header``'s cards, and ``EXTEND`` where astropy puts it when extensions follow."""
    header = schedule.to_header(header)
    header["ORDER"] = (order.upper(), "row order of SCI: READOUT or PHYSICAL")
    header["BUNIT"] = (unit_string(unit), "unit of SCI and ERR")
    # a file cut at an HDU boundary is still valid FITS: the count tells it is not whole
    header["NEXTEND"] = (nextend, "number of extensions")
    hdu = fits.PrimaryHDU(header=header)
    if "EXTEND" not in hdu.header:
        hdu.header.set("EXTEND", True, after="NAXIS")
    return hdu


def table_hdu(table, name):
    """A binary-table HDU named ``name`` of ``table`` (not changed), as every file holds its
    tables: each column of its own type (``int8``, which FITS lacks, as ``int16``), a unit
    FITS lacks (``electron``) in astropy's generic form, text metadata as header cards.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from spherex_reduce.io.fits_write import table_hdu
    >>> table_hdu(Table({"n": np.array([2], np.int8)}), "T").header["TFORM1"]
    'I'
    """
    t = table.copy(copy_data=False)
    for col in list(t.itercols()):
        if col.dtype == np.int8:  # FITS has no signed byte (astropy writes it as logical:
            # a 2 read back True); int16 keeps every value, and astropy reads it as integers
            t.replace_column(col.info.name, col.astype(np.int16))
    generic = {}  # e.g. electron, which FITS lacks: TUNIT in astropy's generic form
    for i, col in enumerate(t.itercols(), start=1):
        if col.unit is not None and not _fits_unit(col.unit):
            generic[i] = col.unit.to_string()
            col.unit = None
    # text (e.g. a noise file's name) as a header card can hold it
    t.meta = {k: header_text(v) if isinstance(v, str) else v for k, v in t.meta.items()
              if k != "comments"}
    with warnings.catch_warnings():  # a longer meta key is a HIERARCH card, read back as given
        warnings.filterwarnings("ignore", "Keyword name .* HIERARCH card", VerifyWarning)
        hdu = fits.table_to_hdu(t)
    for i, text in generic.items():  # read back by file_tables (astropy: a UnitsWarning)
        hdu.header[f"TUNIT{i}"] = text
    hdu.name = name
    return hdu


def _fits_unit(unit):
    """Whether ``unit`` has a FITS form (``electron`` has none: the FITS standard lacks it)."""
    try:
        unit.to_string("fits")
    except ValueError:
        return False
    return True


def write(exposure, path, overwrite=False, images=None, dtype="float32"):
    """Write an `Exposure` to a FITS file, atomically and with checksums.

    Parameters
    ----------
    exposure : `Exposure`
        Raw (readout order) or reduced (physical order) exposure.
    path : str or `pathlib.Path`
        Output file.
    overwrite : bool
        Replace an existing file.  Without it an existing file is kept and
        `FileExistsError` is raised.
    images : dict of str to array or `~astropy.units.Quantity`, optional
        More image extensions, by name, written after the exposure's
        own and before its tables (e.g. the per-integration slopes
        ``INTSLOPE`` of `~spherex_reduce.reduce_integrations`); a
        `~astropy.units.Quantity` gets its unit as ``BUNIT``.  `read`
        ignores them.
    dtype : {'float32', 'float64'}
        Type of the stored floating-point images (``SCI``, ``ERR``,
        ``PHANTOM``, ``REFPIX``, ``REFPHANT`` and ``images``); integers are
        stored as they are, flags as 32-bit integers.  float32, as JWST
        stores its images: a reduction is accumulated in float64, but its
        values' noise is far above float32's relative spacing (6e-8), and
        float32 halves the file (a value float32 cannot hold keeps its
        image float64).

    Returns
    -------
    path : `pathlib.Path`

    Raises
    ------
    ValueError
        A table or image name is reserved for the format (`spherex_reduce.io.layout`)
        or given twice.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, read, write
    >>> s = ReadoutSchedule(DetectorGeometry(12, 8, 2, ref_border=2), skip=3, ref_reads=4,
    ...                     phantom_reads=2, nframes=2)
    >>> e = Exposure.from_arrays(np.ones((2, s.n_reads, 8), "f4"), s,
    ...                          phantom=np.zeros((2, s.n_reads, 2), "f4"))
    >>> out = write(e, pathlib.Path(tempfile.mkdtemp()) / "raw.fits")
    >>> read(out).schedule == s
    True
    """
    path = Path(path)
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype!r}")
    unit = exposure.unit or u.dimensionless_unscaled
    layout = _stored_layout(exposure.schedule, exposure.order)
    hdus = [_image(_stored(layout.to_stored(exposure.data.data), dtype), "SCI", unit)]
    hdus[0].header.extend(_readout_cards(exposure.schedule, exposure.order))
    unc = exposure.data.uncertainty
    if unc is not None:
        if not isinstance(unc, StdDevUncertainty):  # (converting costs two passes)
            unc = unc.represent_as(StdDevUncertainty)
        hdus.append(_image(_stored(layout.to_stored(unc.array), dtype), "ERR", unit))
    dq = exposure.dq
    if dq is not None:  # int32: the same 32 bits as JWST's uint32, read as stored (no BZERO)
        hdus.append(_image(layout.to_stored(dq.astype(np.int32)), "DQ"))
    if exposure.phantom is not None:
        hdus.append(_image(_stored(exposure.phantom, dtype), "PHANTOM", unit))
    hdus.append(table_hdu(exposure.schedule.to_table(), "READOUT"))
    ref = exposure.reference
    if ref is not None:
        hdus.append(_image(_stored(ref.data, dtype), "REFPIX", unit))
        if ref.phantom is not None:
            hdus.append(_image(_stored(ref.phantom, dtype), "REFPHANT", unit))
        if ref.dq is not None:
            hdus.append(_image(np.asarray(ref.dq).astype(np.int32), "REFDQ"))
        times = exposure.schedule.start_times[ref.reads]
        hdus.append(table_hdu(Table({"read": ref.reads, "row": ref.rows, "time": times}),
                               "REFREADS"))
    taken = set(RESERVED)
    for name, array in (images or {}).items():
        values, extra_unit = _value_unit(array)
        if np.shape(values)[-2:] == layout.frame_shape:  # an image of the array: stored
            values = layout.to_stored(values)
        hdus.append(_image(_stored(values, dtype), _extra(name, taken, "image"), extra_unit))
    for name, table in exposure.tables.items():
        hdus.append(table_hdu(table, _extra(name, taken, "table")))
    hdus.insert(0, _primary(exposure.schedule, exposure.header, exposure.order, unit, len(hdus)))
    with atomic_output(path, overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp, checksum=True)
    return path


def _stored_layout(schedule, order):
    """The `~spherex_reduce.core.channel_layout.ChannelLayout` pixels of ``schedule`` in
    ``order`` are written with (checked: readout-order ramps of a layout that is not
    ``columns`` must read each row once, in order)."""
    check_stored_order(schedule, order)
    return schedule.geometry.layout


def _extra(name, taken, what):
    """``name`` in upper case, if neither the format nor another extension uses it."""
    upper = name.upper()
    if upper in taken:
        raise ValueError(f"{what} name {name!r} is reserved for the format or already used")
    taken.add(upper)
    return upper


def _value_unit(array):
    """``(values, unit)`` of an extra image: a Quantity's unit, else None."""
    if isinstance(array, u.Quantity):
        return array.value, array.unit
    return np.asarray(array), None


def write_frames(frames, path, schedule, *, header=None, unit=u.electron, dtype="float32",
                 overwrite=False):
    """Write raw ramps given one frame at a time, in memory near one frame.

    The file is the one `write` gives for the whole exposure (``SCI``,
    ``PHANTOM`` if the schedule has phantom reads, ``READOUT``), written as
    the frames come: each frame is converted to big-endian, added to the
    running ``DATASUM`` and written by a background thread while the next
    one is made.  The phantom values wait in a temporary file in the output
    directory until ``SCI`` is complete.  Nothing is left at ``path`` unless
    every frame was written.

    Parameters
    ----------
    frames : iterable of (`numpy.ndarray`, `numpy.ndarray` or None)
        ``schedule.nframes`` pairs: pixels ``(reads, columns)`` in readout
        order and phantom values ``(reads, channels)`` (None without phantom
        reads), in ``unit``.  The pixel arrays are consumed (byte-swapped in
        place when they already have ``dtype``).
    path : str or `pathlib.Path`
        Output file.
    schedule : `ReadoutSchedule`
        The exposure's schedule; its keywords go in the primary header.
    header : `astropy.io.fits.Header`, optional
        More cards for the primary header (not changed).
    unit : `astropy.units.Unit`
        Unit of the values (``BUNIT``).
    dtype : {'float32', 'float64'}
        Type of the stored values.
    overwrite : bool
        Replace an existing file (checked before the first frame is taken).

    Returns
    -------
    path : `pathlib.Path`

    Raises
    ------
    ValueError
        A frame's shape is not the schedule's, or there are not
        ``schedule.nframes`` frames.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule, read
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=0), ref_mode="none",
    ...                     phantom_reads=0, nframes=3)
    >>> frames = ((np.full((8, 8), k, "f4"), None) for k in range(3))
    >>> out = write_frames(frames, pathlib.Path(tempfile.mkdtemp()) / "raw.fits", s)
    >>> read(out).data.data[:, 0, 0].tolist()
    [0.0, 1.0, 2.0]
    """
    out = atomic_output(path, overwrite)  # refuse before the first frame is made
    stored = np.dtype(dtype).newbyteorder(">")
    if stored.kind != "f":
        raise ValueError(f"dtype must be float32 or float64, got {dtype!r}")
    nframes, nreads = schedule.nframes, schedule.n_reads
    ncols, nchannels = schedule.geometry.ncols, schedule.geometry.nchannels
    layout = _stored_layout(schedule, "readout")
    image = (nreads, ncols) if layout.identity else (layout.nrows, layout.ncols)
    primary = _primary(schedule, header, "readout", unit, 2 + bool(schedule.phantom_reads))
    with out as tmp, open(tmp, "wb") as f, tempfile.TemporaryFile(dir=tmp.parent) as spill:
        f.write(_hdu_bytes(primary))
        sci = _StreamedImage(f, "SCI", stored, (nframes, *image), unit,
                             _readout_cards(schedule, "readout"))
        count = 0
        try:
            for count, (pixels, phantom) in enumerate(frames, 1):
                if count > nframes:
                    raise ValueError(f"more frames than the schedule's {nframes}")
                sci.write(layout.to_stored(_checked(pixels, (nreads, ncols), "pixels")))
                if schedule.phantom_reads:
                    raw = np.ascontiguousarray(_checked(phantom, (nreads, nchannels), "phantom"),
                                               dtype=stored)
                    spill.write(memoryview(raw).cast("B"))
        finally:
            sci.drain()
        if count != nframes:
            raise ValueError(f"{count} frames given, the schedule has {nframes}")
        sci.close()
        if schedule.phantom_reads:
            phantom = _StreamedImage(f, "PHANTOM", stored, (nframes, nreads, nchannels), unit)
            spill.seek(0)
            while chunk := spill.read(1 << 24):
                phantom.write_stored(chunk)
            phantom.close()
        f.write(_hdu_bytes(table_hdu(schedule.to_table(), "READOUT")))
    return out.path


def _checked(array, shape, what):
    if array is None or np.shape(array) != shape:
        got = None if array is None else np.shape(array)
        raise ValueError(f"frame {what} have shape {got}, the schedule gives {shape}")
    return array


def _hdu_bytes(hdu):
    """The bytes of one HDU, with checksums, as `astropy.io.fits.HDUList.writeto` writes it."""
    buf = io.BytesIO()
    if isinstance(hdu, fits.PrimaryHDU):
        fits.HDUList([hdu]).writeto(buf, checksum=True)
        return buf.getvalue()
    primary = fits.PrimaryHDU()
    fits.HDUList([primary, hdu]).writeto(buf, checksum=True)
    return buf.getvalue()[len(primary.header.tostring()):]


class _StreamedImage:
    """An image extension written in pieces; ``DATASUM`` and ``CHECKSUM`` filled in by
    `close`.  Its header is the one astropy makes for an image of that type and shape."""

    def __init__(self, f, name, dtype, shape, unit, cards=None):
        stand_in = np.broadcast_to(np.zeros((), dtype), shape)  # no memory: the header only
        self.header = _image(stand_in, name, unit).header.copy()
        if cards is not None:
            self.header.extend(cards)
        self.header["CHECKSUM"] = ("0" * 16, "HDU checksum updated")
        self.header["DATASUM"] = ("0", "data unit checksum updated")
        self.f, self.dtype = f, dtype
        self.pos = f.tell()
        self.hbytes = self.header.tostring().encode("ascii")
        f.write(self.hbytes)
        self.sum = DataSum()
        self.nbytes = 0
        self._io = None
        self._pending = collections.deque()

    def write(self, arr):
        """Append ``arr`` (native floating point; byte-swapped in place, so it is consumed).

        The disk write runs in a background thread (at most two pieces in
        flight), overlapping the making of the next one.
        """
        raw = np.ascontiguousarray(arr, dtype=self.dtype.newbyteorder("="))
        raw.byteswap(inplace=True)
        self.write_stored(memoryview(raw.view(self.dtype)).cast("B"))

    def write_stored(self, raw):
        """Append bytes as they are stored (big-endian, whole values)."""
        self.sum.add(raw)
        if self._io is None:
            self._io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sxr-fits")
        self._pending.append(self._io.submit(self.f.write, raw))
        while len(self._pending) > 2:
            self._pending.popleft().result()
        self.nbytes += len(raw)

    def drain(self):
        """Wait for the writes in flight (and stop the thread)."""
        while self._pending:
            self._pending.popleft().result()
        if self._io is not None:
            self._io.shutdown()
            self._io = None

    def close(self):
        """Pad the data to a whole block, then fill in the checksums of the header."""
        self.drain()
        f = self.f
        f.write(b"\0" * ((-self.nbytes) % FITS_BLOCK))
        end = f.tell()
        when = datetime.datetime.now().isoformat()[:19]  # as astropy stamps its checksums
        datasum = self.sum.value
        self.header["DATASUM"] = (str(datasum), f"data unit checksum updated {when}")
        self.header["CHECKSUM"] = ("0" * 16, f"HDU checksum updated {when}")
        self.header["CHECKSUM"] = checksum_text(self.header.tostring().encode("ascii"),
                                                 datasum)
        new = self.header.tostring().encode("ascii")
        if len(new) != len(self.hbytes):  # pragma: no cover - card layout is fixed
            raise RuntimeError("header changed size while adding checksums")
        f.seek(self.pos)
        f.write(new)
        f.seek(end)
