"""Read FITS files checked: exposures in this package's layout, and any FITS file.

Reads check the file before trusting it: every header must end and every data
block must fit in the file (a truncated file is named as such), ``NEXTEND``
extensions must be present, and ``CHECKSUM``/``DATASUM`` are verified where
present (see `checksum_policy` to read a damaged file anyway).  Integer data
with ``BSCALE``/``BZERO``/``BLANK`` are scaled to floating point on read (the
file is never changed).  The layout is described in `spherex_reduce.io.layout`.
"""

import contextlib
import contextvars
import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy.io import fits
from astropy.table import Table

from ...core.errors import FormatError
from ...core.exposure import Exposure, ReferenceReads
from ...core.fields import card_text
from ..fits_structure import bad_checksums, scan_hdus
from ..input import InputOptions, apply_input
from ..layout import is_jwst
from .description import describe, file_tables, image_shape, note_bad_checksums, sci_hdu
from .flags import file_flags, foreign_bits, is_own_file, note_foreign_dq, own_flags
from .pixels import physical, unpacking
from .stable_file import StableFile

__all__ = ["CheckedFITS", "checksum_policy", "integration_count", "is_raw_ramp_file",
           "open_checked"]

log = logging.getLogger(__name__)

_VERIFY = contextvars.ContextVar("spherex_reduce_verify_checksum", default=True)


@contextlib.contextmanager
def checksum_policy(verify=True):
    """Set whether reads in this context stop at a checksum mismatch.

    `read` and `~spherex_reduce.io.FrameReader` verify ``CHECKSUM`` and ``DATASUM`` of every HDU
    that has them.  By default a mismatch is a `FormatError`; inside
    ``checksum_policy(verify=False)`` it is logged as a warning and recorded
    in the header of what is read (``HISTORY`` and the keyword ``SXRCKBAD``
    listing the HDUs), which travels to any file written from it.  The
    command line's ``--ignore-checksum`` sets this for the whole command, so
    that every file it reads (including e.g. a pipeline's dark) follows it.

    Parameters
    ----------
    verify : bool
        False to read files whose checksum does not match.

    Examples
    --------
    >>> from spherex_reduce.io import checksum_policy
    >>> with checksum_policy(verify=False):
    ...     pass  # read(...) here warns instead of failing on a bad checksum
    """
    token = _VERIFY.set(bool(verify))
    try:
        yield
    finally:
        _VERIFY.reset(token)


def open_fits(path, verify=None):
    """Open a FITS file read-only after checking its structure and checksums.

    Returns ``(hdul, bad, stable)``: the astropy HDU list (not memory-mapped:
    the readers read pixels with explicit reads), the names of HDUs whose
    checksum failed (only when ``verify`` is False: else that is an error),
    and, for a plain FITS file on disk (not gzip etc., which astropy unpacks),
    a `~spherex_reduce.io.readers.stable_file.StableFile` opened before anything was
    checked, so that a change made while the file is checked or read is seen
    (None for a compressed file).  The caller closes both.  ``verify=None``
    follows `checksum_policy`.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    verify = _VERIFY.get() if verify is None else verify
    stable = StableFile(path)
    try:
        hdul, bad, plain = _open_checked(path, verify)
    except BaseException:
        stable.close()
        raise
    if not plain:
        stable.close()
        stable = None
    return hdul, bad, stable


def _open_checked(path, verify):
    hdus = scan_hdus(path)
    bad = bad_checksums(path, hdus) if hdus else []
    if bad:
        msg = (f"{path}: the checksum of HDU(s) {', '.join(bad)} does not match the bytes "
               "(CHECKSUM/DATASUM): the file is damaged or was changed after writing")
        if verify:
            raise FormatError(f"{msg}; to read it anyway, pass --ignore-checksum "
                              "(verify_checksum=False)")
        log.warning("%s; read anyway (checksum verification off)", msg)
    try:
        hdul = fits.open(path, memmap=False, mode="readonly")
    except OSError as exc:
        raise FormatError(f"{path} is not a readable FITS file: {exc}") from exc
    try:
        for hdu in hdul:
            _check_cards(hdu, path)
    except BaseException:
        hdul.close()
        raise
    return hdul, bad, hdus is not None


def _check_cards(hdu, path):
    """Every card of ``hdu``'s header parses and holds no infinite or NaN number."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # astropy's notes on non-standard cards
        for card in hdu.header.cards:
            try:
                value = card.value
            except Exception as exc:  # VerifyError: e.g. "X = NAN", "X = 1E9999x"
                raise FormatError(f"{path}: HDU {hdu.name!r} has the unreadable header card "
                                  f"{card.keyword} = {card_text(card)}") from exc
            if isinstance(value, float) and not math.isfinite(value):
                raise FormatError(f"{path}: HDU {hdu.name!r} has the header card "
                                  f"{card.keyword} = {value}, not a finite number")


def _readonly(*arrays):
    for array in arrays:
        if array is not None:  # the file's own pages: a step must never write into them
            array.setflags(write=False)


class Closing:
    """``with x:`` calls ``x.close()`` at the end of the block (readers, sources, inputs)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class CheckedFITS(Closing):
    """A FITS file opened read-only by `open_checked`, after the checks `read` makes.

    Use it as a context manager (the file is closed on exit).

    Nothing of the file is memory-mapped: pixels are read into arrays of
    their own when asked for, each read after checking that the file is
    still the one opened and checked (`~spherex_reduce.io.readers.stable_file.StableFile`),
    so a file truncated or rewritten meanwhile is a `FormatError`, never a
    ``SIGBUS``.

    Attributes
    ----------
    path : `pathlib.Path`
    hdul : `astropy.io.fits.HDUList`
        The file's HDUs, read-only.
    bad : list of str
        Names of the HDUs whose checksum failed; only ever non-empty when the
        file was opened with checksum verification off.
    """

    def __init__(self, path, verify_checksum=None):
        self.path, self._name = Path(path), path  # messages name the path as given
        self.hdul, self.bad, self._stable = open_fits(path, verify_checksum)
        self._warned = set()  # the input: section's overrides already logged for this file

    def close(self):
        """Close the file (arrays already returned stay valid)."""
        if self._stable is not None:
            self._stable.close()
        self.hdul.close()

    def exposure(self, dq_bits=None, input=None, integration=None, **supplied):
        """The `Exposure` of a file in this package's format, as `read` returns it.

        ``dq_bits``, ``input``, ``integration`` and ``supplied`` (the readout
        parameters) are as for `read`.
        """
        return exposure_from_hdul(self.hdul, self._name, self.bad, self._stable, supplied,
                                  dq_bits, input, integration, self._warned)

    def physical(self, hdu, flags=False, index=None):
        """The data of image HDU ``hdu`` in physical values (``BSCALE``/``BZERO``
        applied, ``BLANK`` as NaN; as stored if unscaled), or None if it has none.

        ``flags``: the HDU holds integer flags (kept integers); ``index``: read
        ``data[index]`` only (one integration of a 4-D HDU)."""
        with unpacking(self._name):  # astropy unpacks a compressed file lazily
            return physical(hdu, self._name, self._stable, flags, index)

    def note_bad_checksums(self, header):
        """Record in ``header`` (changed in place) which HDUs failed their checksum:
        ``SXRCKBAD`` and a ``HISTORY`` card, as `read` does; nothing if none did."""
        note_bad_checksums(header, self.bad, self._name)


def open_checked(path, verify_checksum=None):
    """Open any FITS file read-only after checking it as `read` does, without reading it.

    The structure is scanned first (a truncated file is named as such),
    ``CHECKSUM``/``DATASUM`` are verified and every header card must parse
    to a finite value.  Use this to read files that may or may not be in this
    package's format.

    Parameters
    ----------
    path : str or `pathlib.Path`
        FITS file (plain, or compressed as astropy reads it); never changed.
    verify_checksum : bool, optional
        As for `read`: a checksum mismatch is an error (True) or only noted
        in `CheckedFITS.bad` (False).  Default: `checksum_policy`.

    Returns
    -------
    `CheckedFITS`
        A context manager holding the open HDU list.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    FormatError
        The file is truncated, not FITS, has a bad checksum (when verified)
        or a header card that does not parse.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.io import open_checked
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "img.fits"
    >>> hdu = fits.PrimaryHDU(np.array([[0, 1], [2, 3]], dtype=np.int16))
    >>> hdu.header["BSCALE"], hdu.header["BZERO"] = 0.5, 10.0
    >>> hdu.writeto(path, checksum=True)
    >>> with open_checked(path) as f:
    ...     data = f.physical(f.hdul[0])
    >>> data.tolist(), f.bad
    ([[10.0, 10.5], [11.0, 11.5]], [])
    """
    return CheckedFITS(path, verify_checksum)


def exposure_from_hdul(hdul, path, bad, stable, supplied, dq_bits=None, options=None,
                       integration=None, warned=None):
    """The `Exposure` in an HDU list opened by `open_fits` (which the caller closes), its
    pixels read from ``stable`` (the file's `~spherex_reduce.io.readers.stable_file.StableFile`;
    None for a file astropy unpacks).  ``warned``: the overrides already logged for this
    file (a set, updated: `FileDescription.warn`)."""
    with unpacking(path):  # astropy unpacks a compressed file's tables and pixels lazily
        return _exposure(hdul, path, bad, stable, supplied, dq_bits, options, integration,
                         warned)


def _exposure(hdul, path, bad, stable, supplied, dq_bits, options, integration, warned):
    options = InputOptions.from_config(options)
    if stable is not None:  # the headers and tables below are still those checked
        stable.check()
    d = describe(hdul, path, supplied, bad, options, integration=integration)
    names = d.names
    if dq_bits is None:
        dq_bits = options.dq_bits

    def image(name, flags=False):
        if name not in names:
            return None
        hdu = hdul[name]
        index = integration if integration is not None and len(image_shape(hdu)) == 4 else None
        return physical(hdu, path, stable, flags, index)

    layout = d.schedule.geometry.layout  # the stored image to the readout frame

    def frame(values, name):
        try:
            return layout.to_readout(values)
        except ValueError as exc:
            raise FormatError(f"{path}: {name}: {exc} (NROWS, NCOLS; CHANLAY "
                              f"{layout.channels})") from None

    data = frame(physical(d.sci, path, stable, index=integration), "SCI")
    err, mask = frame(image("ERR"), "ERR"), frame(image("DQ", flags=True), "DQ")
    phantom = image("PHANTOM")
    bits = foreign_bits(dq_bits)  # checked even if unused
    if mask is not None:  # a DQ from other software: its bits are not ours
        bits = None if is_own_file(names) else bits
        mask = file_flags(mask, d.shape, d.schedule, d.order, bits, path)
        if bits is not None:
            note_foreign_dq(d.header, bits, path)
    reference = None
    if "REFPIX" in names:
        rt = Table.read(hdul["REFREADS"])
        refdq = image("REFDQ", flags=True)
        reference = ReferenceReads(
            data=image("REFPIX"), rows=np.asarray(rt["row"]), reads=np.asarray(rt["read"]),
            phantom=image("REFPHANT"),
            dq=None if refdq is None else own_flags(refdq, path).astype(np.uint32),
        )
        _readonly(reference.data, reference.phantom)
    tables = file_tables(hdul, path)
    data, err, mask, phantom = apply_input(d, data, err, mask, phantom)
    _readonly(data, err, mask, phantom)
    exposure = Exposure.from_arrays(data, d.kept, unit=d.unit, uncertainty=err, mask=mask,
                                    phantom=phantom, header=d.header, order=d.order,
                                    reference=reference, tables=tables)
    d.warn(warned)
    return exposure


@dataclass(frozen=True)
class FileLayout:
    """What the headers of a file say of its layout (`probe`).

    Attributes
    ----------
    names : tuple of str
        The names of its HDUs.
    shape : tuple of int
        The shape of the HDU holding the pixels (``SCI``, else the primary HDU).
    order : str
        ``'READOUT'`` or ``'PHYSICAL'`` as keyword ``ORDER`` says (default ``READOUT``).
    jwst : bool
        The primary header says ``TELESCOP = 'JWST'`` and this package did not write
        the file (`~spherex_reduce.io.readers.flags.is_own_file`): a JWST file, read in
        its own meaning (`~spherex_reduce.io.readers.jwst_level1.JWSTLevel1`).
    """

    names: tuple
    shape: tuple
    order: str
    jwst: bool = False

    @property
    def raw_ramps(self):
        """3-D ramps in readout order with no ``DQ`` or ``ERR``: a raw ramp file (not
        JWST's, whose keywords are not ours)."""
        return (len(self.shape) == 3 and self.order == "READOUT" and not self.jwst
                and "DQ" not in self.names and "ERR" not in self.names)

    @property
    def integrations(self):
        """The integrations of a 4-D ``SCI``, else None."""
        return self.shape[0] if len(self.shape) == 4 else None


def probe(path):
    """The layout of a file from its headers (no pixel data read), or None if it cannot be
    read: the ordinary reader, `read`, then gives the proper error.

    Examples
    --------
    >>> from spherex_reduce.io.readers.fits_read import probe
    >>> probe("no-such-file.fits") is None
    True
    """
    try:
        if not Path(path).is_file():
            return None
        scan_hdus(path)  # truncated or damaged: not astropy's guess, read's error
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with fits.open(path, memmap=False, lazy_load_hdus=True) as hdul:
                sci = sci_hdu(hdul, path)
                order = str(hdul[0].header.get("ORDER", "READOUT")).strip().upper()
                names = tuple(h.name for h in hdul)  # ours keep a JWST input's TELESCOP
                return FileLayout(names, image_shape(sci), order,
                                  is_jwst(hdul[0].header) and not is_own_file(names))
    except (OSError, KeyError, IndexError, ValueError):  # FormatError is a ValueError
        return None


def is_raw_ramp_file(path):
    """True for a file whose SCI is 3-D ramps in readout order (headers only are read).

    A file that cannot be read gives False: the ordinary reader, `read`, then
    gives the proper error.

    Examples
    --------
    >>> from spherex_reduce.io import is_raw_ramp_file
    >>> is_raw_ramp_file("no-such-file.fits")
    False
    """
    layout = probe(path)
    return layout is not None and layout.raw_ramps


def integration_count(path):
    """The number of integrations of a file whose SCI is 4-D, else None (headers only are read).

    A 4-D ``SCI`` (integrations, groups, rows, columns) is the JWST "uncal"
    layout: each integration is a ramp (`read` with ``integration=``).  A file
    that cannot be read gives None: `read` then gives the proper error.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.io import integration_count
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "uncal.fits"
    >>> fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.zeros((3, 4, 8, 8), "f4"),
    ...                                                name="SCI")]).writeto(path)
    >>> integration_count(path), integration_count("no-such-file.fits")
    (3, None)
    """
    layout = probe(path)
    return None if layout is None else layout.integrations
