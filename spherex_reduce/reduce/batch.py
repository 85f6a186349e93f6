"""Batch reduction on dask.distributed: many exposures, one pipeline, one output each.

`run_batch` reduces every input file with the same pipeline, each on a worker
of a `dask.distributed` cluster (the sweep's: an embedded
`~distributed.LocalCluster` of worker processes by default, an existing
scheduler by address, or ``"serial"`` in this process), and writes

- one output per input, ``OUTDIR/<input stem>_reduced.fits`` (`output_paths`),
  each written atomically as ``spherex-reduce reduce`` writes a single file,
  with two header cards saying what made it: ``SXRINPUT``, the SHA-256 of the
  input file's bytes, and ``SXRBATCH``, the id of the batch run;
- a summary table ``OUTDIR/summary.ecsv`` (`SUMMARY_NAME`,
  `spherex_reduce.reduce.batch_summary`): one row per output with its input,
  status (``done``, ``skipped`` or ``failed``), the median and robust standard
  deviation of the output's good pixels (`image_statistics`), the seconds it
  took and, for a failed file, the error.  It is written before any file is
  reduced (so an output directory that cannot be written is found before any
  work) and again, atomically, as each file finishes.

A file that fails is reported and the others finish.  Each output is made
exactly once: an output that already holds this pipeline's reduction of this
input (``SXRCONF`` is the config hash and ``SXRINPUT`` the input's digest) is
never rewritten and counts as done (``skipped``), whether an earlier run, a
concurrent batch or, after a worker died, this run made it; so a batch
resumes where it stopped.  Any other existing output is refused before any
work unless ``overwrite`` is given.  Each file is reduced by `Pipeline.run
<spherex_reduce.Pipeline.run>` exactly as a single ``reduce`` does: the
numbers do not depend on the number of workers.
"""

import errno
import hashlib
import logging
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.stats import mad_std
from astropy.table import Table

from ..core import dq
from ..core.errors import ConfigError, SpherexReduceError
from ..io import checksum_policy, current_dq_bits, foreign_dq_bits, read, write
from ..io.layout import fits_stem
from .batch_summary import SummaryFile, SummaryRow, summary_table
from .integrations import reduce_input
from .pipeline import Pipeline, as_pipeline
from .progress import run_tasks, task_notes

__all__ = ["OUTPUT_SUFFIX", "SUMMARY_NAME", "BatchResult", "BatchTask", "finished_row",
           "image_statistics", "input_digest", "output_paths", "reduce_file", "run_batch"]

log = logging.getLogger(__name__)

#: Appended to an input's stem to name its output.
OUTPUT_SUFFIX = "_reduced.fits"
#: The summary table written in the output directory.
SUMMARY_NAME = "summary.ecsv"
def output_paths(inputs, outdir):
    """The output of each input: ``outdir/<stem>_reduced.fits``.

    The stem is the input's file name without its FITS extension (``.fits``,
    ``.fit``, ``.fts``) and compression suffix (``.gz``, ``.bz2``, ``.fz``).

    Parameters
    ----------
    inputs : sequence of str or path-like
        The input files.
    outdir : str or path-like
        The output directory.

    Returns
    -------
    list of `pathlib.Path`

    Raises
    ------
    ConfigError
        Two inputs would give the same output (the same file given twice, or
        files of the same name in different directories); names both.

    Examples
    --------
    >>> from spherex_reduce.reduce.batch import output_paths
    >>> [p.as_posix() for p in output_paths(["raw/a.fits", "b.fits.gz"], "out")]
    ['out/a_reduced.fits', 'out/b_reduced.fits']
    >>> output_paths(["x/a.fits", "y/a.fits"], "out")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: inputs x/a.fits and y/a.fits would both be reduced ...
    """
    seen = {}
    out = []
    for src in inputs:
        path = Path(outdir) / f"{fits_stem(src)}{OUTPUT_SUFFIX}"
        if path.name in seen:
            raise ConfigError(f"inputs {seen[path.name]} and {src} would both be reduced to "
                              f"{path}: give each input once, or reduce files of the same name "
                              "into different directories")
        seen[path.name] = src
        out.append(path)
    return out


def image_statistics(exposure):
    """Median and robust standard deviation of an exposure's good pixels.

    Good pixels are the light-sensitive ones (not the reference pixels,
    `Exposure.reference_pixel_mask <spherex_reduce.Exposure.reference_pixel_mask>`
    in the exposure's row order, whose values are not sky) that are
    finite with no `spherex_reduce.core.dq` flag but the informational ones
    (`~spherex_reduce.core.dq.image_usable`).  The robust
    standard deviation is `astropy.stats.mad_std` (1.4826 × the median
    absolute deviation).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        E.g. a reduced image (slopes); never modified.

    Returns
    -------
    median, robust_std : `~astropy.units.Quantity`
        In the exposure's unit; NaN when no pixel is good.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy import units as u
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce.reduce.batch import image_statistics
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=0), skip=1, ref_reads=0,
    ...                     ref_mode="none", nframes=1)
    >>> img = np.arange(16.0).reshape(4, 4)
    >>> img[0, 0] = np.nan
    >>> e = Exposure.from_arrays(img, s, unit=u.electron / u.s, order="physical",
    ...                          mask=img > 13)
    >>> median, sigma = image_statistics(e)
    >>> median
    <Quantity 7. electron / s>
    >>> bool(np.isclose(sigma.value, mad_std(np.arange(1.0, 14.0))))
    True
    """
    data = np.asarray(exposure.data.data)
    good = np.isfinite(data)
    if exposure.dq is not None:
        good &= dq.image_usable(exposure.dq)
    good &= ~exposure.reference_pixel_mask()  # not sky (each frame of ramps)
    unit = exposure.unit or u.dimensionless_unscaled
    if not good.any():
        return np.nan * unit, np.nan * unit
    values = data[good].astype(np.float64)
    return float(np.median(values)) * unit, float(mad_std(values)) * unit


# -- one file, on a worker ----------------------------------------------------------------
def _one_line(exc):
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return " ".join(str(exc).split()) or type(exc).__name__


def input_digest(path):
    """The SHA-256 of a file's bytes, as hexadecimal: what ``SXRINPUT`` records.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.reduce.batch import input_digest
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "a.fits"
    >>> _ = p.write_bytes(b"abc")
    >>> input_digest(p)[:16]
    'ba7816bf8f01cfea'
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def _stamped(result, digest, run):
    header = result.header.copy()
    header["SXRINPUT"] = digest  # 64 hexadecimal digits: no room for a comment
    if run is not None:
        header["SXRBATCH"] = (run, "batch run that wrote this file")
    return result.replace(header=header)


def finished_row(path, digest, config_hash, run=None):
    """The summary row of an output that holds this reduction of this input, or None.

    Parameters
    ----------
    path : `pathlib.Path`
        The output; None is returned if it does not exist.
    digest : str
        The input's `input_digest`.
    config_hash : str
        The pipeline's config hash.
    run : str, optional
        This batch run's id: an output it wrote itself (a task run again after
        its worker died) is ``done``; one of another run, ``skipped``.

    Returns
    -------
    `~spherex_reduce.reduce.batch_summary.SummaryRow` or None
        ``output`` (``path``), ``status``, ``median``, ``robust_std``, ``unit`` (of
        the output's pixels, `image_statistics`), ``seconds`` 0; its ``input`` is
        left empty for the caller to name.

    Raises
    ------
    ConfigError
        The output exists but is not a reduced file, or was made with another
        config or from another input (or by a version that did not record its
        input): it is not this batch's to take as done.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.reduce.batch import finished_row
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a_reduced.fits"
    >>> finished_row(out, "0" * 64, "config hash") is None  # not made yet
    True
    >>> _ = out.write_text("not FITS")
    >>> finished_row(out, "0" * 64, "config hash")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: .../a_reduced.fits exists and is not a reduced file ...
    """
    if not path.exists():
        return None
    try:
        existing = read(path, verify_checksum=True)
    except (SpherexReduceError, OSError) as exc:
        raise ConfigError(f"{path} exists and is not a reduced file ({_one_line(exc)}): pass "
                          "--overwrite to replace it, or choose another directory") from None
    made, source = existing.header.get("SXRCONF"), existing.header.get("SXRINPUT")
    if made != config_hash:
        raise ConfigError(f"{path} exists and was made with another pipeline config (SXRCONF "
                          f"{made}, this config's is {config_hash}): pass --overwrite to replace "
                          "it, or choose another directory")
    if source != digest:
        why = ("does not record its input (no SXRINPUT)" if source is None else
               "was made from another input (its SXRINPUT is not this input's SHA-256)")
        raise ConfigError(f"{path} exists and {why}: pass --overwrite to replace it, or choose "
                          "another directory")
    status = "done" if run is not None and existing.header.get("SXRBATCH") == run else "skipped"
    return _statistics_row(existing, "", str(path), status, seconds=0.0)


def _statistics_row(exposure, source, output, status, **more):
    """The summary row of an output: ``status`` and its `image_statistics`."""
    median, sigma = image_statistics(exposure)
    return SummaryRow(source, output, status, median=median.value, robust_std=sigma.value,
                      unit=median.unit.to_string(), **more)


def _reduced(task, digest, pipeline):
    """Reduce the task's input and write its output; the row of what was done.

    ``digest`` is a `concurrent.futures.Future` of the input's `input_digest`,
    computed while the file is reduced: it is waited for only when an output
    exists already, and to stamp the result.
    """
    out, overwrite = Path(task.output), task.overwrite
    try:  # this run made it before its worker died, or (no overwrite) another batch did
        done = out.exists() and finished_row(out, digest.result(), pipeline.config_hash,
                                             task.run)
    except ConfigError:
        if not overwrite:
            raise
        done = None
    if done and (done.status == "done" or not overwrite):
        return done
    result, images = reduce_input(task.input, pipeline, threads=task.threads)
    result = _stamped(result, digest.result(), task.run)
    try:
        write(result, out, overwrite=overwrite, images=images)
    except FileExistsError:  # a concurrent batch wrote it meanwhile: done if it is this
        done = finished_row(out, digest.result(), pipeline.config_hash, task.run)
        if done is None:
            raise
        return done
    # of the output as written (its images float32), as a re-run that skips it measures it
    return _statistics_row(read(out, verify_checksum=True), task.input, task.output, "done")


@dataclass(frozen=True)
class BatchTask:
    """One file of a batch, as `reduce_file` takes it (a worker process shares nothing
    else with the batch).

    Attributes
    ----------
    input, output : str
        Paths.
    config : dict
        The pipeline's effective configuration.
    source : str
        The pipeline's label.
    run : str or None
        The batch run's id.
    overwrite : bool
    threads : int or None
        Bands corrected at once (None: the executor's default).
    verify_checksum : bool
        The command's checksum policy.
    dq_bits : int or None
        The command's foreign DQ bits (None: this process's,
        `~spherex_reduce.io.current_dq_bits`).
    index : int
        Its place among the batch's inputs.
    """

    input: str
    output: str
    config: dict
    source: str
    run: str | None = None
    overwrite: bool = False
    threads: int | None = None
    verify_checksum: bool = True
    dq_bits: int | None = None
    index: int = 0


def reduce_file(task):
    """Reduce one file as ``spherex-reduce reduce`` does, exactly once; never raises.

    An output that already holds this reduction of this input (`finished_row`)
    is not made again: one this run wrote (``run``: the task ran again after
    its worker died) is ``done``, one of another run ``skipped`` (without
    ``overwrite``).  An output that appears while the file is reduced is
    likewise taken as done if it is this reduction, and refused otherwise.

    Parameters
    ----------
    task : `BatchTask`

    Returns
    -------
    `~spherex_reduce.reduce.batch_summary.SummaryRow`
        ``input``, ``output``, ``status`` (``done``, ``skipped`` or
        ``failed``), ``median`` and ``robust_std`` (floats, in ``unit``;
        `image_statistics` of the output), ``seconds``, ``notes`` (warnings, one
        line each) and, for a failed file, ``error`` (one line) and ``kind``:
        ``input`` for a `~spherex_reduce.SpherexReduceError` or an `OSError`
        (bad input or environment, exit status 2 on the command line),
        ``unexpected`` otherwise (a bug, status 1).
    """
    t0 = time.perf_counter()
    row, notes = SummaryRow(task.input, task.output, "failed"), []
    dq_bits = current_dq_bits() if task.dq_bits is None else task.dq_bits
    try:
        with task_notes() as notes, checksum_policy(verify=task.verify_checksum), \
                foreign_dq_bits(dq_bits):
            pipeline = Pipeline(task.config, source=task.source)
            # the SHA-256 (0.7 s for a 1.28 GB file) is computed beside the reduction,
            # which leaves part of a core idle: a serial batch of three such files took
            # 1.38x the time of one without digests when it came first, 1.06x beside
            with ThreadPoolExecutor(1) as hashing:
                done = _reduced(task, hashing.submit(input_digest, task.input), pipeline)
        row = replace(done, input=task.input, output=task.output)
    except Exception as exc:  # reported with the file's name; the batch goes on
        expected = isinstance(exc, (SpherexReduceError, OSError))
        row = replace(row, error=_one_line(exc) if expected
                      else f"{type(exc).__name__}: {_one_line(exc)}",
                      kind="input" if expected else "unexpected")
    return replace(row, notes=tuple(notes), seconds=time.perf_counter() - t0)


# -- the batch ----------------------------------------------------------------------------
@dataclass
class BatchResult:
    """What `run_batch` did: this run's summary table and the rows of failed files.

    ``table`` has one row per input of this run, in the order given; the
    summary file (``summary``) may also list other batches' outputs.  ``failed``
    holds the `~spherex_reduce.reduce.batch_summary.SummaryRow` of each file that
    failed.
    """

    table: Table
    summary: Path | None = None
    failed: list = field(default_factory=list)
    seconds: float = 0.0

    def count(self, status):
        """How many inputs have ``status`` (``done``, ``skipped`` or ``failed``)."""
        return int(np.sum(self.table["status"] == status)) if len(self.table) else 0


def run_batch(pipeline, inputs, outdir, *, scheduler=None, workers=None, threads=None,
              overwrite=False, progress=False, verify_checksum=True):
    """Reduce several files with one pipeline on dask; write an output each and a summary.

    Parameters
    ----------
    pipeline : `~spherex_reduce.Pipeline`, shipped name, path or dict
        The pipeline (as `~spherex_reduce.analysis.as_pipeline` takes it).
        Each file's reduction builds it again from its effective
        configuration, with the installed plugins' steps.
    inputs : sequence of str or path-like
        The input files; each must exist (checked before any work).  They
        are never modified.
    outdir : str or path-like
        The output directory; created (not its parents) if missing.  Outputs
        are named by `output_paths`; the summary is ``outdir/summary.ecsv``,
        written before any file is reduced and updated as each finishes
        (`spherex_reduce.reduce.batch_summary`).
    scheduler : str or `distributed.Client`, optional
        As for `~spherex_reduce.analysis.sweep.run_sweep`: None, an embedded
        `~distributed.LocalCluster` of ``workers`` processes (one thread
        each); an address; a ``Client`` (not closed); ``"serial"``: in this
        process.  With a remote scheduler, the paths must be the same on the
        workers (a shared file system); they are made absolute.
    workers : int, optional
        Worker processes of the LocalCluster (default 2, never more than the
        files to reduce).
    threads : int, optional
        Bands each reduction corrects at once (default: the executor's).
    overwrite : bool
        Reduce every input again, replacing existing outputs.  Without it, an
        output that holds this pipeline's reduction of its input (`finished_row`)
        is skipped, and any other existing output is refused.
    progress : bool
        Print the expected duration once the first file is reduced, and show a
        progress bar on a terminal (`~spherex_reduce.reduce.progress.run_tasks`).
    verify_checksum : bool
        False reads inputs whose checksums do not match (``--ignore-checksum``).

    Returns
    -------
    `BatchResult`
        The summary table (one row per input, in the order given), its path,
        and the rows of failed files (`~spherex_reduce.reduce.batch_summary.SummaryRow`,
        with ``error`` and ``kind``).

    Raises
    ------
    ConfigError
        Two inputs with the same output name, an output directory that is a
        file, an existing output that is not this pipeline's reduction of its
        input.
    FileNotFoundError
        An input, or the output directory's parent, does not exist.
    OSError
        The output directory cannot be written (read-only, full): found by
        writing the summary before any file is reduced, and named as the
        output directory.
    """
    pipeline = as_pipeline(pipeline)
    inputs = [Path(p) for p in inputs]
    if not inputs:
        raise ConfigError("no input files to reduce")
    for p in inputs:
        if p.is_dir():
            raise IsADirectoryError(f"input {p} is a directory; give the files in it")
        if not p.is_file():
            raise FileNotFoundError(f"no such file: {p}")
    outdir = Path(outdir)
    outputs = output_paths(inputs, outdir)
    if outdir.exists() and not outdir.is_dir():
        raise ConfigError(f"output directory {outdir} is a file: with several inputs, -o names "
                          "a directory for one output each")
    if not outdir.exists() and not outdir.absolute().parent.is_dir():
        raise FileNotFoundError(f"the directory {outdir.absolute().parent} of the output "
                                f"directory {outdir} does not exist")
    summary = outdir / SUMMARY_NAME
    if summary.is_dir():
        raise IsADirectoryError(f"{summary} names a directory; the summary table goes there")
    run = uuid.uuid4().hex
    rows, tasks = [], []
    for src, out in zip(inputs, outputs, strict=True):
        if out.is_dir():
            raise IsADirectoryError(f"{out} names a directory; it is the output of {src}")
        done = None
        if out.exists() and not overwrite:
            done = finished_row(out, input_digest(src), pipeline.config_hash)
        rows.append(None if done is None else replace(done, input=str(src), output=str(out)))
        if done is None:
            tasks.append(BatchTask(str(src.absolute()), str(out.absolute()), pipeline.config,
                                   pipeline.source, run=run, overwrite=overwrite,
                                   threads=threads, verify_checksum=verify_checksum,
                                   dq_bits=current_dq_bits(), index=len(rows) - 1))
    outdir.mkdir(exist_ok=True)
    table = SummaryFile(summary, pipeline)
    _writable(outdir, table, rows)  # before any work
    t0 = time.perf_counter()

    def collect(task, res):
        i = task.index
        for note in res.notes:
            log.warning("%s: %s", inputs[i], note)
        given = str(inputs[i]), str(outputs[i])  # the paths as the user gave them
        error = res.error.replace(task.input, given[0]).replace(task.output, given[1])
        rows[i] = replace(res, input=given[0], output=given[1], error=error, notes=())
        table.record([r for r in rows if r is not None], final=False)

    def died(task, exc):  # the worker died (e.g. out of memory): report, go on
        return SummaryRow(task.input, task.output, "failed", kind="unexpected",
                          error=f"{type(exc).__name__}: {_one_line(exc)}")

    if scheduler is None:
        workers = min(2 if workers is None else workers, max(1, len(tasks)))
    try:
        run_tasks(reduce_file, tasks, scheduler, workers, collect, died, noun="file",
                  progress=progress)
    finally:  # also when interrupted: what finished
        table.record([r for r in rows if r is not None])
    failed = [r for r in rows if r.status == "failed"]
    return BatchResult(summary_table(rows, pipeline), summary, failed, time.perf_counter() - t0)


def _writable(outdir, summary, rows):
    """Write the summary of what is already done; an output directory that cannot be
    written (read-only, full) is refused now, in one line naming it, before any work."""
    try:
        summary.record([r for r in rows if r is not None])
    except OSError as exc:
        if exc.errno is None or exc.errno in (errno.ENOENT, errno.ENOTDIR, errno.EISDIR):
            raise
        raise OSError(exc.errno, f"{exc.strerror or exc}; nothing was reduced",
                      f"output directory {outdir}") from None

