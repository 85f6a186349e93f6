"""Pixel values of FITS image HDUs: stored integers scaled to physical values.

Pixels are read from the file with explicit reads
(`~spherex_reduce.io.readers.stable_file.StableFile`, nothing memory-mapped) and
integer data with ``BSCALE``/``BZERO``/``BLANK`` are converted here from the
stored values; the readers of whole files (`spherex_reduce.io.readers.fits_read`) and
of bands (`spherex_reduce.io.readers.frames`, `spherex_reduce.io.readers.read_files`) share it.
"""

import contextlib
import lzma
import zlib

import numpy as np
from astropy.io import fits

from ...core.errors import FormatError
from ...core.fields import header_keyword
from ...core.limits import check_size

__all__ = ["FITS_DTYPES", "FLOAT_FOR", "physical", "scaling", "to_physical", "unpacking"]

#: the floating-point type each BITPIX is read as, and the type it is stored as
FLOAT_FOR = {8: "f4", 16: "f4", 32: "f8", 64: "f8", -32: "f4", -64: "f8"}
FITS_DTYPES = {8: "u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}  # as stored


@contextlib.contextmanager
def unpacking(path):
    """A ``with`` block in which astropy unpacks a compressed file's pixels: a stream that
    ends early or is damaged (e.g. the file changed while it is read) is one
    `~spherex_reduce.core.errors.FormatError` naming the file, not the decompressor's
    `EOFError` or `zlib.error`.

    Examples
    --------
    >>> from spherex_reduce.io.readers.pixels import unpacking
    >>> try:
    ...     with unpacking("a.fits.gz"):
    ...         raise EOFError("Compressed file ended before the end-of-stream marker")
    ... except ValueError as exc:
    ...     print(str(exc).split(":")[0])
    a.fits.gz
    """
    try:
        yield
    except (EOFError, zlib.error, lzma.LZMAError) as exc:
        raise FormatError(f"{path}: the compressed data end early or are damaged ({exc}); "
                          "was the file changed while it was read?") from None


def scaling(hdu, path):
    """``(bscale, bzero, blank)`` of an image HDU, checked, or None if its values are stored
    as they are."""
    h = hdu.header
    if not any(key in h for key in ("BSCALE", "BZERO", "BLANK")):
        return None
    try:
        bscale = header_keyword(h, "BSCALE", float, default=1.0)
        bzero = header_keyword(h, "BZERO", float, default=0.0)
        blank = header_keyword(h, "BLANK", int, default=None) if h["BITPIX"] > 0 else None
    except FormatError as exc:
        raise FormatError(f"{path}: HDU {hdu.name!r}: {exc}") from exc
    if bscale == 0:
        raise FormatError(f"{path}: HDU {hdu.name!r} has BSCALE = 0")
    if bscale == 1 and bzero == 0 and blank is None:
        return None
    return bscale, bzero, blank


def to_physical(stored, scale, dtype):
    """``BZERO + BSCALE * stored`` (``BLANK`` -> NaN) as a new array of ``dtype``."""
    bscale, bzero, blank = scale
    out = stored.astype(dtype)
    if out.dtype.kind in "iu":  # flags: integer offsets only (checked by the caller)
        out += int(bzero)
        return out
    if bscale != 1:
        out *= bscale
    if bzero:
        out += bzero
    if blank is not None:
        out[stored == blank] = np.nan
    return out


def physical(hdu, path, stable, flags=False, index=None):
    """The data of an image HDU in physical values (``data[index]`` if ``index`` is given).

    ``stable`` is the file's `~spherex_reduce.io.readers.stable_file.StableFile`: the
    stored values of a plain FITS file are read from it into a new array
    (nothing is memory-mapped, so a file changed meanwhile is an error, not a
    signal), in native byte order; None for a file astropy unpacks (gzip,
    tile-compressed), whose data come as astropy gives them (callers read such a
    file within `unpacking`).  Scaled data are
    converted here from the stored values: floating point, or 64-bit integers
    for flags (``DQ``), whose ``BSCALE`` must be 1 and ``BZERO`` whole.  Flags
    stored as floating-point numbers are refused (`FormatError`), integral or
    not: a flag of 0.5 cast to an integer would mask nothing.
    """
    if hdu.header.get("NAXIS", 0) == 0:
        return None
    if flags and hdu.header["BITPIX"] < 0:  # 0.5 on a bad read would mask nothing
        raise FormatError(f"{path}: HDU {hdu.name!r}{_version(hdu)} holds flags, which must be "
                          f"integers; it holds floating-point numbers (BITPIX = "
                          f"{hdu.header['BITPIX']})")
    scale = scaling(hdu, path)
    unpacked = stable is None or isinstance(hdu, fits.CompImageHDU)  # by astropy
    if scale is None and unpacked:
        return hdu.data if index is None else hdu.data[index]
    if scale is None:  # in native byte order in place: no second copy
        stored = _stored(hdu, path, index, stable)
        if stored.dtype.isnative:
            return stored
        return stored.byteswap(inplace=True).view(stored.dtype.newbyteorder("="))
    bitpix = hdu.header["BITPIX"]
    if flags:
        if scale[0] != 1 or scale[1] != int(scale[1]):
            raise FormatError(f"{path}: HDU {hdu.name!r} holds flags, which must be integers; "
                              f"it has BITPIX = {bitpix}, BSCALE = {scale[0]}, "
                              f"BZERO = {scale[1]}")
        dtype = np.dtype("i8")
    else:
        dtype = np.dtype(FLOAT_FOR[bitpix])
    shape = tuple(hdu.shape)
    part = shape if index is None else shape[1:]
    check_size(int(np.prod(part, dtype=float)) * dtype.itemsize,
               f"HDU {hdu.name!r} of {path} {part} scaled to {dtype}")
    if unpacked:  # astropy unpacks and scales
        data = np.asarray(hdu.data)
        return (data if index is None else data[index]).astype(dtype)
    return to_physical(_stored(hdu, path, index, stable), scale, dtype)


def _version(hdu):
    """``',2'`` for an extension with ``EXTVER = 2`` (HST's ``DQ,2``), ``''`` without one."""
    return f",{hdu.header['EXTVER']}" if "EXTVER" in hdu.header else ""


def _stored(hdu, path, index, stable):
    """The stored values of an image HDU (``[index]`` of its first axis if given), read from
    the `~spherex_reduce.io.readers.stable_file.StableFile` ``stable`` into a new array."""
    dtype = np.dtype(FITS_DTYPES[hdu.header["BITPIX"]])
    shape = tuple(hdu.shape)
    part = shape if index is None else shape[1:]
    nbytes = int(np.prod(part, dtype=float)) * dtype.itemsize
    check_size(nbytes, f"HDU {hdu.name!r} of {path} {part}")
    offset = hdu.fileinfo()["datLoc"] + (0 if index is None else index * nbytes)
    what = f"HDU {hdu.name!r}" if index is None else f"integration {index} of HDU {hdu.name!r}"
    return stable.read(offset, dtype, part, what)
