"""The layout of an exposure file: extension names and units.

Extension names:

``PRIMARY``
    No data; the readout keywords (`ReadoutSchedule.to_header`), ``BUNIT``,
    ``ORDER`` (``READOUT`` or ``PHYSICAL``) and the provenance of every step.
``SCI``
    Pixels: ramps ``(frames, reads, columns)`` or a 2-D image, in the order
    ``ORDER`` says.
``ERR``, ``DQ``
    Standard deviation and data-quality flags (`spherex_reduce.core.dq`), if any.
``PHANTOM``
    Phantom values, ``(frames, reads, channels)`` or ``(reads, channels)``.
``READOUT``
    One row per read of a frame: ``row kind start time``; cross-checked
    against the header keywords on read.
``REFPIX``, ``REFPHANT``, ``REFDQ``, ``REFREADS``
    Reference reads kept aside by ``unchop`` (pixels, phantoms, flags, and a
    table ``read row time``).

``PROVENANCE``
    One row per step run (``PROVENANCE_COLUMNS``), carried from an input to
    what is made of it; checked when an input is read.

Any other table extension holds a table recorded by a step (e.g. ``REFOFFS``).
Any other image extension is written from `write`'s ``images`` (e.g. the
per-integration slopes ``INTSLOPE``, ``INTERR``, ``INTDQ`` of a 4-D input) and
skipped by `read`.
"""

from pathlib import Path

import numpy as np
from astropy import units as u

from ..core.errors import FormatError

__all__ = ["COMPRESSED_SUFFIXES", "FITS_SUFFIXES", "PROVENANCE_COLUMNS", "RESERVED", "fits_stem",
           "integration_shape", "is_jwst", "unit_string"]

#: Compression suffixes and FITS extensions a file name may end with (case-insensitive).
COMPRESSED_SUFFIXES = (".gz", ".bz2", ".fz", ".z")
FITS_SUFFIXES = (".fits", ".fit", ".fts")


def fits_stem(path):
    """An input file's name without its compression suffix and FITS (or ASDF) extension.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    str

    Examples
    --------
    >>> from spherex_reduce.io.layout import fits_stem
    >>> fits_stem("darks/dark_01.fits.gz"), fits_stem("read_2.FITS"), fits_stem("notes.txt")
    ('dark_01', 'read_2', 'notes.txt')
    >>> fits_stem("r0000101001001001001_0001_wfi01_uncal.asdf")  # a Roman level-1 file
    'r0000101001001001001_0001_wfi01_uncal'
    """
    name = Path(path).name
    for suffixes in (COMPRESSED_SUFFIXES, (*FITS_SUFFIXES, ".asdf")):
        for suffix in suffixes:
            if name.lower().endswith(suffix) and len(name) > len(suffix):
                name = name[:-len(suffix)]
                break
    return name


RESERVED = {"PRIMARY", "SCI", "ERR", "DQ", "PHANTOM", "READOUT", "REFPIX", "REFPHANT", "REFDQ",
             "REFREADS"}

#: Columns of the ``PROVENANCE`` table, in order: one value per row each, ``elapsed`` a
#: number (seconds), the others text.
PROVENANCE_COLUMNS = ("step", "status", "parameters", "inputs", "versions", "elapsed", "route")


def unit_string(unit):
    """A unit as ``BUNIT`` holds it: astropy's generic format ('electron' is not a FITS unit).

    Parameters
    ----------
    unit : `astropy.units.UnitBase`

    Returns
    -------
    str
        Empty for a dimensionless unit.

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.io.layout import unit_string
    >>> unit_string(u.electron / u.s), unit_string(u.one)
    ('electron / s', '')
    """
    return "" if unit == u.one else unit.to_string()


def integration_shape(shape, integration, path):
    """The shape of the ramps read: ``shape`` itself, or one integration's of a 4-D SCI.

    Parameters
    ----------
    shape : tuple of int
        The shape of the file's ``SCI``.
    integration : int or None
        The integration read (from 0), which a 4-D ``SCI`` needs and no other allows.
    path : str or `pathlib.Path`
        The file, for the messages.

    Returns
    -------
    tuple of int

    Raises
    ------
    FormatError
        The integration is missing, not wanted, or not one of the file's.

    Examples
    --------
    >>> from spherex_reduce.io.layout import integration_shape
    >>> integration_shape((3, 5, 8, 8), 1, "f.fits"), integration_shape((5, 8, 8), None, "f.fits")
    ((5, 8, 8), (5, 8, 8))
    """
    if len(shape) == 4 and integration is None:
        raise FormatError(
            f"{path}: SCI is 4-D {shape} (integrations, groups, rows, columns): reduce it with "
            "'spherex-reduce reduce' (or spherex_reduce.reduce_integrations), which fits each "
            "integration, or read one integration with read(path, integration=i)")
    if integration is None:
        return shape
    if len(shape) != 4:
        raise FormatError(f"{path}: integration={integration!r} given but SCI has shape {shape}, "
                          "not 4-D (integrations, groups, rows, columns)")
    if (isinstance(integration, bool) or not isinstance(integration, (int, np.integer))
            or not 0 <= integration < shape[0]):
        raise FormatError(f"{path}: integration={integration!r} is not one of the file's "
                          f"{shape[0]} integrations (0 to {shape[0] - 1})")
    return shape[1:]


def is_jwst(header):
    """Whether a primary header is a JWST file's (``TELESCOP = 'JWST'``): its keywords
    have JWST's meanings, never this package's
    (`~spherex_reduce.io.readers.jwst_level1.JWSTLevel1` reads it).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.layout import is_jwst
    >>> is_jwst(fits.Header({"TELESCOP": "JWST "})), is_jwst(fits.Header({"NFRAMES": 8}))
    (True, False)
    """
    value = header.get("TELESCOP")
    return isinstance(value, str) and value.strip().upper() == "JWST"
