"""The ``DQ`` extension of a file: whose bits they are, and how a 2-D ``DQ`` covers ramps.

A file written by this package (it has a ``READOUT`` table: both writers put
one in every file) holds `spherex_reduce.core.dq` bits, kept as they are.  In any
other file the bits follow the convention of the system that wrote it
(JWST, a lab's electronics), whose meanings are not ours: by default every
non-zero bit masks a pixel (a flag we cannot read is never fitted as good;
bits 32-63 of a 64-bit ``DQ`` too), and a masked pixel gets
`~spherex_reduce.core.dq.DO_NOT_USE`.  `foreign_dq_bits`
(``--dq-bits`` on the command line), ``input: dq_bits`` or the ``dq_bits``
argument of `~spherex_reduce.io.read` choose other bits.

A ``DQ`` has the shape of ``SCI``, or, over ramps (3-D ``SCI``), the shape of
one frame: a pixel mask of the array ``(nrows, ncols)`` (the JWST layout),
or, in readout order, one row per read ``(n_reads, ncols)``.  It then applies
to every frame; a pixel mask applies to every read of each row (the
schedule's ``rows`` say which row each read is).  Flags are integers: a
``DQ`` of floating-point numbers is refused when it is read
(`~spherex_reduce.io.readers.pixels.physical`).
"""

import contextlib
import contextvars
from pathlib import Path

import numpy as np

from ...core.errors import ConfigError, FormatError
from ...core.limits import check_size
from ..header_text import header_text

__all__ = ["DEFAULT_DQ_BITS", "check_dq_bits", "current_dq_bits", "foreign_dq_bits",
           "is_own_file"]

_MAX_BITS = 2**32 - 1
#: Bits of a foreign ``DQ`` that mask a pixel unless told otherwise: all 32.
DEFAULT_DQ_BITS = _MAX_BITS

_BITS = contextvars.ContextVar("spherex_reduce_dq_bits", default=DEFAULT_DQ_BITS)


def check_dq_bits(bits, what="dq_bits"):
    """``bits`` if it is a valid mask of foreign DQ bits (an integer, 0 to 2**32 - 1).

    Raises
    ------
    ConfigError
        Naming ``what`` and the value.

    Examples
    --------
    >>> from spherex_reduce.io.readers.flags import check_dq_bits
    >>> check_dq_bits(5)
    5
    >>> check_dq_bits(-1)
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: dq_bits: must be an integer from 0 to ... got -1
    """
    if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)) \
            or not 0 <= bits <= _MAX_BITS:
        raise ConfigError(f"{what}: must be an integer from 0 to {_MAX_BITS} (a sum of 2**bit "
                          f"for bits 0-31), got {bits!r}")
    return int(bits)


def current_dq_bits():
    """The bits of a foreign ``DQ`` that mask a pixel here (see `foreign_dq_bits`).

    Examples
    --------
    >>> from spherex_reduce.io import current_dq_bits, foreign_dq_bits
    >>> with foreign_dq_bits(5):
    ...     current_dq_bits()
    5
    """
    return _BITS.get()


@contextlib.contextmanager
def foreign_dq_bits(bits=DEFAULT_DQ_BITS):
    """Set which bits of a foreign ``DQ`` mask a pixel, for every read in this context.

    A foreign file is one this package did not write (it has no ``READOUT``
    table).  The command line's ``--dq-bits`` sets this for the whole command,
    so that every file it reads (including e.g. a pipeline's dark) follows it.
    Files written by this package keep all their flags.

    Parameters
    ----------
    bits : int
        Sum of ``2**bit`` of the bits that mask, 0 to 2**32 - 1 (bits 0 to
        31); default every bit.  1: bit 0 only; 0: a foreign ``DQ`` masks
        nothing.

    Raises
    ------
    ConfigError
        ``bits`` is not an integer in that range.

    Examples
    --------
    >>> from spherex_reduce.io import foreign_dq_bits
    >>> with foreign_dq_bits(1 | 4):
    ...     pass  # read(...) here masks pixels with bit 0 or bit 2 set in a foreign DQ
    """
    token = _BITS.set(check_dq_bits(bits))
    try:
        yield
    finally:
        _BITS.reset(token)


def is_own_file(names):
    """Whether a file with HDUs ``names`` was written by this package (it has ``READOUT``).

    Examples
    --------
    >>> from spherex_reduce.io.readers.flags import is_own_file
    >>> is_own_file(["PRIMARY", "SCI", "DQ", "READOUT"]), is_own_file(["PRIMARY", "SCI", "DQ"])
    (True, False)
    """
    return "READOUT" in names


def foreign_bits(bits=None):
    """The bits of a foreign ``DQ`` that mask: ``bits`` checked, or `foreign_dq_bits`'s if None.

    Examples
    --------
    >>> from spherex_reduce.io.readers.flags import foreign_bits
    >>> foreign_bits(), foreign_bits(6)
    (4294967295, 6)
    """
    return _BITS.get() if bits is None else check_dq_bits(bits)


def note_foreign_dq(header, bits, path):
    """Record in ``header`` (in place) which bits of the foreign ``DQ`` of ``path`` masked:
    ``SXRDQBIT`` and a ``HISTORY`` line (the setting is not in the pipeline config)."""
    header["SXRDQBIT"] = (bits, "bits of the input's foreign DQ that masked")
    which = ("any bit set masked as DO_NOT_USE" if bits == _MAX_BITS else
             f"any of bits {bits:#x} set masked as DO_NOT_USE, other bits ignored")
    header.add_history(f"DQ of {header_text(Path(path).name)} not written by spherex_reduce: "
                       f"pixels with {which}")


def file_flags(stored, sci_shape, schedule, order, bits, path):
    """The flags of a file's ``DQ`` for an exposure of shape ``sci_shape``.

    Parameters
    ----------
    stored : `numpy.ndarray`
        The ``DQ`` as stored (integers; possibly a memory map, never written).
    sci_shape : tuple
        Shape of ``SCI``.
    schedule : `~spherex_reduce.ReadoutSchedule`
    order : {'readout', 'physical'}
    bits : int or None
        Bits of a foreign ``DQ`` that mask (`foreign_bits`; all 32, the
        default, is every bit: any value but 0 masks, bits 32-63 of a 64-bit
        ``DQ`` too), or None for a file written by this package, whose flags
        are kept as they are (`own_flags`).
    path : str
        Names the file in messages.

    Returns
    -------
    `numpy.ndarray`
        Integer flags (``bits`` None) or booleans (foreign: masked pixels), of
        ``sci_shape`` or broadcast to it (a read-only view).

    Raises
    ------
    FormatError
        The ``DQ`` holds floating-point values, or (a file of this package) a
        bit above 31, or has a shape that fits neither ``SCI`` nor one frame
        of it.
    """
    shape = tuple(stored.shape)
    stored = flag_bits(stored, path)
    rows = _rows_of(shape, sci_shape, schedule, order, path)
    # the exposure's uint32 flags (twice while made from booleans) and boolean mask
    check_size(9 * int(np.prod(sci_shape, dtype=float)), f"the flags of {path} {sci_shape}")
    if bits is None:
        flags = own_flags(stored, path)
    else:  # every bit (the default): any bit of the stored type, 32-63 of a 64-bit DQ too
        mask = ~stored.dtype.type(0) if bits == _MAX_BITS else np.asarray(bits).astype(
            stored.dtype)  # the chosen bits the type has
        flags = np.empty(shape, bool)
        for i in range(shape[0]):  # a frame (or a row) at a time: no temporary of DQ's size
            np.not_equal(np.bitwise_and(stored[i], mask), 0, out=flags[i])
    if rows is not None:
        flags = flags[rows]
    return flags if shape == sci_shape else np.broadcast_to(flags, sci_shape)


def flag_bits(stored, path):
    """The bits of integer flags as stored: a view as unsigned integers of the same size.

    A signed type's negative values are its top bit (``-1`` in an ``int16``
    ``DQ`` is bits 0-15), never bits of a wider type.

    Raises
    ------
    FormatError
        ``stored`` is not integers (a `~spherex_reduce.io.readers.pixels.physical`
        read of flags never is).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.readers.flags import flag_bits
    >>> flag_bits(np.array([-1, 4], np.int16), "x.fits").tolist()
    [65535, 4]
    """
    stored = np.asarray(stored)
    if stored.dtype.kind not in "iu":
        raise FormatError(f"{path}: DQ holds flags, which must be integers; it holds "
                          f"{stored.dtype.name} values")
    native = stored.dtype.newbyteorder("=")
    return stored.astype(native, copy=False).view(f"u{native.itemsize}")


def own_flags(stored, path):
    """Flags of a file this package wrote (its 32 bits), checked to have no higher bit.

    Raises
    ------
    FormatError
        A value with a bit above 31 (a 64-bit ``DQ``): it would be lost in the
        exposure's 32-bit flags.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.readers.flags import own_flags
    >>> own_flags(np.array([1, 2**31], np.uint64), "x.fits").tolist()
    [1, 2147483648]
    >>> own_flags(np.array([1, 2**40], np.uint64), "x.fits")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.FormatError: x.fits: DQ holds 1099511627776, a flag above bit 31 ...
    """
    stored = flag_bits(stored, path)
    if stored.dtype.itemsize > 4 and stored.size and (top := int(stored.max())) > _MAX_BITS:
        raise FormatError(f"{path}: DQ holds {top}, a flag above bit 31 (bit "
                          f"{top.bit_length() - 1}); this package's flags are bits 0-31: the "
                          "file's flags were changed by other software")
    return stored


def _rows_of(shape, sci_shape, schedule, order, path):
    """None if a ``DQ`` of ``shape`` applies as it is (then broadcast over frames), or the
    row of each read (a pixel mask over ramps in readout order).  Refuses other shapes."""
    if shape == sci_shape:
        return None
    nrows, ncols = schedule.geometry.nrows, schedule.geometry.ncols
    if len(sci_shape) == 3 and len(shape) == 2:
        if shape == (nrows, ncols):  # a pixel mask of the array (also when n_reads == nrows)
            return schedule.rows if order == "readout" else None
        if shape == sci_shape[1:]:  # one row per read of a frame
            return None
    frame = "" if len(sci_shape) == 2 else (
        f", one frame's {sci_shape[1:]}"
        + (f" or the array's ({nrows}, {ncols})" if sci_shape[1:] != (nrows, ncols) else ""))
    raise FormatError(f"{path}: DQ has shape {shape}, SCI has shape {sci_shape}: a DQ must have "
                      f"SCI's shape{frame}")
