"""Read a raw ramp file one frame (or a band of reads) at a time."""

import mmap
import os
from pathlib import Path

import numpy as np
from astropy.io import fits

from ...core.errors import FormatError
from ...core.exposure import Exposure
from ..input import InputOptions, apply_gain, apply_input
from .description import describe, file_tables, image_shape
from .fits_read import Closing, exposure_from_hdul, open_fits
from .pixels import FITS_DTYPES, FLOAT_FOR, physical, scaling, to_physical, unpacking
from .stable_file import pread_into

__all__ = ["FrameReader", "RampReader", "consecutive_runs"]


class RampReader(Closing):
    """A reader of raw ramps that a `~spherex_reduce.io.sources.FileSource` reads bands from.

    It offers ``schedule``, ``header``, ``unit``, ``tables``, ``phantom``
    (``(frames, reads, channels)`` or None), ``has_phantom``, ``stored_dtype``,
    ``readable_in_bands()``, ``reads(k, first, stop)`` (reads of frame ``k``),
    ``scale(values)`` (the gain of ``input:``, in place), ``exposure()`` (the
    whole ramp) and ``close()``; optionally ``reads_into(out, runs)`` (runs of reads
    of every frame straight into ``out``, or False: `FrameReader.reads_into`).  A
    reader of a new layout subclasses it, and `~spherex_reduce.io.sources.open_input`
    then takes it as an open reader.
    """


class FrameReader(RampReader):
    """Read a raw ramp file by reads of every frame (or by frames), never all of it at once.

    The executor (`spherex_reduce.io.sources.FileSource`) reads bands of rows of
    every frame with `reads_into` (or `reads`; ``pread``), so a `~spherex_reduce.Pipeline`
    reduces a file in memory near the output plus a few bands.  Use as a
    context manager.

    Parameters
    ----------
    path : str or `pathlib.Path`
        A file of ramps ``(frames, reads, columns)`` in readout order.  It is
        checked as by `~spherex_reduce.io.read` (structure, checksums, keywords) when opened.
        Scaled integer data come as floating point frames (`frame`).
    verify_checksum : bool, optional
        As for `~spherex_reduce.io.read`.
    dq_bits : int, optional
        Accepted as by `~spherex_reduce.io.read`, unused: a file with a
        ``DQ`` (or ``ERR``) is not a raw ramp file to this reader (read it
        whole with `~spherex_reduce.io.read`).
    input : dict or `~spherex_reduce.io.input.InputOptions`, optional
        As for `~spherex_reduce.io.read`: frames dropped at the start of
        every ramp are never read (frame ``k`` is the file's ``k + dropped``)
        and `reads` gives the file's values, which `scale` multiplies by the
        gain as `~spherex_reduce.io.read` does.
    **supplied
        As for `~spherex_reduce.io.read`.

    Attributes
    ----------
    schedule : `ReadoutSchedule`
        The schedule of the frames served (the file's, less the dropped frames).
    header : `astropy.io.fits.Header`
    """

    def __init__(self, path, verify_checksum=None, dq_bits=None, input=None, **supplied):
        self.path = Path(path)
        self._map = self._stable = None
        options = InputOptions.from_config(input)
        if options.reads is not None:
            raise FormatError(f"{path}: input.reads is {options.reads}: FrameReader reads one "
                              "3-D SCI; open the file with open_input (or ExtensionReads)")
        self._hdul, bad, self._stable = open_fits(path, verify=verify_checksum)
        plain = self._stable is not None
        try:
            with unpacking(path):  # astropy unpacks a compressed file lazily
                d = describe(self._hdul, path, supplied, bad, options)
                if len(d.shape) != 3 or d.order != "readout" or "DQ" in d.names \
                        or "ERR" in d.names:
                    raise FormatError(f"{path} is not a raw ramp file in readout order")
                self._d = d
                self._layout = d.schedule.geometry.layout
                self._stored_shape = image_shape(d.sci)[1:]  # rows, columns as stored
                self.schedule, self.header, self.unit = d.kept, d.header, d.unit
                self._drop, self._gain = d.drop, d.gain
                phantom = (np.asarray(physical(self._hdul["PHANTOM"], path, self._stable))
                           if "PHANTOM" in d.names else None)
                self._phantom = apply_input(d, None, None, None, phantom)[3]
                self._scale = scaling(d.sci, path)
                self._tables = file_tables(self._hdul, path)
                self._map = map_frames(d.sci, path) if plain else None
        except Exception:
            self.close()
            raise
        self._warned = set()  # one warning per override, also if read whole later
        d.warn(self._warned)
        #: tables of the file (e.g. ``PROVENANCE``), phantom values ``(frames, reads,
        #: channels)`` or None, and the type the pixels are stored as
        self.tables, self.phantom = self._tables, self._phantom
        self.stored_dtype = None if self._map is None else self._map[2]
        self._opened = (bad, supplied, options)

    def exposure(self):
        """The whole file as the `Exposure` `~spherex_reduce.io.read` gives, from the file
        already open and checked (not opened or verified again)."""
        bad, supplied, options = self._opened
        return exposure_from_hdul(self._hdul, self.path, bad, self._stable, supplied,
                                  options=options, warned=self._warned)

    def scale(self, values):
        """``values`` (reads ``(..., columns)`` as `reads` gives them) multiplied in place
        by the gain of ``input:`` (nothing if none), as `~spherex_reduce.io.read` does."""
        return apply_gain(values, self._gain, self.schedule.geometry)

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
        if self._stable is not None:
            self._stable.close()
            self._stable = None
        self._hdul.close()

    @property
    def nframes(self):
        """Number of frames in the file."""
        return self.schedule.nframes

    def frame(self, k):
        """Frame ``k`` as a one-frame `Exposure` (schedule with ``nframes=1``)."""
        k += self._drop
        if self._map is None:  # compressed: astropy unpacks (and scales) the section
            with unpacking(self.path):
                data = self._layout.to_readout(np.asarray(self._d.sci.section[k : k + 1]))
            if data.dtype.kind in "iu":
                data = data.astype(FLOAT_FOR[self._d.sci.header["BITPIX"]])
        else:  # explicit reads (`reads`), converted to native order or scaled
            stored = self.reads(k - self._drop, 0, self._d.shape[1])
            data = (stored.astype(stored.dtype.newbyteorder("=")) if self._scale is None else
                    to_physical(stored, self._scale, FLOAT_FOR[self._d.sci.header["BITPIX"]]))
            data = data[None]
        data = self.scale(data)
        phantom = None if self._phantom is None else self._phantom[k - self._drop:][:1]
        return Exposure.from_arrays(data, self.schedule.replace(nframes=1), unit=self.unit,
                                    phantom=phantom, header=self.header, tables=self._tables)

    @property
    def has_phantom(self):
        """Whether the file has phantom values."""
        return self._phantom is not None

    def readable_in_bands(self):
        """Whether `reads` serves this file: pixels stored as floating point, neither
        scaled nor compressed (other files are read whole)."""
        dtype = self._map[2] if self._map is not None else None
        return (dtype is not None and dtype.kind == "f" and self._scale is None
                and (self._phantom is None or self._phantom.dtype.kind == "f"))

    def reads(self, k, first, stop):
        """Reads ``first:stop`` of frame ``k`` (after the dropped frames) as they are in the
        file (a copy): `scale` applies the gain.

        Read with ``pread``: no page of the memory map is touched (a file cut
        while it is read is an error naming it, never ``SIGBUS``), and several
        threads may read at once.  The executor's bands use it for files
        `readable_in_bands` whose channels are not columns (`reads_into` for
        the others); `frame` for any file stored as it is on disk.

        A layout whose channels are not columns reads what holds the band
        (`~spherex_reduce.core.channel_layout.ChannelLayout.stored_rows_of`):
        for quadrants read along rows, two runs of ``stop - first`` rows; for
        ``rows`` (quadrants read along columns), columns ``first:stop`` (two
        runs of ``stop - first`` columns) of every stored row, one ``pread``
        a row and run: the file's bytes once, in many small reads.

        Returns
        -------
        `numpy.ndarray`
            ``(stop - first, columns)`` of the readout frame, possibly big-endian.
        """
        if self._layout.identity:
            return self._stored_rows(k, first, stop)
        rows, (at, column) = self._layout.stored_rows_of(first, stop)
        columns = np.unique(column)
        if columns.size <= self._stored_shape[1] // 4 and hasattr(os, "preadv"):
            # a few columns of each row
            part = self._stored_columns(k, rows, consecutive_runs(columns))
            return part[at, np.searchsorted(columns, column)]
        return np.concatenate([self._stored_rows(k, r[0], r[-1] + 1)
                               for r in consecutive_runs(rows)])[at, column]

    def reads_into(self, out, runs):
        """Runs of reads of every frame, as the file holds them, straight into ``out``.

        One ``pread`` a run and frame into a view of ``out`` (no copy of its own;
        read again where the system returns fewer bytes); the file's byte order is
        kept (the caller swaps them) and `scale` is not applied.

        Parameters
        ----------
        out : `numpy.ndarray`
            ``(frames, n, columns)``, C-contiguous, of `stored_dtype`'s item size.
        runs : sequence of tuple
            ``(a, b, first)``: ``out[k, a:b]`` gets reads ``first:first + b - a`` of
            frame ``k`` (after the dropped frames), for every frame ``k``.

        Returns
        -------
        bool
            False, with nothing read, where the file cannot be read so (channels
            that are not columns, no ``preadv``): `reads` serves it.
        """
        if not self._layout.identity or not hasattr(os, "preadv"):
            return False
        _, offset, dtype, fd = self._map
        nreads, ncols = self._stored_shape
        row = ncols * dtype.itemsize
        view = memoryview(out).cast("B")
        per_frame = out.shape[1] * row
        for k in range(out.shape[0]):
            base = offset + (k + self._drop) * nreads * row
            at = k * per_frame
            for a, b, first in runs:
                pread_into(fd, np.frombuffer(view[at + a * row:at + b * row], np.uint8),
                           base + first * row,
                           f"{self.path}: the file ends inside frame {k + self._drop}")
        return True

    def _stored_columns(self, k, rows, runs):
        """The columns of ``runs`` (runs of consecutive columns) of stored rows ``rows`` of
        frame ``k``, side by side: one ``pread`` a row and run."""
        _, offset, dtype, fd = self._map
        nrows, ncols = self._stored_shape
        base = offset + (k + self._drop) * nrows * ncols * dtype.itemsize
        buf = np.empty((rows.size, sum(run.size for run in runs)), dtype)
        for i, r in enumerate(rows):
            at = 0
            for run in runs:
                pread_into(fd, buf[i, at:at + run.size],
                           base + (int(r) * ncols + int(run[0])) * dtype.itemsize,
                           f"{self.path}: the file ends inside frame {k}")
                at += run.size
        return buf

    def _stored_rows(self, k, first, stop):
        """Rows ``first:stop`` of the stored image of frame ``k`` (a copy, as in the file)."""
        mm, offset, dtype, fd = self._map
        nreads, ncols = self._stored_shape
        k += self._drop
        pos = offset + (k * nreads + first) * ncols * dtype.itemsize
        if not hasattr(os, "preadv"):  # (Windows) from the map, then release its pages
            count = (stop - first) * ncols
            buf = np.frombuffer(mm, dtype, count=count, offset=pos).reshape(-1, ncols).copy()
            self._release(pos, count * dtype.itemsize)
            return buf
        return pread_into(fd, np.empty((stop - first, ncols), dtype), pos,
                      f"{self.path}: the file ends inside frame {k}")

    def _release(self, start, nbytes):
        mm = self._map[0] if self._map is not None else None
        if mm is None or not hasattr(mm, "madvise"):
            return
        page = start - start % mmap.PAGESIZE
        length = (start + nbytes - page) // mmap.PAGESIZE * mmap.PAGESIZE
        if length:
            mm.madvise(mmap.MADV_DONTNEED, page, length)


def consecutive_runs(values):
    """Sorted unique integers split into runs of consecutive values.

    Parameters
    ----------
    values : `numpy.ndarray`
        Sorted unique integers.

    Returns
    -------
    list of `numpy.ndarray`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.readers.frames import consecutive_runs
    >>> [r.tolist() for r in consecutive_runs(np.array([0, 1, 2, 5, 7, 8]))]
    [[0, 1, 2], [5], [7, 8]]
    """
    return np.split(values, np.flatnonzero(np.diff(values) != 1) + 1)


def map_frames(hdu, path):
    """``(mmap, data offset, dtype, file descriptor)`` of an image HDU stored as it is on
    disk, or None (tile-compressed: read by sections).  ``dtype`` is the stored type:
    scaling (`scaling`) is the caller's.  The descriptor (kept open, the map's own
    file) serves `pread`.

    Reading frames from a memory map and converting them to native byte order
    in one pass is ~2x faster than astropy's section reads followed by
    arithmetic on big-endian arrays.
    """
    h = hdu.header
    dtype = FITS_DTYPES.get(h.get("BITPIX"))
    if dtype is None or isinstance(hdu, fits.CompImageHDU):  # astropy decompresses those
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

