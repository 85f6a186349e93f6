"""What a reader needs to know of a FITS file before reading pixels: `describe`.

`describe` validates an open file against this package's layout
(`spherex_reduce.io.layout`) and the ``input:`` section, and returns a
`FileDescription`; every reader (`~spherex_reduce.io.read`,
`~spherex_reduce.io.FrameReader`, ``ReadFiles``) starts from it.
"""

import contextlib
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.table import Table

from ...core.channel_layout import check_stored_order
from ...core.errors import FormatError
from ...core.exposure import expected_shape
from ...core.fields import header_keyword
from ...core.readout.schedule import ReadoutSchedule
from ..header_text import header_text
from ..input import InputOptions
from ..layout import PROVENANCE_COLUMNS, RESERVED, integration_shape

log = logging.getLogger(__name__)

__all__ = [
    "FileDescription",
    "check_integrations",
    "check_provenance",
    "check_shape",
    "describe",
    "file_tables",
    "image_shape",
    "note_bad_checksums",
    "readout_shape",
    "sci_hdu",
]


@dataclass(frozen=True, eq=False)
class FileDescription:
    """A FITS file as `describe` found it (no pixel data loaded).

    Attributes
    ----------
    names : list of str
        The names of its HDUs.
    header : `astropy.io.fits.Header`
        The exposure's header (the primary header, reconciled with the config).
    sci : HDU
        The HDU holding the pixels.
    shape : tuple of int
        The pixels' shape (of one integration for a 4-D ``SCI``) in the readout
        frame (`readout_shape`: the file's own for ``channels: columns``).
    schedule : `~spherex_reduce.ReadoutSchedule`
        The file's schedule.
    order : str
        ``'readout'`` or ``'physical'``.
    unit : `astropy.units.Unit`
        The unit after the ``input:`` section (electrons if a gain applies).
    kept : `~spherex_reduce.ReadoutSchedule`
        The schedule of the frames kept (``input: drop_first_reads``).
    drop : int
        Frames dropped at the start of the ramp.
    gain : `numpy.ndarray` or None
        Gain per channel to apply, or None.
    notes : tuple of str
        What the ``input:`` section overrode, for `warn` to log once the reader
        has accepted the whole file (a refused file gets its error alone).
    """

    names: list
    header: fits.Header
    sci: object
    shape: tuple
    schedule: ReadoutSchedule
    order: str
    unit: object
    kept: ReadoutSchedule
    drop: int
    gain: object
    notes: tuple = ()

    def warn(self, seen=None):
        """Log the ``input:`` section's overrides, one warning each; with ``seen`` (a set,
        updated), only those not in it: one warning per keyword per file, however many
        integrations of it are read."""
        for note in self.notes:
            if seen is None or note not in seen:
                log.warning("%s", note)
            if seen is not None:
                seen.add(note)


def note_bad_checksums(header, bad, path):
    """Record in ``header`` (in place) that HDUs ``bad`` of ``path`` failed their checksum."""
    if not bad:
        return
    previous = str(header.get("SXRCKBAD", "")).strip()
    header["SXRCKBAD"] = (",".join(filter(None, [previous, *bad]))[:68],
                          "input HDUs whose checksum failed, read anyway")
    header.add_history(f"checksum of {', '.join(bad)} in {header_text(Path(path).name)} did "
                       "not match; read anyway (checksum verification off)")


def sci_hdu(hdul, path):
    """The HDU holding the pixels: ``SCI``, else the primary HDU if it has data.

    A file with several ``SCI`` extensions (``SCI,1`` ... ``SCI,n``: HST's
    ``_ima`` and ``_raw`` files store a ramp so, one read each, latest first)
    is refused here, naming what was found: taking ``SCI,1`` as the image would
    reduce one read as if it were the ramp.  ``input: reads: extensions``
    reads such a file as a ramp
    (`~spherex_reduce.io.readers.extension_reads.ExtensionReads`).
    """
    sci = [h for h in hdul if h.name == "SCI"]
    if len(sci) > 1:
        versions = [h.header.get("EXTVER", 1) for h in sci]
        times = [h.header.get("SAMPTIME") for h in sci]
        when = (f", SAMPTIME {times[0]} ... {times[-1]} s" if None not in times else
                ", no SAMPTIME" if all(t is None for t in times) else ", SAMPTIME in some")
        raise FormatError(
            f"{path} holds {len(sci)} SCI extensions (EXTVER {versions[0]} ... "
            f"{versions[-1]}{when}): one image per read, as HST's _ima and _raw files store "
            "a ramp; to read them as one ramp in SAMPTIME order set input.reads: extensions "
            "in the config, or give the reads as one 3-D SCI, or one file per read (--reads)")
    if sci:
        return sci[0]
    if hdul[0].header.get("NAXIS", 0) > 0:
        return hdul[0]
    raise FormatError(f"{path} has no SCI extension and no primary data")


def image_shape(hdu):
    """The shape of an image HDU from its header (numpy order; no data read)."""
    return tuple(hdu.header[f"NAXIS{i}"] for i in range(hdu.header.get("NAXIS", 0), 0, -1))


def describe(hdul, path, supplied, bad=(), options=None, decided=(), integration=None,
             sci=None):
    """Validate an open file; return what every reader needs (`FileDescription`; no pixel
    data loaded).

    ``options`` (`InputOptions`, the ``input:`` section) is applied: config
    keywords fill or override the file's (each override a note, which the
    reader logs with `FileDescription.warn` once it has accepted the whole
    file: a refused file gets its error alone), the
    unit, the frames dropped (``schedule`` is then that of the kept frames,
    ``drop`` their number) and the gain per channel (``gain``, or None).  ``decided``: supplied keys
    the caller sets whatever the file says (not compared with its keywords).
    With ``integration``, ``SCI`` must be 4-D (integrations, groups, rows,
    columns) and what is described is that integration's ramps.  ``sci``: the
    HDU holding the pixels when the caller chose it (one read of a ramp stored
    as extensions), else `sci_hdu`.
    """
    options = InputOptions() if options is None else options
    names = [h.name for h in hdul]
    header = hdul[0].header.copy()
    notes = []  # overrides: warned about once the file is accepted, not before an error
    derived = options.reconcile(header, {k: v for k, v in supplied.items()
                                         if k not in decided}, path, notes)
    sci = sci_hdu(hdul, path) if sci is None else sci
    if integration is not None and len(image_shape(sci)) == 4:
        check_integrations(hdul, path)
    shape = integration_shape(image_shape(sci), integration, path)
    table = Table.read(hdul["READOUT"]) if "READOUT" in names else None
    schedule = ReadoutSchedule.from_header(
        header, table, **{k: v for k, v in supplied.items() if k not in derived})
    options.check_derived(schedule, derived, supplied, path)
    order = header_keyword(header, "ORDER", str, default="READOUT").strip().lower()
    if order not in ("readout", "physical"):
        raise FormatError(f"keyword ORDER must be READOUT or PHYSICAL, got {order!r}")
    shape = readout_shape(shape, schedule, order, path)
    check_shape(shape, schedule, order, "SCI")
    if "PHANTOM" in names:
        pshape = tuple(hdul["PHANTOM"].shape)
        if integration is not None and len(pshape) == 4:  # one integration's, as SCI's
            pshape = pshape[1:]
        frames_reads = expected_shape(schedule, order, len(shape) == 3)[:-1]
        expected = (*frames_reads, schedule.geometry.nchannels)
        if pshape != expected:
            raise FormatError(
                f"PHANTOM has shape {pshape}, the schedule gives {expected} "
                "(frames, reads, channels): check NFRAMES, NCHAN and the read order keywords"
            )
    elif schedule.phantom_reads and order == "readout":
        raise FormatError(f"NPHANT={schedule.phantom_reads} but the file has no PHANTOM extension")
    bunit = header_keyword(header if "BUNIT" in header else sci.header, "BUNIT", str,
                           default=None)
    unit = options.unit_of(bunit, header, path, notes)
    drop, kept = options.frames(header, schedule, len(shape) == 3, path)
    gain, unit = options.gains(unit, header, schedule.geometry.nchannels, path, notes)
    for key in ("CHECKSUM", "DATASUM", "ORDER", "NEXTEND"):
        header.remove(key, ignore_missing=True)
    note_bad_checksums(header, bad, path)
    if integration is not None:
        header["SXRINT"] = (integration, "integration of the input's 4-D SCI (from 0)")
    return FileDescription(names, header, sci, shape, schedule, order, unit, kept, drop, gain,
                           tuple(notes))


def readout_shape(shape, schedule, order, path):
    """The shape, in the readout frame, of pixels stored as ``shape`` (the file's ``SCI``).

    For ``channels: columns`` the two are the same.  Otherwise the last two
    axes must be the stored image's ``(NROWS, NCOLS)`` and become the readout
    frame's (`~spherex_reduce.core.channel_layout.ChannelLayout`); ramps in
    readout order must then read every row once, in order.

    Raises
    ------
    FormatError
        Naming the layout and the shapes, or what the schedule reads.
    """
    layout = schedule.geometry.layout
    if layout.identity or len(shape) < 2:
        return shape
    try:
        check_stored_order(schedule, order)
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}") from None
    if tuple(shape[-2:]) != (layout.nrows, layout.ncols):
        raise FormatError(
            f"{path}: SCI has shape {shape} but the header keywords give a stored image of "
            f"{layout.nrows} x {layout.ncols} (NROWS, NCOLS; CHANLAY {layout.channels})")
    return (*shape[:-2], *layout.frame_shape)


def check_integrations(hdul, path):
    """The number of integrations of a file whose ``SCI`` is 4-D, checked with its ``ERR``,
    ``DQ`` and ``PHANTOM`` (headers only).

    Each of those must be 4-D with as many integrations as ``SCI`` (the rest
    of its shape is checked with each integration), except a ``DQ`` of fewer
    dimensions, which applies to every integration.

    Raises
    ------
    FormatError
        ``SCI`` has no integration, or an extension has another number of
        integrations, or is not 4-D (``ERR``, ``PHANTOM``); the message names
        the extension and both shapes.
    """
    shape = image_shape(sci_hdu(hdul, path))
    count = shape[0]
    if count < 1:
        raise FormatError(f"{path}: SCI is 4-D {shape} (integrations, groups, rows, columns) "
                          "with no integration")
    names = [h.name for h in hdul]
    for name in ("ERR", "DQ", "PHANTOM"):
        other = image_shape(hdul[name]) if name in names else None
        if other is None or (len(other) == 4 and other[0] == count) or (
                name == "DQ" and len(other) < 4):
            continue
        why = (f"a 4-D {name} must have SCI's {count} integrations, it has {other[0]}"
               if len(other) == 4 else
               "it must be 4-D too, one per integration (only a DQ may apply to every "
               "integration)")
        raise FormatError(f"{path}: {name} has shape {other}, SCI has shape {shape}: {why}")
    return count


def check_shape(shape, schedule, order, name):
    if len(shape) not in (2, 3):
        raise FormatError(f"{name} must be 2-D (an image), 3-D (groups, rows, columns) or 4-D "
                          f"(integrations, groups, rows, columns), got shape {shape}")
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


def file_tables(hdul, path):
    """The binary tables of an open file that are not part of the layout (``PROVENANCE``,
    a step's table ...), by extension name: what an exposure read from it carries.

    A table astropy cannot read, or a ``PROVENANCE`` that is not one value per
    cell of the type of its column (`check_provenance`), is a `FormatError`.
    """
    tables = {}
    for h in hdul:
        if not isinstance(h, fits.BinTableHDU) or h.name in RESERVED:
            continue
        try:
            with warnings.catch_warnings():  # a TUNIT outside the FITS standard: see below
                warnings.simplefilter("ignore", u.UnitsWarning)
                table = Table.read(h)
        except (ValueError, TypeError, KeyError, IndexError) as exc:
            raise FormatError(f"{path}: table {h.name} cannot be read: {exc}") from exc
        for col in table.itercols():  # e.g. 'electron2 / s2', as the writer puts it
            if isinstance(col.unit, u.UnrecognizedUnit):
                with contextlib.suppress(ValueError):
                    col.unit = u.Unit(str(col.unit))
        tables[h.name] = table
    if "PROVENANCE" in tables:
        check_provenance(tables["PROVENANCE"], path)
    return tables


def check_provenance(table, path):
    """Refuse a ``PROVENANCE`` table whose columns (those of
    ``spherex_reduce.io.layout.PROVENANCE_COLUMNS`` it has) do not hold one value per row,
    a number for ``elapsed`` and text for the others.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from spherex_reduce.io.readers.description import check_provenance
    >>> check_provenance(Table({"step": ["unchop"], "elapsed": [0.5]}), "a.fits")
    >>> try:
    ...     check_provenance(Table({"step": ["unchop"], "elapsed": ["slow"]}), "a.fits")
    ... except ValueError as exc:
    ...     print(exc)
    a.fits: table PROVENANCE is damaged: column 'elapsed' must hold one number per row (a step
    run), it holds text
    """
    for name in PROVENANCE_COLUMNS:
        if name not in table.colnames:
            continue  # an older file's table: the columns it has are carried
        column = table[name]
        kinds, what = ("iuf", "number") if name == "elapsed" else ("U", "text")
        masked = bool(np.any(getattr(column, "mask", False)))
        if column.ndim == 1 and column.dtype.kind in kinds and not masked:
            continue
        held = {"U": "text", "S": "bytes", "O": "variable-length arrays",
                "b": "booleans"}.get(column.dtype.kind, "numbers")
        if column.ndim > 1:
            held = f"{held} in arrays of shape {column.shape[1:]}"
        raise FormatError(f"{path}: table PROVENANCE is damaged: column {name!r} must hold one "
                          f"{what} per row (a step run), it holds {held}"
                          + (" with missing values" if masked else ""))
