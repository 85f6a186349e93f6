"""The summary table of a batch, ``OUTDIR/summary.ecsv``: one row per output, kept up to date.

A batch records each file as it finishes (`SummaryFile.record`), so a run stopped midway
(killed, interrupted, out of power) leaves a summary of what it finished.  A
record is a read-merge-write of the table under a lock on the output
directory (`~spherex_reduce.io.lock.locked_directory`), written atomically:
two batches writing into one directory each add their rows and never remove
the other's.  The merge keys rows by output file name:

- a row of this run replaces the table's row of the same output, except that
  a failed row never replaces a ``done`` or ``skipped`` row of an output that
  exists (another batch made it; the failure is reported by the run that had
  it);
- the table's other rows are kept if they are valid: ``done`` or ``skipped``
  and the output still exists (a row of a file since deleted, or of a failure
  whose file this run does not retry, is dropped);
- a table made with another pipeline config (``config_hash`` in its metadata)
  is replaced, as is one that cannot be read.

A summary of many thousand rows takes a while to write: when a record takes
longer than `SummaryFile.SLOW`, the next ones are spaced out (see there).

Rows of this run come first, in the order of its inputs, then the others in
their former order.
"""

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.table import Table

from .._version import __version__
from ..io import atomic_output
from ..io.lock import locked_directory

__all__ = ["COLUMNS", "STATUSES", "SummaryFile", "SummaryRow", "read_rows", "summary_table"]

#: What the summary's ``status`` column may say.
STATUSES = ("done", "skipped", "failed")
#: The columns of a row (``unit`` is a column only when the outputs' units differ).
COLUMNS = ("input", "output", "status", "median", "robust_std", "unit", "seconds", "error")


@dataclass(frozen=True)
class SummaryRow:
    """One output of a batch: a row of the summary (the `COLUMNS`), with what only the
    run that made it knows.

    Attributes
    ----------
    input, output : str
        The paths.
    status : str
        One of `STATUSES`.
    median, robust_std : float
        `~spherex_reduce.reduce.batch.image_statistics` of the output, in ``unit``
        (NaN for a failed file).
    unit : str
    seconds : float
    error : str
        Why it failed, one line (empty otherwise).
    kind : str
        For a failure: ``input`` (a bad input or environment) or ``unexpected`` (a
        bug); not written to the summary.
    notes : tuple of str
        Warnings raised while the file was reduced, one line each; not written.
    """

    input: str
    output: str
    status: str
    median: float = math.nan
    robust_std: float = math.nan
    unit: str = ""
    seconds: float = math.nan
    error: str = ""
    kind: str = ""
    notes: tuple = ()


def summary_table(rows, pipeline):
    """The summary of ``rows`` (`SummaryRow`) as an astropy table.

    Parameters
    ----------
    rows : list of `SummaryRow`
        One per output, in the order the table lists them.
    pipeline : `~spherex_reduce.Pipeline`
        Its source and config hash go into the metadata.

    Returns
    -------
    `~astropy.table.Table`
        ``median`` and ``robust_std`` in the outputs' unit (a ``unit`` column
        when they differ), ``seconds`` in s.

    Examples
    --------
    >>> from spherex_reduce import Pipeline
    >>> from spherex_reduce.reduce.batch_summary import SummaryRow, summary_table
    >>> row = SummaryRow("a.fits", "out/a_reduced.fits", "done", median=1.5, robust_std=0.25,
    ...                  unit="electron / s", seconds=2.0)
    >>> t = summary_table([row], Pipeline({"steps": [{"fit_ramp": {}}]}))
    >>> t["median"].quantity[0]
    <Quantity 1.5 electron / s>
    """
    units = {r.unit for r in rows if r.status != "failed"}
    t = Table({
        "input": [str(r.input) for r in rows],
        "output": [str(r.output) for r in rows],
        "status": [r.status for r in rows],
        "median": np.array([r.median for r in rows], dtype=float),
        "robust_std": np.array([r.robust_std for r in rows], dtype=float),
        "seconds": np.array([r.seconds for r in rows], dtype=float),
        "error": [r.error for r in rows],
    }, dtype=[str, str, str, float, float, float, str])
    if len(units) == 1:
        unit = u.Unit(units.pop())
        t["median"].unit = t["robust_std"].unit = unit
    elif units:  # outputs in different units (e.g. ADU and electrons): one per row
        t.add_column([r.unit for r in rows], name="unit", index=5)
    t["seconds"].unit = u.s
    t["median"].description = ("median of the output's light-sensitive pixels, finite and "
                               "not masked by DQ (reference pixels left out)")
    t["robust_std"].description = "astropy.stats.mad_std of the same pixels"
    t.meta.update({"pipeline": pipeline.source, "config_hash": pipeline.config_hash,
                   "version": __version__})
    return t


def read_rows(path, config_hash):
    """The rows (`SummaryRow`) of the summary at ``path`` if it was made with
    ``config_hash``; else ``[]``.

    A missing, unreadable or damaged summary, or one of another config, gives
    ``[]`` (it is replaced by the next `SummaryFile.record`).
    """
    try:
        t = Table.read(path, format="ascii.ecsv")
    except Exception:  # missing, or damaged (e.g. cut by a full disk before this version)
        return []
    if t.meta.get("config_hash") != config_hash or not set(COLUMNS[:5]) <= set(t.colnames):
        return []
    unit = t["median"].unit
    rows = []
    for r in t:
        row = {name: _plain(r[name]) for name in t.colnames if name in COLUMNS}
        row.setdefault("unit", "" if unit is None else unit.to_string())
        rows.append(SummaryRow(**row))
    return rows


def _plain(value):
    if np.ma.is_masked(value):
        return ""
    return value.item() if isinstance(value, np.generic) else value


def _merged(old, mine, outdir):
    """The rows of a summary holding ``old`` and, over them, this run's rows ``mine``.

    An output is looked for in ``outdir`` by its name (the rows give the paths as each run
    was given them, maybe relative to another directory).
    """
    def _valid(row):
        return row.status != "failed" and (outdir / Path(row.output).name).exists()

    by_name = {Path(r.output).name: r for r in old}
    order = []
    for row in mine:
        name = Path(row.output).name
        order.append(name)
        former = by_name.get(name)
        if row.status == "failed" and former is not None and _valid(former):
            continue  # a valid output, made by another batch: never reported as failed
        by_name[name] = row
    rest = [Path(r.output).name for r in old if Path(r.output).name not in order]
    return [by_name[n] for n in order] + [by_name[n] for n in rest if _valid(by_name[n])]


class SummaryFile:
    """The summary of a batch run at ``path``, updated by `record` as files finish.

    Parameters
    ----------
    path : `pathlib.Path`
        ``OUTDIR/summary.ecsv`` (OUTDIR exists).
    pipeline : `~spherex_reduce.Pipeline`
        The batch's pipeline.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.reduce.pipeline import as_pipeline
    >>> from spherex_reduce.reduce.batch_summary import SummaryFile, SummaryRow
    >>> out = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (out / "a_reduced.fits").write_bytes(b"")
    >>> row = SummaryRow("a.fits", str(out / "a_reduced.fits"), "done", median=1.5,
    ...                  robust_std=0.25, unit="electron / s", seconds=2.0)
    >>> summary = SummaryFile(out / "summary.ecsv", as_pipeline("spherex-default"))
    >>> [str(s) for s in summary.record([row])["status"]]
    ['done']
    """

    #: A record that took longer than this (s) is followed by others at most every
    #: `SPACING` times its duration, so that writing the summary of a batch of many
    #: thousand files stays a small part of the run (the last record is always made).
    SLOW = 0.1
    SPACING = 10

    def __init__(self, path, pipeline):
        self.path = Path(path)
        self.pipeline = pipeline
        self._written = None  # (identity of the file written last, its rows)
        self._next = 0.0

    def record(self, rows, final=True):
        """Merge this run's finished ``rows`` into the summary and write it, atomically.

        Parameters
        ----------
        rows : list of `SummaryRow`
            This run's rows so far, in the order of its inputs.
        final : bool
            False: the record may be left for a later one if records are slow
            (see `SLOW`).

        Returns
        -------
        `~astropy.table.Table` or None
            The summary as written (None if left for later).

        Raises
        ------
        OSError
            The directory cannot be written (read-only, full, ...).
        """
        start = time.monotonic()
        if not final and start < self._next:
            return None
        with locked_directory(self.path.parent):
            merged = _merged(self._current(), rows, self.path.parent)
            table = summary_table(merged, self.pipeline)
            with atomic_output(self.path, overwrite=True) as tmp:
                table.write(tmp, format="ascii.ecsv")
            self._written = (_identity(self.path), merged)
        took = time.monotonic() - start
        self._next = start + self.SPACING * took if took > self.SLOW else 0.0
        return table

    def _current(self):
        """The rows of the summary as it is now: those written last if no other batch has
        written it since (the file is the same), else read again."""
        if self._written is not None and self._written[0] == _identity(self.path):
            return self._written[1]
        return read_rows(self.path, self.pipeline.config_hash)


def _identity(path):
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size)
