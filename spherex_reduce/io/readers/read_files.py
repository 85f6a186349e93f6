"""Read a ramp stored as one FITS file per read (frame up the ramp), a band of rows at a time.

Many test sets (e.g. ASIC-driven labs) store a ramp as files ``read_1.fits``,
``read_2.fits`` ...: each holds one 2-D image, one frame of the ramp.
`ReadFiles` opens them all, checks each as `~spherex_reduce.io.read` checks a
file (structure, checksums, header cards, shape against the schedule) and that
they agree (shape, ``BITPIX``, unit, ``ORDER``), and serves rows of every frame
like `~spherex_reduce.io.FrameReader` does for one 3-D file, so a
`~spherex_reduce.io.sources.FileSource` streams them.  The files are never modified.
"""

import dataclasses
import glob
import os
import re
import threading
from pathlib import Path

import numpy as np

from ...core.errors import FormatError
from ...core.exposure import Exposure
from ...core.limits import check_count, check_size
from ..header_text import header_text
from ..input import InputOptions, apply_gain, apply_input
from ..layout import fits_stem
from .description import describe, file_tables, image_shape
from .fits_read import open_fits
from .flags import file_flags, flag_bits, foreign_bits, is_own_file, note_foreign_dq
from .frames import RampReader, consecutive_runs, map_frames
from .pixels import FLOAT_FOR, physical, scaling, to_physical, unpacking
from .stable_file import pread_into

__all__ = ["MAX_READ_FILES", "FrameImage", "ImageRamp", "ReadFiles", "natural_key",
           "read_file_paths", "read_mask"]

#: most files one ramp may be read from (each stays open while it is read)
MAX_READ_FILES = 400

DIGITS = "0123456789"


def natural_key(path):
    """Sort key of a path in natural order: the numbers in its name compare as numbers.

    Only the ASCII digits ``0``-``9`` make numbers (`read_file_paths` refuses a
    file name holding any other character Unicode counts as a digit, such as
    ``²`` or a full-width ``１``).

    Examples
    --------
    >>> from spherex_reduce.io.readers.read_files import natural_key
    >>> sorted(["read_10.fits", "read_2.fits", "read_1.fits"], key=natural_key)
    ['read_1.fits', 'read_2.fits', 'read_10.fits']
    """
    parts = re.split(r"([0-9]+)", str(path))
    return [(0, int(p), "") if i % 2 else (1, 0, p) for i, p in enumerate(parts)]


def _check_read_names(paths, pattern):
    """Refuse names whose read numbers are not plain (a digit other than ASCII ``0``-``9``)
    or that give two files the same place in the ramp (``read_2`` and ``read_02``)."""
    for path in paths:
        odd = [c for c in Path(path).name if (c.isdigit() or c.isnumeric()) and c not in DIGITS]
        if odd:
            raise FormatError(f"--reads {pattern!r}: {path}: the name holds {odd[0]!r}, a digit "
                              "other than ASCII 0-9; read numbers are read from ASCII digits "
                              "only: rename the file")
    seen = {}  # the name without FITS and compression suffixes, its numbers as numbers
    for path in paths:
        key = tuple(natural_key(Path(path).parent / fits_stem(path).lower()))
        if key in seen:
            raise FormatError(f"--reads {pattern!r}: {seen[key]} and {path} have the same read "
                              "number: which comes first is not defined; keep one of them")
        seen[key] = path


def read_file_paths(pattern):
    """The files a glob pattern matches, in natural order (``read_2`` before ``read_10``).

    Parameters
    ----------
    pattern : str
        A glob pattern (``DIR/read_*.fits``).

    Returns
    -------
    list of str

    Raises
    ------
    FormatError
        The pattern matches no file, or only one (a ramp needs two reads at
        least); a file name holds a digit other than ASCII ``0``-``9``; two
        names have the same numbers (``read_2`` and ``read_02``).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.io.readers.read_files import read_file_paths
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> for n in (10, 2, 1):
    ...     _ = (d / f"read_{n}.fits").write_bytes(b"")
    >>> [pathlib.Path(p).name for p in read_file_paths(str(d / "read_*.fits"))]
    ['read_1.fits', 'read_2.fits', 'read_10.fits']
    """
    paths = sorted((p for p in glob.glob(pattern) if Path(p).is_file()), key=natural_key)
    if not paths:
        raise FormatError(f"--reads {pattern!r} matches no file")
    if len(paths) == 1:
        raise FormatError(f"--reads {pattern!r} matches one file ({paths[0]}); a ramp needs "
                          "two reads at least, one file each")
    check_count(len(paths), f"the number of files --reads {pattern!r} matches", MAX_READ_FILES)
    _check_read_names(paths, pattern)
    return paths


def read_mask(path, nreads, shape, verify_checksum=None):
    """The flags of every read from one mask file: ``nreads`` arrays of ``shape`` (their bits,
    unsigned, `~spherex_reduce.io.readers.flags.flag_bits`).

    The file's ``DQ`` extension, else its primary HDU, holds integers: a 2-D
    image of ``shape`` applies to every read, a 3-D one ``(nreads, *shape)``
    holds one plane per read.  Checked as `~spherex_reduce.io.read` checks a
    file (structure, checksums); never modified.

    Raises
    ------
    FormatError
        No image, one of floating-point numbers, or one of another shape; the
        message names both shapes.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.readers.read_files import read_mask
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "mask.fits"
    >>> fits.PrimaryHDU(np.array([[0, 4], [0, 0]], np.int16)).writeto(path)
    >>> [plane.tolist() for plane in read_mask(path, 2, (2, 2))]
    [[[0, 4], [0, 0]], [[0, 4], [0, 0]]]
    >>> read_mask(path, 2, (3, 2))
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.FormatError: ...mask.fits: the mask has shape (2, 2); ...
    """
    hdul, _, stable = open_fits(path, verify=verify_checksum)
    try:
        with unpacking(path):
            names = [h.name for h in hdul]
            hdu = hdul["DQ"] if "DQ" in names else hdul[0]
            if not hdu.is_image or hdu.header.get("NAXIS", 0) == 0:
                raise FormatError(f"{path}: a mask file holds the flags as a DQ extension or "
                                  "in its primary HDU; this one has neither")
            flags = flag_bits(physical(hdu, path, stable, flags=True), path)
    finally:
        if stable is not None:
            stable.close()
        hdul.close()
    if flags.shape == tuple(shape):
        return [flags] * nreads
    if flags.shape == (nreads, *shape):
        return list(flags)
    raise FormatError(f"{path}: the mask has shape {flags.shape}; expected {tuple(shape)} (one "
                      f"mask for every read) or {(nreads, *shape)} (one plane per read file)")


class _ReadFile:
    """One open file of a read: its checked description, and how its rows are read."""

    def __init__(self, path, verify, supplied, tables=False, options=None):
        self.path = path
        self.hdul, bad, stable = open_fits(path, verify=verify)
        self.plain = stable is not None
        self.image = None
        try:
            with unpacking(path):  # astropy unpacks a compressed file lazily
                names = [h.name for h in self.hdul]
                naxis = self.hdul["SCI" if "SCI" in names else 0].header.get("NAXIS", 0)
                if naxis != 2:
                    raise FormatError(f"{path}: a file per read holds one 2-D image (rows x "
                                      f"columns), its {'SCI' if 'SCI' in names else 'primary HDU'} "
                                      f"has {naxis} axes")
                try:
                    self.d = describe(self.hdul, path, supplied, bad, options,
                                       decided=("nframes",))
                except FormatError as exc:  # name the file: there are many
                    if str(path) in str(exc):
                        raise
                    raise FormatError(f"{path}: {exc}") from exc
                if "ERR" in self.d.names:
                    raise FormatError(f"{path}: a file per read holds the pixels (and "
                                      "optionally PHANTOM and DQ), not ERR")
                sci = self.d.sci
                #: the read's flags as stored (2-D, of the image's shape), or None
                self.dq = None
                self.layout = self.d.schedule.geometry.layout
                self.stored_shape = image_shape(sci)  # the image as stored: rows, columns
                if "DQ" in self.d.names:
                    self.dq = np.array(physical(self.hdul["DQ"], path, stable, flags=True))
                    if self.dq.shape != self.stored_shape:
                        raise FormatError(f"{path}: DQ has shape {self.dq.shape}, SCI "
                                          f"{self.stored_shape}: a read's flags are one "
                                          "value per pixel of its image")
                    self.dq = self.layout.to_readout(self.dq)
                self.own = is_own_file(self.d.names)
                self.bitpix = sci.header["BITPIX"]
                self.phantom = None
                if "PHANTOM" in self.d.names:  # as a 3-D file's (FrameReader), in floats
                    hdu = self.hdul["PHANTOM"]
                    self.phantom = np.array(physical(hdu, path, stable))
                    if self.phantom.dtype.kind != "f":
                        self.phantom = self.phantom.astype(FLOAT_FOR[hdu.header["BITPIX"]])
                #: the file's tables (only if asked: the first file's are the exposure's)
                self.tables = file_tables(self.hdul, path) if tables else {}
                self.image = FrameImage(sci, path, self.plain, self.dq, self.layout)
                if self.image.mapped:  # its rows are read from the image's own descriptor
                    self.hdul.close()
        except Exception:
            self.close()
            raise
        finally:  # what is read later is read through the map's own descriptor
            if stable is not None:
                stable.close()

    def close(self):
        if self.image is not None:
            self.image.close()
        self.hdul.close()


class FrameImage:
    """One frame of a ramp stored as a 2-D image HDU: its rows, and its flags.

    Parameters
    ----------
    hdu : image HDU
        The frame's pixels, in an open file (kept open while rows are read
        from it unless the image is `mapped`).
    path : str or `pathlib.Path`
        Its file (messages name it).
    plain : bool
        The file is plain FITS on disk: rows are read with ``pread`` from a
        descriptor of the image's own (else astropy unpacks them).
    dq : `numpy.ndarray` or None
        The frame's flags in the readout frame (2-D), or None.
    layout : `~spherex_reduce.core.channel_layout.ChannelLayout`
        How the image's channels lie (`rows` gives the readout frame's rows).
    """

    def __init__(self, hdu, path, plain, dq, layout):
        self.hdu, self.path, self.dq, self.layout = hdu, path, dq, layout
        self.scale = scaling(hdu, path)
        self._unpack = threading.Lock()  # astropy's HDU is read by one thread at a time
        self._map = map_frames(hdu, path) if plain and hasattr(os, "preadv") else None
        if self._map is not None:  # read with pread from one descriptor per image
            mm, offset, stored, fd = self._map
            mm.close()
            self._map = (None, offset, stored, fd)

    @property
    def mapped(self):
        """Whether rows are read with ``pread`` (else from the open HDU)."""
        return self._map is not None

    def rows(self, first, stop, dtype):
        """Rows ``first:stop`` of the readout frame as ``dtype`` (physical values, native
        order): of the image itself for ``channels: columns``, else gathered from the
        stored rows that hold them (as `~spherex_reduce.io.FrameReader.reads`)."""
        if self.layout.identity:
            return self._stored_rows(first, stop, dtype)
        rows, take = self.layout.stored_rows_of(first, stop)
        return np.concatenate([self._stored_rows(r[0], r[-1] + 1, dtype)
                               for r in consecutive_runs(rows)])[take]

    def _stored_rows(self, first, stop, dtype):
        """Rows ``first:stop`` of the image as stored, as ``dtype``."""
        ncols = self.hdu.header["NAXIS1"]
        if self._map is None:  # compressed: astropy unpacks (and scales) the section
            # (the file is kept open; also without pread, e.g. on Windows)
            with self._unpack, unpacking(self.path):
                return np.asarray(self.hdu.section[first:stop]).astype(dtype)
        _, offset, stored, fd = self._map
        buf = pread_into(fd, np.empty((stop - first, ncols), stored),
                     offset + first * ncols * stored.itemsize,
                     f"{self.path}: the file ends inside the image")
        if self.scale is not None:
            return to_physical(buf, self.scale, dtype)
        return buf.astype(dtype)

    def close(self):
        """Close the image's descriptor (its file is the caller's)."""
        if self._map is not None:
            os.close(self._map[3])
            self._map = None


class ImageRamp(RampReader):
    """A ramp whose frames are separate 2-D images (`FrameImage`), read a band of rows of
    every frame at a time: what `ReadFiles` and
    `~spherex_reduce.io.readers.extension_reads.ExtensionReads` share.

    A subclass sets ``schedule``, ``order``, ``unit``, ``header``, ``tables``,
    ``phantom``, ``label`` (the input as messages name it) and ``_images``
    (the frames kept, in time order), ``_shape`` (of one image), ``_gain``, ``_dtype`` and
    ``_dq_bits``
    (foreign bits that mask, or None for this package's flags).
    """

    @property
    def nframes(self):
        """Number of frames."""
        return self.schedule.nframes

    @property
    def has_phantom(self):
        """Whether the frames have phantom values."""
        return self.phantom is not None

    def readable_in_bands(self):
        """Whether the rows are in readout order, as the executor streams them, with no
        read's flags (else use `exposure`)."""
        return self.order == "readout" and not any(f.dq is not None for f in self._images)

    def frame_rows(self, k, first, stop):
        """Rows ``first:stop`` of frame ``k``, floating point (a new array), as stored:
        `scale` applies the gain."""
        return self._images[k].rows(first, stop, self._dtype)

    def scale(self, values):
        """``values`` (``(..., columns)``) multiplied in place by the gain of ``input:``,
        as `~spherex_reduce.io.FrameReader.scale`."""
        return apply_gain(values, self._gain, self.schedule.geometry)

    def reads(self, k, first, stop):
        """Reads ``first:stop`` of frame ``k``, as `~spherex_reduce.io.FrameReader.reads`
        gives them (here always floating point, scaled, native byte order)."""
        return self.frame_rows(k, first, stop)

    def exposure(self):
        """The whole ramp in memory as an `~spherex_reduce.Exposure` (checked to fit)."""
        nrows, ncols = self._shape
        shape = (self.nframes, nrows, ncols)
        check_size(float(np.prod(shape)) * self._dtype.itemsize,
                   f"a ramp of {self.nframes} frames of {nrows} x {ncols}")
        data = np.empty(shape, self._dtype)
        for k in range(self.nframes):
            data[k] = self.frame_rows(k, 0, nrows)
        self.scale(data)
        mask, header = self._flags(shape), self.header.copy()
        if mask is not None and self._dq_bits is not None:
            note_foreign_dq(header, self._dq_bits, self.label)
        return Exposure.from_arrays(data, self.schedule, unit=self.unit, phantom=self.phantom,
                                    header=header, order=self.order, tables=self.tables,
                                    mask=mask)

    def _flags(self, shape):
        """The frames' flags stacked (a frame without any: no flag), as `file_flags` takes a
        3-D file's: foreign bits (``input: dq_bits``) unless they are this package's."""
        if all(f.dq is None for f in self._images):
            return None
        stored = np.zeros(shape, np.uint64)  # every bit of each read's flags, none added
        for k, f in enumerate(self._images):
            if f.dq is not None:
                stored[k] = flag_bits(f.dq, f.path)
        return file_flags(stored, shape, self.schedule, self.order, self._dq_bits, self.label)

    def close(self):
        """Close every frame's image."""
        for f in getattr(self, "_images", ()):
            f.close()
        self._images = []


class ReadFiles(ImageRamp):
    """A ramp stored as one FITS file per read, read a band of rows of every frame at a time.

    It offers what `~spherex_reduce.io.sources.FileSource` asks of a
    `~spherex_reduce.io.FrameReader` (``schedule``, ``header``, ``unit``,
    ``tables``, ``phantom``, ``stored_dtype``, `reads`), so a
    `~spherex_reduce.Pipeline` streams the ramp from the files: memory stays
    near the output plus a few bands.  Use as a context manager.

    Parameters
    ----------
    paths : sequence of str or `pathlib.Path`
        The files, one per read, in the order of the ramp (`read_file_paths`
        sorts a glob's matches).  Each holds one 2-D image (``SCI`` or the
        primary HDU), rows in the order the header's (or config's) ``ORDER``
        says, and optionally a 2-D ``PHANTOM`` (reads x channels); nothing else
        is read from it.  Each is checked as by `~spherex_reduce.io.read`.
    verify_checksum : bool, optional
        As for `~spherex_reduce.io.read`.
    input : dict or `~spherex_reduce.io.input.InputOptions`, optional
        As for `~spherex_reduce.io.read` (the ``input:`` section): the unit,
        the gain (`reads` and `exposure` give the values multiplied by it) and
        the first files (reads) left out.
    dq : str or `pathlib.Path`, optional
        One mask file for every read (``--reads-dq``): a 2-D integer image of
        flags (the shape of a read's image) applies to every read, a 3-D one
        holds one plane per file, in the files' order (`read_mask`).  Its
        flags join each read file's own ``DQ`` (bitwise or) and mask as they
        do: any bit, or ``input: dq_bits``.
    **supplied
        Geometry and readout values for keywords the first file lacks (as for
        `~spherex_reduce.io.read`); ``nframes`` is always the number of files
        (the first file's ``NFRAMES``, and the config's, are replaced).

    Attributes
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
        The first file's schedule with ``nframes`` = the number of files.
    header : `astropy.io.fits.Header`
        The first file's header (the exposure's), with ``NFRAMES`` and a
        HISTORY line naming the files.
    order : str
        ``'readout'`` or ``'physical'``.
    unit : `astropy.units.Unit`

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.readers.read_files import ReadFiles
    >>> from spherex_reduce.io.examples import tiny_schedule
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> header = tiny_schedule(phantom_reads=0).to_header()
    >>> header["ORDER"] = "PHYSICAL"
    >>> for k in range(3):
    ...     fits.PrimaryHDU(np.full((64, 64), k, np.float32), header).writeto(
    ...         d / f"read_{k}.fits")
    >>> with ReadFiles(sorted(d.glob("read_*.fits"))) as r:
    ...     print(r.schedule.nframes, r.order, r.frame_rows(2, 0, 1)[0, :3].tolist())
    3 physical [2.0, 2.0, 2.0]
    """

    def __init__(self, paths, verify_checksum=None, input=None, dq=None, **supplied):
        options = InputOptions.from_config(input)
        if options.reads is not None:
            raise FormatError(f"input.reads is {options.reads} (the reads of a ramp are the SCI "
                              "extensions of one file) but the reads are given as files, one "
                              "per read: leave input.reads out")
        each = dataclasses.replace(options, drop_first_reads=0)  # a file holds one read
        paths = [Path(p) for p in paths]
        if len(paths) < 2:
            raise FormatError("a ramp read from files needs two files at least, one per read")
        check_count(len(paths), "the number of read files", MAX_READ_FILES)
        supplied = {**supplied, "nframes": len(paths)}  # whatever the config says
        self.paths = paths
        self._dq_bits = foreign_bits(options.dq_bits)  # checked even if unused
        self._files, self._images = [], []
        try:
            for path in paths:
                self._files.append(_ReadFile(path, verify_checksum, supplied,
                                             tables=not self._files, options=each))
                self._check_like_first(self._files[-1])
            first = self._files[0]
            if dq is not None:  # one mask file: its plane of each read joins the read's DQ
                planes = read_mask(dq, len(paths), first.stored_shape, verify_checksum)
                for f, stored in zip(self._files, planes, strict=True):
                    plane = first.layout.to_readout(stored)
                    f.image.dq = plane if f.image.dq is None else (
                        flag_bits(f.image.dq, f.path) | plane)
            self.schedule = first.d.schedule.replace(nframes=len(paths))
            self.order, self.unit = first.d.order, first.d.unit
            self.header = first.d.header.copy()
            self.header["NFRAMES"] = (len(paths), "frames up the ramp: one file per read")
            self.header.add_history(f"ramp of {len(paths)} files, one per read: "
                                    f"{header_text(paths[0].name)} ... "
                                    f"{header_text(paths[-1].name)}")
            if dq is not None:
                self.header.add_history(f"flags of every read from {header_text(Path(dq).name)}")
            self._gain = first.d.gain
            drop, self.schedule = options.frames(self.header, self.schedule, True, paths[0])
            for f in self._files[:drop]:  # the reads left out (input.drop_first_reads)
                f.close()
            self._files, self.paths = self._files[drop:], paths[drop:]
            self._images, self._shape = [f.image for f in self._files], tuple(first.d.shape)
            self.label = self.paths[0]
            self.tables = first.tables
            if first.own:  # flags written by this package: kept as they are
                self._dq_bits = None
            self._dtype = np.dtype(FLOAT_FOR[first.bitpix])
            phantoms = [f.phantom for f in self._files]
            self.phantom = (None if phantoms[0] is None else  # the gain as a 3-D file's
                            apply_input(first.d, None, None, None, np.stack(phantoms))[3])
        except BaseException:
            self.close()
            raise
        first.d.warn()  # every file accepted: the overrides, once (they are the same in each)
        #: the type `reads` returns (floating point, native order)
        self.stored_dtype = self._dtype

    def _check_like_first(self, f):
        first = self._files[0]
        for what, got, want in (("shape", f.d.shape, first.d.shape),
                                ("BITPIX", f.bitpix, first.bitpix),
                                ("unit (BUNIT)", f.d.unit, first.d.unit),
                                ("ORDER", f.d.order, first.d.order),
                                ("PHANTOM", f.phantom is not None, first.phantom is not None)):
            if got != want:
                raise FormatError(f"{f.path}: {what} is {got}, but {first.path} has {want}: the "
                                  "files of one ramp must agree")
        if f.d.schedule != first.d.schedule:  # every file is read in the first one's order
            mine, theirs = f.d.schedule.to_header(), first.d.schedule.to_header()
            keys = [k for k in dict.fromkeys([*theirs, *mine]) if mine.get(k) != theirs.get(k)]
            what = (f"keyword {keys[0]} is {mine.get(keys[0])!r}, but {first.path} has "
                    f"{theirs.get(keys[0])!r}" if keys else
                    f"the readout schedule ({mine.get('TFRAME')} s frames) differs from "
                    f"{first.path}'s")
            raise FormatError(f"{f.path}: {what}: the files of one ramp must have one readout "
                              "(keywords and READOUT table)")

    def close(self):
        """Close every file."""
        for f in self._files:
            f.close()
        self._files, self._images = [], []
