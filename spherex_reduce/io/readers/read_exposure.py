"""`read`: an exposure from a file, with the reader its layout needs.

A file in this package's layout, or any FITS file of ramps or an image, is read
by `~spherex_reduce.io.readers.fits_read.CheckedFITS`; one whose reads are
``SCI`` extensions (``input: {reads: extensions}``) by
`~spherex_reduce.io.readers.extension_reads.ExtensionReads`, itself made of
the lower readers; an ASDF file (a Roman WFI level-1 file) by
`~spherex_reduce.io.readers.roman_l1.read_roman`.
"""

from dataclasses import replace

from ...core.errors import FormatError
from ..input import InputOptions
from .extension_reads import ExtensionReads
from .fits_read import CheckedFITS, probe
from .jwst_level1 import JWSTLevel1
from .roman_l1 import is_asdf_file, read_roman

__all__ = ["read"]


def read(path, verify_checksum=None, dq_bits=None, input=None, integration=None, **supplied):
    """Read an exposure written by `write` (or raw data from other electronics).

    Parameters
    ----------
    path : str or `pathlib.Path`
        FITS file, or a Roman WFI level-1 ASDF file (recognised by its first
        bytes, read with its own metadata:
        `~spherex_reduce.io.readers.roman_l1.read_roman`).  It is opened
        read-only and never changed; its pixels are
        read with explicit reads (nothing memory-mapped: a file truncated or
        rewritten while it is read is a `FormatError`, never a ``SIGBUS``),
        so the whole file is in memory when this returns (to reduce a
        full-size raw file, give `~spherex_reduce.Pipeline.run` its path: it
        streams it in bands); the arrays of the returned exposure are read-only.  Integer data with
        ``BSCALE``/``BZERO``/``BLANK`` are scaled to floating point
        (``float32`` for 8- and 16-bit data, else ``float64``; ``BLANK`` is
        NaN) in memory.
    verify_checksum : bool, optional
        Whether a ``CHECKSUM``/``DATASUM`` mismatch is an error (True), or a
        logged warning recorded in the returned header (False: ``HISTORY``
        and ``SXRCKBAD``).  Default: `checksum_policy` (True).
    dq_bits : int, optional
        Which bits of a ``DQ`` written by other software (a file without a
        ``READOUT`` table) mask a pixel, as a sum of ``2**bit``; such pixels
        get `~spherex_reduce.core.dq.DO_NOT_USE` and other bits are dropped.
        Default: `~spherex_reduce.io.foreign_dq_bits` (every bit: a flag
        that cannot be read is never fitted as good).  A file written by
        this package keeps all its flags.  A 2-D ``DQ`` with ramps applies
        to every frame (a pixel mask ``(nrows, ncols)`` to every read of
        each row).  When not given: ``input``'s
        ``dq_bits`` if it has one.
    input : dict or `~spherex_reduce.io.input.InputOptions`, optional
        What the file needs before the steps, as the ``input:`` section of a
        pipeline config (:ref:`yaml`): ``unit`` (``BUNIT`` when the file lacks
        it; ADU, DN and counts are read as ``adu``, ELECTRONS and e- as
        ``electron``, ``/S`` as per second), ``gain`` (e-/ADU, one
        number or one per channel: the data, uncertainties and phantom values
        are multiplied by it and become electrons; recorded as ``GAIN``),
        ``drop_first_reads`` (frames left out at the start of every ramp;
        recorded as ``NDROPRD``), ``header`` (``fill``: a ``supplied`` value
        that disagrees with the file's keyword is an error; ``override``: it
        replaces it, with a warning and a ``HISTORY`` card), ``dq_bits`` and
        ``reads`` (``extensions``: the file's ``SCI`` extensions are the reads
        of one ramp, in ``SAMPTIME`` order, as HST's ``_raw`` files store it:
        `~spherex_reduce.io.readers.extension_reads.ExtensionReads`).
    integration : int, optional
        For a 4-D ``SCI`` (integrations, groups, rows, columns: the JWST
        "uncal" layout), which integration to read (from 0): its ramps, with
        the file's header (plus ``SXRINT``, the integration) and schedule,
        and the same integration of a 4-D ``ERR``, ``DQ`` or ``PHANTOM`` (a
        ``DQ`` of lower dimension applies to every integration).  A 4-D
        ``SCI`` is refused without it; `~spherex_reduce.reduce_integrations`
        reduces every integration.  A JWST file (``TELESCOP = 'JWST'``) is
        read in its own keywords' meaning, in the detector orientation
        (`~spherex_reduce.io.readers.jwst_level1.JWSTLevel1`).
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
        The file is truncated or damaged (checksum), lacks ``SCI``, a keyword
        is missing or invalid, or the header, the ``READOUT`` table and the
        array shapes disagree; the message names the keyword or dimension.
    ResourceError
        Scaled data would not fit in memory once in floating point.

    Examples
    --------
    Unsigned 16-bit data (stored with ``BZERO = 32768``) come back as floats:

    >>> import tempfile, pathlib, numpy as np
    >>> from spherex_reduce import Exposure, ReadoutSchedule, DetectorGeometry, read, write
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=0), ref_mode="none",
    ...                     phantom_reads=0, nframes=2)
    >>> counts = np.arange(2 * 8 * 8, dtype=np.uint16).reshape(2, 8, 8) + 60000
    >>> out = write(Exposure.from_arrays(counts, s), pathlib.Path(tempfile.mkdtemp()) / "u.fits")
    >>> e = read(out)
    >>> e.data.data.dtype, float(e.data.data.max())
    (dtype('float32'), 60127.0)
    """
    options = InputOptions.from_config(input)
    if is_asdf_file(path):  # a Roman level-1 file: its own metadata, in its own meaning
        if integration is not None:
            raise FormatError(f"{path}: integration={integration} given, but a Roman level-1 "
                              "file holds one ramp, not integrations")
        return read_roman(path, input=options, dq_bits=dq_bits, **supplied)
    if options.reads == "extensions":  # one read per SCI extension: a reader of its own
        if dq_bits is not None:
            options = replace(options, dq_bits=dq_bits)
        with ExtensionReads(path, verify_checksum, input=options, **supplied) as reads:
            return reads.exposure()
    layout = probe(path)
    if layout is not None and layout.jwst:  # JWST's keywords, in JWST's meaning
        with JWSTLevel1(path, verify_checksum) as f:
            return f.exposure(dq_bits=dq_bits, input=options, integration=integration,
                              **supplied)
    with CheckedFITS(path, verify_checksum) as f:
        return f.exposure(dq_bits=dq_bits, input=options, integration=integration, **supplied)
