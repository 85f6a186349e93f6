"""The one entry point for inputs: `open_input`, and the sources the executor reads.

Whatever a user gives (an `~spherex_reduce.Exposure` in memory, the path of a
raw ramp file, of a reduced image or of a 4-D file of integrations, the files
of a ramp stored one per read, an open reader), `open_input` opens it once,
with the pipeline config's ``input:`` section and its ``geometry:``/
``readout:`` values for keywords a file lacks, and hands out *sources*: what
the executor (`spherex_reduce.reduce.executor`) reads bands of rows from.

A source (`Source`) is either the exposure in memory (`MemorySource`: bands
are views) or an open reader of a raw file (`FileSource`: bands are read with
``pread``, no page of the file is mapped).  Both give the *side block* (the
reads of the reference rows of every frame, with their phantom values) and
bands of rows of every frame, and either can be loaded whole (`Source.exposure`)
for a step that needs the whole exposure.

A new input layout is one reader class (a `~spherex_reduce.io.readers.frames.RampReader`
read in bands, or one that returns an `~spherex_reduce.Exposure`) and one
branch in `open_input`.
"""

import copy
import os
import threading
from pathlib import Path

import numpy as np

from ..core.block import Block, Context
from ..core.errors import FormatError
from ..core.exposure import Exposure, first_frames_schedule
from .input import InputOptions
from .readers.description import check_integrations
from .readers.extension_reads import ExtensionReads
from .readers.fits_read import CheckedFITS, Closing, probe
from .readers.frames import FrameReader, RampReader
from .readers.jwst_level1 import JWSTLevel1
from .readers.read_exposure import read
from .readers.read_files import ReadFiles
from .readers.roman_l1 import is_asdf_file

__all__ = ["FileSource", "Input", "MemorySource", "Source", "context_of", "open_input",
           "read_phantom", "side_block", "side_indices"]


def side_indices(schedule):
    """Reads of a frame the kernels prepare from: those of reference rows and of rows read
    more than once (their mean is the row's value)."""
    counts = np.bincount(schedule.rows, minlength=schedule.geometry.nrows)
    return np.flatnonzero(schedule.is_reference | (counts[schedule.rows] > 1))


def _frames(values, ramp):
    """``values`` with a leading frame axis (a 2-D image is one frame); None stays None."""
    if values is None:
        return None
    values = np.asarray(values)
    return values if ramp else values[None]


def context_of(exposure):
    """The `~spherex_reduce.core.block.Context` of an exposure."""
    return Context(exposure.schedule, exposure.order, exposure.is_ramp, exposure.unit,
                   exposure.header, has_phantom=exposure.phantom is not None)


def side_block(exposure):
    """The side block of an exposure: the reads kernels prepare from (see the module's
    description).

    In readout order: the reads of `side_indices` taken from the pixels.
    In physical order: the reference reads kept aside by ``unchop`` if there
    are any, else the physical reference rows that were read.
    """
    s = exposure.schedule
    ramp = exposure.is_ramp
    unc = exposure.data.uncertainty
    unc = None if unc is None else unc.array

    def take(values, idx):
        return None if values is None else np.take(_frames(values, ramp), idx, axis=-2)

    every = read_phantom(exposure)
    if exposure.order == "readout":
        idx = side_indices(s)
        return Block(take(exposure.data.data, idx), idx, "readout",
                     phantom=take(exposure.phantom, idx), dq=take(exposure.dq, idx),
                     uncertainty=take(unc, idx), read_phantom=every)
    ref = exposure.reference
    if ref is not None and np.shape(ref.data)[-2] > 0:
        return Block(_frames(ref.data, ramp), np.asarray(ref.reads), "readout",
                     phantom=_frames(ref.phantom, ramp), dq=_frames(ref.dq, ramp),
                     read_phantom=every)
    rows = s.geometry.reference_rows
    rows = rows[s.read_of_row()[rows] >= 0] if rows.size else rows
    return Block(take(exposure.data.data, rows), rows, "physical",
                 phantom=take(exposure.phantom, rows), dq=take(exposure.dq, rows),
                 uncertainty=take(unc, rows), read_phantom=every)


def read_phantom(exposure):
    """The phantom values of every read of every frame ``(frames, n_reads, nchannels)``, in
    readout order (None without phantom values).

    In physical order a read takes its row's phantom value (the mean over the
    row's reads for a row read more than once), and the reference reads kept
    aside by ``unchop`` their own.
    """
    if exposure.phantom is None:
        return None
    ph = _frames(exposure.phantom, exposure.is_ramp)
    if exposure.order == "readout":
        return ph
    s = exposure.schedule
    out = np.take(ph, s.rows, axis=1)
    ref = exposure.reference
    if ref is not None and ref.phantom is not None and np.shape(ref.data)[-2] > 0:
        out[:, np.asarray(ref.reads)] = _frames(ref.phantom, exposure.is_ramp)
    return out


class Source(Closing):
    """What the executor reads: the side block and bands of rows of every frame.

    Attributes
    ----------
    context : `~spherex_reduce.core.block.Context`
        Schedule, row order, ramp or image, unit and header of the blocks.
    header : `astropy.io.fits.Header`
    tables : dict of `~astropy.table.Table`
    reference : `~spherex_reduce.ReferenceReads` or None
        Reference reads kept aside by ``unchop``.
    nrows : int
        Rows (reads) of a frame.
    in_memory : bool
        The whole exposure is in memory (a kernel whose estimate needs the
        whole exposure can run on it).
    where : str
        For provenance: ``'memory'`` or ``'a file'``.
    """

    in_memory = False
    where = ""

    def arrays(self):
        """The arrays its bands are views of, by name (``'data'``, ``'phantom'``,
        ``'dq'``, ``'uncertainty'``, with a leading frame axis), when they are the
        executor's own and may be written (an exposure a pass made); else None."""
        return None

    def side(self):
        """The side block (`~spherex_reduce.core.block.Block`)."""
        raise NotImplementedError

    def read(self, lo, hi):
        """Rows ``lo:hi`` of every frame (`~spherex_reduce.core.block.Block`)."""
        raise NotImplementedError

    def take(self, rows):
        """The pixels of rows ``rows`` (integers, any order) of every frame, ``(frames,
        len(rows), ncols)``: an array of the caller's (a copy), for work on a few rows of
        an exposure that is not held whole."""
        raise NotImplementedError

    def exposure(self):
        """The whole input as an `~spherex_reduce.Exposure` in memory."""
        raise NotImplementedError

    def first_frames(self, n):
        """The source of this ramp's first ``n`` frames: its bands are read from those
        frames only (a file's others are not read).  A step that needs the whole exposure
        (`exposure`) has the file read whole, once for every cut of one source, and
        held while the source is.  Raises ValueError for an image, grouped reads, or
        ``n`` out of range."""
        raise NotImplementedError

    def close(self):
        """Release what the source opened (nothing by default)."""


class MemorySource(Source):
    """Bands of an in-memory `~spherex_reduce.Exposure` (views: never written, unless
    ``owned``).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
    owned : bool
        The exposure is the executor's own (made by the kernels of a pass, seen by no
        caller): its bands are views that the kernels may write in place.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.io.sources import MemorySource
    >>> source = MemorySource(example_raw_exposure())
    >>> source.nrows, source.read(0, 8).data.shape, source.side().order
    (64, (6, 8, 64), 'readout')
    >>> source.take([5, 2]).shape
    (6, 2, 64)
    """

    in_memory = True
    where = "memory"

    def __init__(self, exposure, owned=False):
        self._exposure, self._owned = exposure, bool(owned)
        self.context = context_of(exposure)
        self.header, self.tables = exposure.header, exposure.tables
        self.reference = exposure.reference
        self.nrows = exposure.data.data.shape[-2]
        ramp = exposure.is_ramp
        unc = exposure.data.uncertainty
        self._arrays = (_frames(exposure.data.data, ramp), _frames(exposure.phantom, ramp),
                        _frames(exposure.dq, ramp), None if unc is None else _frames(unc.array,
                                                                                    ramp))

    def exposure(self):
        return self._exposure

    def first_frames(self, n):
        return MemorySource(self._exposure.first_frames(n))

    def side(self):
        return side_block(self._exposure)

    def read(self, lo, hi):
        data, phantom, flags, unc = (None if a is None else a[:, lo:hi] for a in self._arrays)
        return Block(data, np.arange(lo, hi), self.context.order, phantom=phantom, dq=flags,
                     uncertainty=unc, owned=self._owned)

    def take(self, rows):
        return np.take(self._arrays[0], rows, axis=1)

    def arrays(self):
        if not self._owned:
            return None
        names = ("data", "phantom", "dq", "uncertainty")
        return {n: a for n, a in zip(names, self._arrays, strict=True) if a is not None}


class FileSource(Source):
    """Bands of a raw ramp file, read with ``pread`` (no page of the file is mapped).

    Parameters
    ----------
    reader : `~spherex_reduce.io.FrameReader` or `~spherex_reduce.io.readers.read_files.ReadFiles`
        An open reader of a file whose pixels are stored as they are
        (floating point, not scaled, not compressed: ``reader.readable_in_bands()``),
        or of a ramp stored as one file per read, in readout order.
    owned : bool
        Close the reader with the source.
    """

    where = "a file"

    def __init__(self, reader, owned=False):
        self.reader, self._owned = reader, owned
        s = reader.schedule
        self.context = Context(s, "readout", True, reader.unit, reader.header,
                               has_phantom=reader.has_phantom)
        self.header, self.tables = reader.header, reader.tables
        self.reference = None
        self.nrows = s.n_reads
        self._dtype = reader.stored_dtype.newbyteorder("=")
        self._phantom = reader.phantom
        self._loaded = {}  # the file read whole for a step of a cut (shared by the cuts)
        self._loading = threading.Lock()  # cuts reduced in threads read it once
        self._cut = False

    def exposure(self):
        n = self.context.schedule.nframes
        if not self._cut:
            return self.reader.exposure()
        with self._loading:  # read once for every cut of this source, the whole one too
            whole = self._loaded.get("exposure")
            if whole is None:
                whole = self._loaded["exposure"] = self.reader.exposure()
        return whole if n == self.reader.schedule.nframes else whole.first_frames(n)

    def first_frames(self, n):
        if not self.context.ramp:
            raise ValueError("first frames: the file holds an image, not ramps")
        cut = copy.copy(self)  # the same open reader, which the original closes
        cut._owned, cut._cut = False, True
        schedule = first_frames_schedule(self.context.schedule, n)
        cut.context = self.context.replace(schedule=schedule)
        cut._phantom = None if self._phantom is None else self._phantom[:schedule.nframes]
        return cut

    def close(self):
        if self._owned:
            self.reader.close()

    def _reads(self, idx):
        """Reads ``idx`` (in any order) of every frame ``(frames, len(idx), ncols)``, native
        order: each run of consecutive reads read straight into its place, once per frame."""
        s = self.context.schedule
        out = np.empty((s.nframes, idx.size, s.geometry.ncols), self._dtype)
        if idx.size == 0:
            return out
        cuts = np.flatnonzero(np.diff(idx) != 1) + 1
        runs = [(int(a), int(b), int(idx[a])) for a, b in zip([0, *cuts], [*cuts, idx.size],
                                                              strict=True)]
        into = getattr(self.reader, "reads_into", None)
        if into is not None and into(out, runs):  # the file's bytes, straight into place
            if not self.reader.stored_dtype.isnative:
                out.byteswap(inplace=True)  # its order made native
        else:  # the reader's copies, their byte order converted as they are put
            for k in range(s.nframes):
                for a, b, first in runs:
                    out[k, a:b] = self.reader.reads(k, first, first + b - a)
        return self.reader.scale(out)  # the gain of input:, as a whole read applies it

    def side(self):
        idx = side_indices(self.context.schedule)
        phantom = None if self._phantom is None else self._phantom[:, idx]
        return Block(self._reads(idx), idx, "readout", phantom=phantom, owned={"data"},
                     read_phantom=self._phantom)

    def read(self, lo, hi):
        idx = np.arange(lo, hi)
        phantom = None if self._phantom is None else self._phantom[:, lo:hi]
        return Block(self._reads(idx), idx, "readout", phantom=phantom, owned={"data"})

    def take(self, rows):
        rows = np.asarray(rows, dtype=np.intp)
        if rows.size and (rows.min() < 0 or rows.max() >= self.nrows):
            raise IndexError(f"rows {rows.min()}..{rows.max()} of a frame of {self.nrows}")
        return self._reads(rows)


def _from_reader(reader, owned):
    """The source of an open reader: its file in bands if it can be, else read whole (from
    the file already open and checked; an owned reader is then closed)."""
    if reader.readable_in_bands():
        return FileSource(reader, owned=owned)
    try:
        return MemorySource(reader.exposure())
    finally:
        if owned:
            reader.close()


class Input(Closing):
    """An opened input: one ramp or image, or the integrations of a 4-D file.

    Made by `open_input`; use as a context manager (what it opened is closed
    at the end of the block).

    Attributes
    ----------
    integrations : int or None
        The integrations of a 4-D ``SCI`` (each one a ramp: `source` with
        ``integration=k``), or None for one ramp or image.
    label : str
        The input as messages name it.
    """

    def __init__(self, label, integrations=None, *, source=None, owned=True, checked=None,
                 options=None, supplied=None):
        self.label, self.integrations = label, integrations
        self._source, self._owned, self._checked = source, owned, checked
        self._options, self._supplied = options, dict(supplied or {})

    def source(self, integration=None):
        """The `Source` of the input, or of integration ``integration`` of a 4-D file.

        Raises `~spherex_reduce.core.errors.FormatError` as the reader does for
        a 4-D file without ``integration``, and for ``integration`` of an input
        that has none.
        """
        if self._checked is not None:  # a 4-D file, opened and checked once
            return MemorySource(self._checked.exposure(integration=integration,
                                                       input=self._options, **self._supplied))
        if integration is not None:
            raise FormatError(f"{self.label}: integration={integration} given, but the input "
                              "is one ramp or image, not a 4-D file of integrations")
        return self._source

    def close(self):
        """Close what `open_input` opened."""
        if self._source is not None and self._owned:
            self._source.close()
        if self._checked is not None:
            self._checked.close()


def open_input(what, *, input=None, **supplied):
    """Open an input, whatever its layout: the one entry point for inputs.

    Parameters
    ----------
    what : `~spherex_reduce.Exposure`, `Source`, reader, path, glob or sequence of paths
        - an `~spherex_reduce.Exposure` (bands are views of it);
        - a `Source`, or an open `~spherex_reduce.io.FrameReader` or
          `~spherex_reduce.io.readers.read_files.ReadFiles` (not closed here);
        - the path of a FITS file: a raw ramp file in readout order is read in
          bands, and so is a ramp stored as ``SCI`` extensions, one per read,
          when ``input`` says ``reads: extensions``
          (`~spherex_reduce.io.readers.extension_reads.ExtensionReads`); a 4-D ``SCI``
          (integrations, groups, rows, columns) gives an `Input` with
          ``integrations``; a JWST file (``TELESCOP = 'JWST'``: an ``uncal``
          file, a dark reference file) is read in its own keywords' meaning
          (`~spherex_reduce.io.readers.jwst_level1.JWSTLevel1`); anything else is read whole
          (`~spherex_reduce.io.read`);
        - the path of a Roman WFI level-1 ASDF file (``roman_datamodels``'
          ``ScienceRawModel``): its resultants, read whole with the file's
          own read pattern, frame time and detector
          (`~spherex_reduce.io.readers.roman_l1.read_roman`);
        - a sequence of paths: one ramp stored as one file per read, in that
          order (`~spherex_reduce.io.readers.read_files.read_file_paths` expands a glob
          such as ``'DIR/read_*.fits'`` in natural order, as ``--reads`` does).
    input : dict or `~spherex_reduce.io.input.InputOptions`, optional
        The pipeline config's ``input:`` section.
    **supplied
        Its ``geometry:``/``readout:`` values, for keywords a file lacks.

    Returns
    -------
    `Input`

    Raises
    ------
    FileNotFoundError, FormatError
        As the readers do.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.io.sources import open_input
    >>> with open_input(example_raw_exposure()) as inp:
    ...     print(inp.integrations, inp.source().where)
    None memory
    """
    options = InputOptions.from_config(input)
    if isinstance(what, Exposure):
        return Input("exposure in memory", source=MemorySource(what))
    if isinstance(what, Source):
        return Input("source", source=what, owned=False)
    if isinstance(what, RampReader):  # FrameReader, ReadFiles, ExtensionReads
        return Input(str(getattr(what, "path", "reader")), source=_from_reader(what, False))
    if isinstance(what, (list, tuple)):  # one file per read
        return _read_files(what, options, supplied)
    path = os.fspath(what)
    if is_asdf_file(path):  # a Roman level-1 file, read whole with its own metadata
        return Input(path, source=MemorySource(read(path, input=options, **supplied)))
    if options.reads == "extensions":  # one read per SCI extension (HST _raw)
        reader = ExtensionReads(path, input=options, **supplied)
        return Input(path, source=_from_reader(reader, True))
    layout = probe(path)  # None: read() below says what is wrong
    if layout is not None and layout.jwst:  # JWST's keywords, in JWST's meaning
        return _jwst(path, options, supplied)
    if layout is not None and layout.integrations is not None:
        return _integrations(path, options, supplied)
    if layout is not None and layout.raw_ramps:
        reader = FrameReader(path, input=options, **supplied)
        return Input(path, source=_from_reader(reader, True))
    return Input(path, source=MemorySource(read(path, input=options, **supplied)))


def _integrations(path, options, supplied):
    """A 4-D file: opened and checked once, each integration read when asked for, with
    explicit reads (`~spherex_reduce.io.readers.stable_file.StableFile`: nothing mapped, so a file
    changed meanwhile is an error, never a signal)."""
    checked = CheckedFITS(path)
    try:
        count = check_integrations(checked.hdul, path)
    except BaseException:
        checked.close()
        raise
    return Input(path, count, checked=checked, options=options, supplied=supplied)


def _jwst(path, options, supplied):
    """A JWST level-1 file (`~spherex_reduce.io.readers.jwst_level1.JWSTLevel1`): its
    integrations read when asked for, or its one ramp read now."""
    reader = JWSTLevel1(path)
    if reader.integrations is not None:
        return Input(path, reader.integrations, checked=reader, options=options,
                     supplied=supplied)
    with reader:
        return Input(path, source=MemorySource(reader.exposure(input=options, **supplied)))


def _read_files(paths, options, supplied):
    reader = ReadFiles(paths, input=options, **supplied)
    label = f"{len(paths)} read files {Path(paths[0]).name} ..."
    return Input(label, source=_from_reader(reader, True))
