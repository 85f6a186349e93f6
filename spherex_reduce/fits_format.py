"""Read and write exposures as FITS.

Layout (extension names):

``PRIMARY``
    No data; the readout keywords (`ReadoutSchedule.to_header`), ``BUNIT``,
    ``ORDER`` (``READOUT`` or ``PHYSICAL``) and the provenance of every step.
``SCI``
    Pixels: ramps ``(frames, reads, columns)`` or a 2-D image, in the order
    ``ORDER`` says.
``ERR``, ``DQ``
    Standard deviation and data-quality flags (`spherex_reduce.dq`), if any.
``PHANTOM``
    Phantom values, ``(frames, reads, channels)`` or ``(reads, channels)``.
``READOUT``
    One row per read of a frame: ``row kind start time``; cross-checked
    against the header keywords on read.
``REFPIX``, ``REFPHANT``, ``REFDQ``, ``REFREADS``
    Reference reads kept aside by ``unchop`` (pixels, phantoms, flags, and a
    table ``read row time``).

Any other table extension holds a table recorded by a step (e.g. ``REFOFFS``).

Writes go to a temporary file in the target directory, with FITS checksums,
and are renamed into place only when complete; an existing file is kept unless
``overwrite=True``.
"""

import mmap
import os
import tempfile
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import StdDevUncertainty
from astropy.table import Table

from .errors import FormatError
from .exposure import Exposure, ReferenceReads, expected_shape
from .schedule import ReadoutSchedule

__all__ = ["FrameReader", "atomic_output", "read", "write"]

_RESERVED = {"PRIMARY", "SCI", "ERR", "DQ", "PHANTOM", "READOUT", "REFPIX", "REFPHANT", "REFDQ",
             "REFREADS"}


class atomic_output:
    """Context manager giving a temporary path that is renamed to ``path`` on success.

    Refuses to start if ``path`` exists and ``overwrite`` is False, so nothing
    is computed only to be thrown away.  On error the temporary file is removed
    and an existing ``path`` is left untouched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_output(out) as tmp:
    ...     _ = tmp.write_text("done")
    >>> out.read_text()
    'done'
    """

    def __init__(self, path, overwrite=False):
        self.path = Path(path)
        self.overwrite = overwrite
        if self.path.exists() and not overwrite:
            raise FileExistsError(
                f"{self.path} exists; not overwriting it (pass overwrite=True / --overwrite)"
            )
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"output directory {self.path.parent} does not exist")

    def __enter__(self):
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp",
                                   dir=self.path.parent)
        os.close(fd)
        os.unlink(tmp)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            if self.path.exists() and not self.overwrite:
                self.tmp.unlink(missing_ok=True)
                raise FileExistsError(f"{self.path} appeared while writing; not overwriting it")
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return False


def _image(data, name, unit=None):
    hdu = fits.ImageHDU(np.asarray(data), name=name)
    if unit is not None:
        hdu.header["BUNIT"] = _unit_str(unit)
    return hdu


def write(exposure, path, overwrite=False):
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

    Returns
    -------
    path : `pathlib.Path`

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
    header = exposure.schedule.to_header(exposure.header)
    header["ORDER"] = (exposure.order.upper(), "row order of SCI: READOUT or PHYSICAL")
    unit = exposure.unit or u.dimensionless_unscaled
    header["BUNIT"] = (_unit_str(unit), "unit of SCI and ERR")
    hdus = [fits.PrimaryHDU(header=header), _image(exposure.data.data, "SCI", unit)]
    unc = exposure.data.uncertainty
    if unc is not None:
        if not isinstance(unc, StdDevUncertainty):  # (converting costs two passes)
            unc = unc.represent_as(StdDevUncertainty)
        hdus.append(_image(unc.array, "ERR", unit))
    dq = exposure.dq
    if dq is not None:
        hdus.append(_image(dq.astype(np.int32), "DQ"))  # unsigned would need BZERO: no memmap
    if exposure.phantom is not None:
        hdus.append(_image(exposure.phantom, "PHANTOM", unit))
    hdus.append(_table_hdu(exposure.schedule.to_table(), "READOUT"))
    ref = exposure.reference
    if ref is not None:
        hdus.append(_image(ref.data, "REFPIX", unit))
        if ref.phantom is not None:
            hdus.append(_image(ref.phantom, "REFPHANT", unit))
        if ref.dq is not None:
            hdus.append(_image(np.asarray(ref.dq).astype(np.int32), "REFDQ"))
        times = exposure.schedule.start_times[ref.reads]
        hdus.append(_table_hdu(Table({"read": ref.reads, "row": ref.rows, "time": times}),
                               "REFREADS"))
    for name, table in exposure.tables.items():
        if name.upper() in _RESERVED:
            raise ValueError(f"table name {name!r} is reserved for the format")
        hdus.append(_table_hdu(table, name.upper()))
    with atomic_output(path, overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp, checksum=True)
    return path


def _table_hdu(table, name):
    t = Table(table, copy=False)
    t.meta = {k: v for k, v in t.meta.items() if k != "comments"}
    hdu = fits.table_to_hdu(t)
    hdu.name = name
    return hdu


def _open(path, memmap):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    try:
        return fits.open(path, memmap=memmap, mode="readonly")
    except OSError as exc:
        raise FormatError(f"{path} is not a readable FITS file: {exc}") from exc


def _describe(hdul, path, supplied):
    """Validate an open file; return what every reader needs (no pixel data loaded)."""
    names = [h.name for h in hdul]
    header = hdul[0].header.copy()
    if "SCI" in names:
        sci = hdul["SCI"]
    elif hdul[0].header.get("NAXIS", 0) > 0:
        sci = hdul[0]
    else:
        raise FormatError(f"{path} has no SCI extension and no primary data")
    shape = tuple(sci.header[f"NAXIS{i}"] for i in range(sci.header["NAXIS"], 0, -1))
    table = Table.read(hdul["READOUT"]) if "READOUT" in names else None
    schedule = ReadoutSchedule.from_header(header, table, **supplied)
    order = str(header.get("ORDER", "READOUT")).strip().lower()
    if order not in ("readout", "physical"):
        raise FormatError(f"keyword ORDER must be READOUT or PHYSICAL, got {order!r}")
    _check_shape(shape, schedule, order, "SCI")
    if "PHANTOM" in names:
        pshape = tuple(hdul["PHANTOM"].shape)
        frames_reads = expected_shape(schedule, order, len(shape) == 3)[:-1]
        expected = (*frames_reads, schedule.geometry.nchannels)
        if pshape != expected:
            raise FormatError(
                f"PHANTOM has shape {pshape}, the schedule gives {expected} "
                "(frames, reads, channels): check NFRAMES, NCHAN and the read order keywords"
            )
    elif schedule.phantom_reads and order == "readout":
        raise FormatError(f"NPHANT={schedule.phantom_reads} but the file has no PHANTOM extension")
    unit = _unit(header.get("BUNIT", sci.header.get("BUNIT", "electron")))
    for key in ("CHECKSUM", "DATASUM", "ORDER"):
        header.remove(key, ignore_missing=True)
    return {"names": names, "header": header, "sci": sci, "shape": shape,
            "schedule": schedule, "order": order, "unit": unit}


def _readonly(*arrays):
    for array in arrays:
        if array is not None:  # the file's own pages: a step must never write into them
            array.setflags(write=False)


def read(path, **supplied):
    """Read an exposure written by `write` (or raw data from other electronics).

    Parameters
    ----------
    path : str or `pathlib.Path`
        FITS file.  It is opened read-only (memory-mapped) and never changed;
        the arrays of the returned exposure are read-only.
    **supplied
        Geometry and readout parameters (``nrows``, ``skip``, ``frame_time``
        ...) used where the header lacks them, e.g. from a pipeline config's
        ``geometry:`` and ``readout:`` sections.

    Returns
    -------
    exposure : `Exposure`

    Raises
    ------
    FormatError
        The file lacks ``SCI``, a keyword is missing, or the header, the
        ``READOUT`` table and the array shapes disagree; the message names the
        keyword or dimension.
    """
    with _open(path, memmap=True) as hdul:
        d = _describe(hdul, path, supplied)
        names = d["names"]
        data = d["sci"].data
        err = hdul["ERR"].data if "ERR" in names else None
        mask = hdul["DQ"].data if "DQ" in names else None
        phantom = hdul["PHANTOM"].data if "PHANTOM" in names else None
        reference = None
        if "REFPIX" in names:
            rt = Table.read(hdul["REFREADS"])
            reference = ReferenceReads(
                data=hdul["REFPIX"].data, rows=np.asarray(rt["row"]), reads=np.asarray(rt["read"]),
                phantom=hdul["REFPHANT"].data if "REFPHANT" in names else None,
                dq=(hdul["REFDQ"].data.astype(np.uint16) if "REFDQ" in names else None),
            )
            _readonly(reference.data, reference.phantom)
        tables = {
            h.name: Table.read(h)
            for h in hdul
            if isinstance(h, fits.BinTableHDU) and h.name not in _RESERVED
        }
    _readonly(data, err, mask, phantom)
    return Exposure.from_arrays(data, d["schedule"], unit=d["unit"], uncertainty=err, mask=mask,
                                phantom=phantom, header=d["header"], order=d["order"],
                                reference=reference, tables=tables)


class FrameReader:
    """Read a raw ramp file one frame at a time, without mapping the whole file.

    Used by `~spherex_reduce.Pipeline` to reduce ramps frame by frame in
    memory near one frame.  Use as a context manager.

    Parameters
    ----------
    path : str or `pathlib.Path`
        A file of ramps ``(frames, reads, columns)`` in readout order.
    **supplied
        As for `read`.

    Attributes
    ----------
    schedule : `ReadoutSchedule`
        The full exposure's schedule.
    header : `astropy.io.fits.Header`
    """

    def __init__(self, path, **supplied):
        self.path = Path(path)
        self._map = None
        self._hdul = _open(path, memmap=False)
        try:
            d = _describe(self._hdul, path, supplied)
            if len(d["shape"]) != 3 or d["order"] != "readout" or "DQ" in d["names"] \
                    or "ERR" in d["names"]:
                raise FormatError(f"{path} is not a raw ramp file in readout order")
            self._d = d
            self.schedule, self.header, self.unit = d["schedule"], d["header"], d["unit"]
            self._phantom = (np.asarray(self._hdul["PHANTOM"].data)
                             if "PHANTOM" in d["names"] else None)
            self._tables = {h.name: Table.read(h) for h in self._hdul
                            if isinstance(h, fits.BinTableHDU) and h.name not in _RESERVED}
            self._map = _map_frames(d["sci"], path)
        except Exception:
            self._hdul.close()
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self):
        """Close the file."""
        if self._map is not None:
            mm, _, _, fd = self._map
            os.close(fd)
            try:
                mm.close()
            except BufferError:  # a frame view is still alive (e.g. in a traceback):
                pass  # the map closes when it is collected
            self._map = None
        self._hdul.close()

    @property
    def nframes(self):
        """Number of frames in the file."""
        return self.schedule.nframes

    def frame(self, k):
        """Frame ``k`` as a one-frame `Exposure` (schedule with ``nframes=1``)."""
        if self._map is None:  # scaled or unusual data: astropy reads the section
            data = np.asarray(self._d["sci"].section[k : k + 1])
        else:
            data = self._mapped_frame(k)
        phantom = None if self._phantom is None else self._phantom[k : k + 1]
        return Exposure.from_arrays(data, self.schedule.replace(nframes=1), unit=self.unit,
                                    phantom=phantom, header=self.header, tables=self._tables)


    @property
    def has_phantom(self):
        """Whether the file has phantom values."""
        return self._phantom is not None

    def fusable(self):
        """Whether `raw` gives floating-point pixels and phantom values (what the fused
        path needs)."""
        dtype = self._map[2] if self._map is not None else None
        return (dtype is not None and dtype.kind == "f"
                and (self._phantom is None or self._phantom.dtype.kind == "f"))

    def raw(self, k):
        """Frame ``k`` as it is in the file, without copying it.

        Returns ``(pixels, phantom, release)``: pixels ``(reads, columns)``,
        possibly big-endian and read-only (a view of the memory-mapped file);
        phantom values ``(reads, channels)`` or None; and ``release()``, to
        call once the pixels have been used (frees the file's pages in this
        process).  Only for files whose data are not scaled (`fusable`).
        """
        mm, offset, dtype, _ = self._map
        shape = self._d["shape"][1:]
        count = int(np.prod(shape))
        start = offset + k * count * dtype.itemsize
        view = np.frombuffer(mm, dtype=dtype, count=count, offset=start).reshape(shape)
        phantom = None if self._phantom is None else self._phantom[k]
        return view, phantom, lambda: self._release(start, count * dtype.itemsize)

    def reads(self, k, first, stop):
        """Reads ``first:stop`` of frame ``k`` as they are in the file (a copy).

        Read with ``pread``: no page of the memory map is touched, and several
        threads may read at once.  Only for files whose data are not scaled
        (`fusable`).

        Returns
        -------
        `numpy.ndarray`
            ``(stop - first, columns)``, possibly big-endian.
        """
        mm, offset, dtype, fd = self._map
        nreads, ncols = self._d["shape"][1:]
        pos = offset + (k * nreads + first) * ncols * dtype.itemsize
        if not hasattr(os, "preadv"):  # (Windows) from the map, then release its pages
            count = (stop - first) * ncols
            buf = np.frombuffer(mm, dtype, count=count, offset=pos).reshape(-1, ncols).copy()
            self._release(pos, count * dtype.itemsize)
            return buf
        buf = np.empty((stop - first, ncols), dtype)
        view = memoryview(buf).cast("B")
        done = 0
        while done < view.nbytes:
            got = os.preadv(fd, [view[done:]], pos + done)
            if got <= 0:
                raise FormatError(f"{self.path}: the file ends inside frame {k}")
            done += got
        return buf

    def _release(self, start, nbytes):
        mm = self._map[0] if self._map is not None else None
        if mm is None or not hasattr(mm, "madvise"):
            return
        page = start - start % mmap.PAGESIZE
        length = (start + nbytes - page) // mmap.PAGESIZE * mmap.PAGESIZE
        if length:
            mm.madvise(mmap.MADV_DONTNEED, page, length)

    def _mapped_frame(self, k):
        """Frame ``k`` copied from the mapped file into a native-endian array.

        The file's pages are then released from this process (``MADV_DONTNEED``):
        they stay in the page cache, but the resident memory stays near one frame.
        """
        view, _, release = self.raw(k)
        data = view.astype(view.dtype.newbyteorder("="))
        del view
        release()
        return data[None]


_FITS_DTYPES = {8: "u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}


def _map_frames(hdu, path):
    """``(mmap, data offset, dtype, file descriptor)`` of an unscaled image HDU, or None
    (read by sections).  The descriptor (kept open, the map's own file) serves `pread`.

    Reading frames from a memory map and converting them to native byte order
    in one pass is ~2x faster than astropy's section reads followed by
    arithmetic on big-endian arrays.
    """
    h = hdu.header
    dtype = _FITS_DTYPES.get(h.get("BITPIX"))
    if (dtype is None or h.get("BSCALE", 1) != 1 or h.get("BZERO", 0) != 0
            or isinstance(hdu, fits.CompImageHDU)):  # tile-compressed: astropy decompresses
        return None
    dtype = np.dtype(dtype)
    start = hdu.fileinfo()["datLoc"]
    nbytes = int(np.prod(hdu.shape)) * dtype.itemsize
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
    try:
        # a plain FITS file on disk (not .gz, .bz2 or .zip, which astropy unpacks)
        if os.read(fd, 9) != b"SIMPLE  =" or os.fstat(fd).st_size < start + nbytes:
            os.close(fd)
            return None
        mm = mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
    except BaseException:
        os.close(fd)
        raise
    return mm, start, dtype, fd


def _unit_str(unit):
    """Units in astropy's generic format ('electron / s'): 'electron' is not a FITS unit."""
    return "" if unit == u.one else unit.to_string()


def _unit(value):
    try:
        return u.Unit(str(value).strip(), parse_strict="raise")
    except ValueError as exc:
        raise FormatError(f"keyword BUNIT={value!r} is not a unit astropy understands") from exc


def _check_shape(shape, schedule, order, name):
    if len(shape) not in (2, 3):
        raise FormatError(f"{name} must be 2-D or 3-D, got shape {shape}")
    expected = expected_shape(schedule, order, len(shape) == 3)
    if shape == expected:
        return
    labels = ["frames (NFRAMES)"] if len(shape) == 3 else []
    labels += ["reads (NROWS, REFBORD, NREFRD, REFMODE)" if order == "readout" else
               "rows (NROWS)", "columns (NCOLS)"]
    for axis, (got, want, label) in enumerate(zip(shape, expected, labels, strict=True)):
        if got != want:
            raise FormatError(
                f"{name} has shape {shape} but the header keywords give {expected}: axis {axis}, "
                f"{label}, is {got}, expected {want}"
            )
