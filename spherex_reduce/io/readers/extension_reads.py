"""Read a ramp stored as image extensions of one file, one read each (HST WFC3/IR ``_raw``).

HST's WFC3/IR (like NICMOS before it) stores a MULTIACCUM ramp as one
*imset* per read, ``i = 1 ... n``: the extensions ``SCI,i``, ``ERR,i``,
``DQ,i``, ``SAMP,i`` and ``TIME,i`` (``EXTVER`` i), the latest read first
(``SCI,1`` is the last read, ``SCI,n`` the zeroth read, at ``SAMPTIME`` 0).
Each ``SCI`` header gives its ``SAMPTIME`` (s from the start of the ramp) and
``BUNIT``; an extension with no data (``NAXIS = 0``) stands for an image of
the one value of its ``PIXVALUE`` keyword.

`ExtensionReads` reads such a file as one ramp in time order (the ``SCI``
extensions sorted by ``SAMPTIME``) when the config asks for it
(``input: reads: extensions``; without it the file is refused in one line,
never reduced from ``SCI,1``).  What is read, and what is not:

- every ``SCI,i``: one read, in counts (``BUNIT`` ``COUNTS``, ``DN``,
  ``ADU`` or absent: `~spherex_reduce.io.input.InputOptions` as for any file).
  The schedule gets the ``SAMPTIME`` of every read as its ``read_times``:
  the ramp fit uses those times, the sample sequences of HST being uneven.
  Reads in a rate unit (the calibrated ``_ima``: ``ELECTRONS/S``,
  ``COUNTS/S``, each read divided by its ``SAMPTIME`` after zeroth-read,
  dark and non-linearity corrections) are refused: reduce the ``_raw`` file.
- ``DQ,i``: that read's flags, foreign bits (any bit masks, or
  ``input: dq_bits``), as a ``DQ`` of any other file.
- ``ERR,i``, ``SAMP,i`` and ``TIME,i`` are not read (the fit gives its own
  uncertainties; ``SAMP`` and ``TIME`` describe the calibrated product).

The rows of every read are served a band at a time like those of one file
per read (`~spherex_reduce.io.readers.read_files.ImageRamp`); a read with flags makes
the ramp read whole.  The file is never modified.
"""

import dataclasses
import itertools
from pathlib import Path

import numpy as np
from astropy import units as u

from ...core.errors import FormatError
from ...core.fields import header_keyword
from ...core.limits import check_count
from ..header_text import header_text
from ..input import InputOptions, parse_unit
from .description import describe, file_tables, image_shape
from .fits_read import open_fits
from .flags import foreign_bits
from .pixels import FLOAT_FOR, physical, unpacking
from .read_files import MAX_READ_FILES, FrameImage, ImageRamp

__all__ = ["ExtensionReads", "extension_reads"]


def extension_reads(hdul, path):
    """The ``SCI`` extensions of an open file in time order: ``[(SAMPTIME, EXTVER, HDU)]``.

    Raises
    ------
    FormatError
        Fewer than two ``SCI``; two with one ``EXTVER``; a ``SCI`` without
        ``SAMPTIME`` or with a bad one; two reads at one ``SAMPTIME``;
        extensions of different shapes (or not 2-D) or units; reads in a rate
        unit.  One line naming the extensions.
    ResourceError
        More ``SCI`` than ``MAX_READ_FILES`` (each read keeps a descriptor open).

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.readers.extension_reads import extension_reads
    >>> hdul = fits.HDUList([fits.PrimaryHDU()] + [
    ...     fits.ImageHDU(np.zeros((4, 4), "i2"), fits.Header({"SAMPTIME": t}), "SCI", ver=v)
    ...     for v, t in ((1, 12.9), (2, 2.9), (3, 0.0))])
    >>> [(t, v) for t, v, _ in extension_reads(hdul, "x_raw.fits")]
    [(0.0, 3), (2.9, 2), (12.9, 1)]
    """
    sci = [h for h in hdul if h.name == "SCI"]
    if len(sci) < 2:
        raise FormatError(f"{path}: input.reads is extensions, but the file holds {len(sci)} "
                          "SCI extension(s): a ramp stored as extensions has one SCI per read, "
                          "two at least")
    check_count(len(sci), f"the SCI extensions of {path} (one open descriptor each)",
                MAX_READ_FILES)
    reads, seen = [], {}
    for h in sci:
        version = h.header.get("EXTVER", 1)
        if version in seen:
            raise FormatError(f"{path}: two SCI extensions have EXTVER {version}: which DQ "
                              "belongs to which read is not defined")
        seen[version] = h
        if "SAMPTIME" not in h.header:
            raise FormatError(f"{path}: SCI,{version} has no SAMPTIME: the time of each read "
                              "(s from the start of the ramp) orders and fits the reads")
        try:
            t = header_keyword(h.header, "SAMPTIME", float, minimum=0)
        except FormatError as exc:
            raise FormatError(f"{path}: SCI,{version}: {exc}") from None
        reads.append((t, version, h))
    reads.sort(key=lambda r: r[0])
    for (t, a, _), (t2, b, _) in itertools.pairwise(reads):
        if t == t2:
            raise FormatError(f"{path}: SCI,{a} and SCI,{b} have the same SAMPTIME {t:g} s: "
                              "two reads at one time")
    _check_alike(reads, path)
    return reads


def _check_alike(reads, path):
    """Every read 2-D, of one shape and one unit, and not a rate."""
    _, v0, h0 = reads[0]
    shape, unit = image_shape(h0), h0.header.get("BUNIT")
    for _, v, h in reads:
        if image_shape(h) != shape or len(shape) != 2:
            raise FormatError(f"{path}: SCI,{v} has shape {image_shape(h)}, SCI,{v0} "
                              f"{shape}: the reads of one ramp are 2-D images of one shape")
        if h.header.get("BUNIT") != unit:
            raise FormatError(f"{path}: SCI,{v} has BUNIT {h.header.get('BUNIT')!r}, SCI,{v0} "
                              f"{unit!r}: the reads of one ramp have one unit")
    if unit is not None and _is_rate(unit):
        raise FormatError(f"{path}: the reads are in {unit!r}, a rate (as in a calibrated "
                          "_ima file, each read divided by its SAMPTIME): a ramp fit needs "
                          "the counts of every read; reduce the _raw file")


def _is_rate(text):
    """Whether a ``BUNIT`` text is per second (``ELECTRONS/S``, ``COUNTS/S``, ``DN/s``)."""
    try:
        unit = parse_unit(text).decompose()
    except ValueError:
        return str(text).replace(" ", "").lower().endswith(("/s", "/sec", "/second"))
    return any(base == u.s and power < 0 for base, power in zip(unit.bases, unit.powers,
                                                                strict=True))


def _read_flags(hdul, version, shape, path, stable):
    """The flags of read ``version`` (``DQ,version``) as stored, or None (no ``DQ``, or
    one that flags nothing); a ``DQ`` without data is its ``PIXVALUE`` everywhere."""
    try:
        hdu = hdul["DQ", version]
    except KeyError:
        return None
    if hdu.header.get("NAXIS", 0) == 0:
        try:
            value = header_keyword(hdu.header, "PIXVALUE", int, minimum=0, default=0)
        except FormatError as exc:
            raise FormatError(f"{path}: DQ,{version}: {exc}") from None
        return np.full(shape, value, np.int64) if value else None
    flags = np.asarray(physical(hdu, path, stable, flags=True))
    if flags.shape != tuple(shape):
        raise FormatError(f"{path}: DQ,{version} has shape {flags.shape}, SCI,{version} "
                          f"{tuple(shape)}: a read's flags are one value per pixel of its image")
    return flags if flags.any() else None


class ExtensionReads(ImageRamp):
    """A ramp stored as ``SCI`` extensions of one file, one per read, read in time order.

    It offers what `~spherex_reduce.io.sources.FileSource` asks of a reader
    (as `~spherex_reduce.io.readers.read_files.ReadFiles` does), so a
    `~spherex_reduce.Pipeline` streams the ramp a band at a time (read whole
    when a read has flags).  `~spherex_reduce.io.sources.open_input`,
    `~spherex_reduce.io.read` and ``Pipeline.run(path)`` use it for a file
    when the config's ``input:`` says ``reads: extensions``.  Use as a
    context manager.

    Parameters
    ----------
    path : str or `pathlib.Path`
        The file (the layout is in the module's description), checked as by
        `~spherex_reduce.io.read`; never modified.
    verify_checksum : bool, optional
        As for `~spherex_reduce.io.read`.
    input : dict or `~spherex_reduce.io.input.InputOptions`, optional
        As for `~spherex_reduce.io.read` (the ``input:`` section): unit, gain,
        the first reads (in time order) left out, ``dq_bits``.
    **supplied
        Geometry and readout values for keywords the file lacks (as for
        `~spherex_reduce.io.read`); ``nframes`` is always the number of
        ``SCI`` and ``read_times`` their ``SAMPTIME`` (the config's are replaced).

    Attributes
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
        With ``nframes`` the reads and ``read_times`` their ``SAMPTIME``.
    header : `astropy.io.fits.Header`
        The primary header (the exposure's), with ``NFRAMES`` and a HISTORY line.
    order : str
        ``'readout'`` or ``'physical'``.
    unit : `astropy.units.Unit`

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.readers.extension_reads import ExtensionReads
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "ramp_raw.fits"
    >>> hdus = [fits.PrimaryHDU()]
    >>> for v, t in ((1, 12.9), (2, 2.9), (3, 0.0)):  # the latest read first
    ...     hdus.append(fits.ImageHDU(np.full((8, 8), 10 * t, "f4"),
    ...                               fits.Header({"SAMPTIME": t}), "SCI", ver=v))
    >>> fits.HDUList(hdus).writeto(path)
    >>> readout = dict(nrows=8, ncols=8, nchannels=2, ref_border=0, skip=1, ref_mode="none",
    ...                phantom_reads=0, row_overhead=0, pixel_rate=1e5, frame_time=2.9)
    >>> with ExtensionReads(path, **readout) as r:
    ...     print(r.schedule.read_times, r.frame_rows(2, 0, 1)[0, :2].tolist())
    (0.0, 2.9, 12.9) [129.0, 129.0]
    """

    def __init__(self, path, verify_checksum=None, input=None, **supplied):
        options = InputOptions.from_config(input)
        self.path = self.label = path
        self._images = []
        self._hdul, bad, stable = open_fits(path, verify=verify_checksum)
        try:
            with unpacking(path):  # astropy unpacks a compressed file lazily
                self._open(options, bad, stable, supplied)
        except BaseException:
            self.close()
            raise
        finally:  # what is read later is read through each image's own descriptor
            if stable is not None:
                stable.close()
        self._d.warn()
        #: the type `reads` returns (floating point, native order)
        self.stored_dtype = self._dtype

    def _open(self, options, bad, stable, supplied):
        path, hdul = self.path, self._hdul
        reads = extension_reads(hdul, path)
        times = [t for t, _, _ in reads]
        each = dataclasses.replace(options, drop_first_reads=0)  # dropped below, in time order
        decided = {"nframes": len(reads), "read_times": times}
        d = self._d = describe(hdul, path, {**supplied, **decided}, bad, each,
                               decided=tuple(decided), sci=reads[0][2])
        if "PHANTOM" in d.names:
            raise FormatError(f"{path}: a ramp stored as SCI extensions is read without "
                              "PHANTOM values; this file has a PHANTOM extension")
        self.order, self.unit, self._gain = d.order, d.unit, d.gain
        self.schedule = d.schedule.replace(**decided)
        self.header = d.header.copy()
        self.header["NFRAMES"] = (len(reads), "frames up the ramp: one SCI extension per read")
        self.header.add_history(f"ramp of the {len(reads)} SCI extensions of "
                                f"{header_text(Path(path).name)}, in SAMPTIME order "
                                f"({times[0]:g} ... {times[-1]:g} s)")
        drop, self.schedule = options.frames(self.header, self.schedule, True, path)
        self._shape, plain = tuple(d.shape), stable is not None
        self._dq_bits = foreign_bits(options.dq_bits)
        layout = d.schedule.geometry.layout  # flags and rows: to the readout frame
        self._images = [FrameImage(h, path, plain, layout.to_readout(_read_flags(
            hdul, v, image_shape(h), path, stable)), layout) for _, v, h in reads[drop:]]
        self._dtype = np.result_type(*(FLOAT_FOR[h.header["BITPIX"]] for _, _, h in reads))
        self.tables, self.phantom = file_tables(hdul, path), None
        if all(f.mapped for f in self._images):  # rows come from each image's descriptor
            hdul.close()

    def close(self):
        """Close the file."""
        super().close()
        self._hdul.close()
