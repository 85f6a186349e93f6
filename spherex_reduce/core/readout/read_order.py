"""Explicit read orders: the physical row of every read of a frame, given as a list.

A schedule's read order is normally built from the row-chopping skip ``S`` and
the reference reads (``skip``, ``ref_reads``, ``ref_mode``,
`spherex_reduce.core.readout.schedule.chopped_order`).  The ``readout`` field
``order`` states it instead, read by read: a list of physical row indices (or
the path of an ECSV file whose one integer column holds them).  Every active
row appears exactly once; a reference row (the geometry's top and bottom
reference rows) may appear any number of times, each appearance one reference
read, anywhere in the frame.  :func:`check_order` is the one check of such a
list; a FITS file records ``ROWORDER = 'explicit'`` and its ``READOUT`` table
carries the rows (:func:`order_text`, :func:`parse_order_text`).

Examples
--------
>>> from spherex_reduce import DetectorGeometry
>>> from spherex_reduce.core.readout.read_order import check_order
>>> g = DetectorGeometry(6, 4, 1, ref_border={"top": 1})   # row 0 is a reference row
>>> rows, is_ref = check_order([0, 1, 3, 5, 0, 2, 4], g)
>>> rows.tolist(), is_ref.astype(int).tolist()
([0, 1, 3, 5, 0, 2, 4], [1, 0, 0, 0, 1, 0, 0])
>>> check_order([0, 1, 3, 5, 2, 2], g)
Traceback (most recent call last):
...
ValueError: order reads active row 2 twice (entries 4 and 5); every active row must ...
"""

import os

import numpy as np

from ..errors import FormatError
from ..limits import check_size

__all__ = ["EXPLICIT", "ORDER_REPLACES", "check_order", "order_conflict", "order_from_table",
           "order_text", "parse_order_text", "read_order_file"]

#: The value of the ``ROWORDER`` keyword of a file read in an explicit order.
EXPLICIT = "explicit"

#: The readout fields an explicit order replaces (given together with it: refused).
ORDER_REPLACES = ("skip", "ref_reads", "ref_mode")

# Bytes a checked order costs per entry (the list, its int64 and bool arrays and the
# schedule's arrays built from it), and per byte of an ECSV file while it is parsed.
_BYTES_PER_ENTRY = 200
_BYTES_PER_FILE_BYTE = 50


def order_text(order):
    """The ``ROWORDER`` card of an explicit order: ``'explicit'`` (the READOUT table lists
    the rows).

    Examples
    --------
    >>> from spherex_reduce.core.readout.read_order import order_text
    >>> order_text([0, 2, 1, 3])
    'explicit'
    """
    return EXPLICIT


def parse_order_text(text):
    """The value of a ``ROWORDER`` card: ``'explicit'`` (raises ValueError for anything else).

    Examples
    --------
    >>> from spherex_reduce.core.readout.read_order import parse_order_text
    >>> parse_order_text("explicit")
    'explicit'
    """
    if text.strip() != EXPLICIT:
        raise ValueError(f"must be {EXPLICIT!r} (the READOUT table lists the rows), got {text!r}")
    return EXPLICIT


def read_order_file(path):
    """The row indices of an ECSV file of one integer column (a list of int).

    Parameters
    ----------
    path : str or path-like
        The file; a relative path is taken from the current directory.

    Raises
    ------
    ValueError
        The file cannot be read, is not ECSV, has not exactly one column, or
        the column is not of integers; the message names the file.
    ResourceError
        The file is too large to parse in the memory available.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from astropy.table import Table
    >>> from spherex_reduce.core.readout.read_order import read_order_file
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "rows.ecsv"
    >>> Table({"row": [0, 2, 1, 3]}).write(path, format="ascii.ecsv")
    >>> read_order_file(path)
    [0, 2, 1, 3]
    """
    from astropy.table import Table  # only files need it

    try:
        size = os.path.getsize(path)
    except OSError as exc:
        raise ValueError(f"order file {os.fspath(path)!r}: {exc.strerror or exc}") from None
    check_size(_BYTES_PER_FILE_BYTE * size, f"the order file {os.fspath(path)!r} of {size} bytes")
    try:
        table = Table.read(path, format="ascii.ecsv")
    except Exception as exc:  # astropy raises many kinds for a file that is not ECSV
        raise ValueError(f"order file {os.fspath(path)!r} is not an ECSV table: "
                         f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                         ) from None
    if len(table.colnames) != 1:
        raise ValueError(f"order file {os.fspath(path)!r} must have one column of row "
                         f"indices, it has {len(table.colnames)}: {table.colnames}")
    column = np.asarray(table.columns[0])
    if column.dtype.kind not in "iu" or column.ndim != 1:
        raise ValueError(f"order file {os.fspath(path)!r}: column {table.colnames[0]!r} must "
                         f"hold integers (row indices), it holds {column.dtype}")
    return column.astype(np.int64).tolist()


def order_conflict(given):
    """The refusal of an explicit order given with fields it replaces (`ORDER_REPLACES`).

    Examples
    --------
    >>> from spherex_reduce.core.readout.read_order import order_conflict
    >>> order_conflict(["skip"])
    'order gives the read order, so skip cannot be given with it: leave out skip, ...'
    """
    return (f"order gives the read order, so {', '.join(given)} cannot be given with it: "
            f"leave out {', '.join(ORDER_REPLACES)}")


def check_order(order, geometry, given=()):
    """An explicit read order checked against a geometry: ``(rows, is_ref)``.

    Parameters
    ----------
    order : sequence of int or str
        Physical row (0-based) of every read of a frame, in read order, or the
        path of an ECSV file of one integer column (:func:`read_order_file`).
    geometry : `~spherex_reduce.DetectorGeometry`
        The array read (not a window of a larger one).
    given : sequence of str
        The fields of `ORDER_REPLACES` given with the order (refused).

    Returns
    -------
    rows : `numpy.ndarray` of int
        The rows, one per read.
    is_ref : `numpy.ndarray` of bool
        True for reads of a reference row.

    Raises
    ------
    ValueError
        An empty order, an entry that is not an integer or is out of
        ``[0, nrows)``, an active row missing or read twice (the message names
        the first such entry); ``given`` not empty; a window.
    ResourceError
        An order too long for the memory available.
    """
    if given:
        raise ValueError(order_conflict(given))
    if geometry.window is not None:
        raise ValueError("an explicit order cannot be given for a window (yet): give skip, "
                         "ref_reads and ref_mode")
    if isinstance(order, (str, os.PathLike)):
        order = read_order_file(order)
    if isinstance(order, np.ndarray):
        order = order.tolist()
    if not isinstance(order, (list, tuple)):
        raise ValueError(f"order must be a list of row indices or the path of an ECSV file, "
                         f"got {type(order).__name__}")
    if not order:
        raise ValueError("order is empty: list the physical row of every read")
    check_size(_BYTES_PER_ENTRY * len(order), f"an explicit read order of {len(order)} reads")
    nrows = geometry.nrows
    for i, row in enumerate(order):
        if isinstance(row, (bool, np.bool_)) or not isinstance(row, (int, np.integer)):
            raise ValueError(f"order entry {i} must be an integer row index, got {row!r}")
        if not 0 <= row < nrows:
            raise ValueError(f"order entry {i} is row {row}, outside the array's rows "
                             f"0 to {nrows - 1}")
    rows = np.array(order, dtype=np.int64)
    reference = np.zeros(nrows, dtype=bool)
    reference[geometry.reference_rows] = True
    is_ref = reference[rows]
    active = rows[~is_ref]
    counts = np.bincount(active, minlength=nrows)
    twice = np.flatnonzero(counts > 1)
    if twice.size:
        where = np.flatnonzero(rows == twice[0])[:2]
        raise ValueError(f"order reads active row {twice[0]} twice (entries {where[0]} and "
                         f"{where[1]}); every active row must appear exactly once")
    missing = geometry.active_rows[counts[geometry.active_rows] == 0]
    if missing.size:
        raise ValueError(f"order misses {missing.size} active row(s), the first {missing[0]}; "
                         "every active row must appear exactly once")
    return rows.astype(int), is_ref


def order_from_table(table):
    """The explicit order of a file whose header says ``ROWORDER = 'explicit'``: its
    ``READOUT`` table's ``row`` column (a list of int; checked by the schedule).

    Raises
    ------
    FormatError
        No table (None), or no integer ``row`` column.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from spherex_reduce.core.readout.read_order import order_from_table
    >>> order_from_table(Table({"row": [0, 2, 1, 3]}))
    [0, 2, 1, 3]
    >>> order_from_table(None)
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.FormatError: keyword ROWORDER = 'explicit' needs the READOUT ...
    """
    if table is None or "row" not in table.colnames:
        raise FormatError(f"keyword ROWORDER = {EXPLICIT!r} needs the READOUT table's 'row' "
                          "column, which lists the rows in read order")
    rows = np.asarray(table["row"])
    if rows.dtype.kind not in "iu" or rows.ndim != 1:
        raise FormatError(f"READOUT column 'row' must hold integers, it holds {rows.dtype}")
    return rows.tolist()
