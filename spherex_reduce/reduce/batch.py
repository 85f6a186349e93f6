"""Batch reduction on dask.distributed: many exposures, one pipeline, one output each.

`run_batch` reduces every input file with the same pipeline, each on a worker
of a `dask.distributed` cluster (the sweep's: an embedded
`~distributed.LocalCluster` of worker processes by default, an existing
scheduler by address, or ``"serial"`` in this process), and writes

- one output per input, ``OUTDIR/<input stem>_reduced.fits`` (`output_paths`),
  each written atomically as ``spherex-reduce reduce`` writes a single file;
- a summary table ``OUTDIR/summary.ecsv`` (`SUMMARY_NAME`): one row per input
  with its output, status (``done``, ``skipped`` or ``failed``), the median
  and robust standard deviation of the output's good pixels
  (`image_statistics`), the seconds it took and, for a failed file, the error.

A file that fails is reported and the others finish.  An output that already
holds this pipeline's reduction (it reads, and its ``SXRCONF`` is this
config's hash) is skipped, so an interrupted batch resumes; any other existing
output is refused before any work unless ``overwrite`` is given.  Each file is
reduced by `Pipeline.run <spherex_reduce.Pipeline.run>` exactly as a single
``reduce`` does: the numbers do not depend on the number of workers.
"""

import contextlib
import logging
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.stats import mad_std
from astropy.table import Table

from .._version import __version__
from ..core import dq
from ..core.errors import ConfigError, SpherexReduceError
from ..io import (
    atomic_output,
    checksum_policy,
    current_dq_bits,
    foreign_dq_bits,
    read,
    write,
)
from .integrations import reduce_input
from .pipeline import Pipeline, as_pipeline
from .scheduler import map_on_dask

__all__ = ["OUTPUT_SUFFIX", "STATUSES", "SUMMARY_NAME", "BatchResult", "image_statistics",
           "output_paths", "reduce_file", "run_batch"]

log = logging.getLogger(__name__)

#: Appended to an input's stem to name its output.
OUTPUT_SUFFIX = "_reduced.fits"
#: The summary table written in the output directory.
SUMMARY_NAME = "summary.ecsv"
#: What the summary's ``status`` column may say.
STATUSES = ("done", "skipped", "failed")
#: Compression suffixes and FITS extensions taken off an input's name (case-insensitive).
_COMPRESSED = (".gz", ".bz2", ".fz", ".z")
_FITS = (".fits", ".fit", ".fts")


def _stem(path):
    name = Path(path).name
    for suffixes in (_COMPRESSED, _FITS):
        for suffix in suffixes:
            if name.lower().endswith(suffix) and len(name) > len(suffix):
                name = name[:-len(suffix)]
                break
    return name


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
        path = Path(outdir) / f"{_stem(src)}{OUTPUT_SUFFIX}"
        if path.name in seen:
            raise ConfigError(f"inputs {seen[path.name]} and {src} would both be reduced to "
                              f"{path}: give each input once, or reduce files of the same name "
                              "into different directories")
        seen[path.name] = src
        out.append(path)
    return out


def image_statistics(exposure):
    """Median and robust standard deviation of an exposure's good pixels.

    Good pixels are finite with no `spherex_reduce.core.dq` flag but the
    informational ones (`~spherex_reduce.core.dq.image_usable`).  The robust
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
    unit = exposure.unit or u.dimensionless_unscaled
    if not good.any():
        return np.nan * unit, np.nan * unit
    values = data[good].astype(np.float64)
    return float(np.median(values)) * unit, float(mad_std(values)) * unit


# -- one file, on a worker ----------------------------------------------------------------
@contextlib.contextmanager
def _notes():
    """Collect the warnings issued and logged (at WARNING or above) while reducing a file.

    On a worker they would go to the worker's stderr, unlabelled; they are
    returned with the file's result and logged by `run_batch`, naming the file.
    """
    notes = []

    class Collect(logging.Handler):
        def emit(self, record):
            notes.append(" ".join(record.getMessage().split()))

    logger = logging.getLogger("spherex_reduce")
    handler = Collect(logging.WARNING)
    propagate, logger.propagate = logger.propagate, False
    logger.addHandler(handler)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield notes
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate
        for w in caught:
            text = " ".join(str(w.message).split())
            if text not in notes:
                notes.append(text)


def _one_line(exc):
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return " ".join(str(exc).split()) or type(exc).__name__


def reduce_file(task):
    """Reduce one file as ``spherex-reduce reduce`` does; never raises.

    Parameters
    ----------
    task : dict
        ``input`` and ``output`` (paths), ``config`` and ``source`` (the
        pipeline's effective configuration and label), ``overwrite``,
        ``threads`` (None: the executor's default), ``verify_checksum`` and ``dq_bits``
        (the policies of the command, which a worker process does not share).

    Returns
    -------
    dict
        ``input``, ``output``, ``status`` (``done`` or ``failed``),
        ``median`` and ``robust_std`` (floats, in ``unit``; `image_statistics`
        of the output), ``seconds``, ``notes`` (warnings, one line each) and,
        for a failed file, ``error`` (one line) and ``kind``: ``input`` for a
        `~spherex_reduce.SpherexReduceError` or an `OSError` (bad input or
        environment, exit status 2 on the command line), ``unexpected``
        otherwise (a bug, status 1).
    """
    t0 = time.perf_counter()
    row = {"input": task["input"], "output": task["output"], "status": "failed",
           "median": np.nan, "robust_std": np.nan, "unit": "", "error": "", "kind": "",
           "notes": []}
    try:
        with _notes() as notes, checksum_policy(verify=task.get("verify_checksum", True)), \
                foreign_dq_bits(task.get("dq_bits", current_dq_bits())):
            row["notes"] = notes
            pipeline = Pipeline(task["config"], source=task["source"])
            result, images = reduce_input(task["input"], pipeline, threads=task.get("threads"))
            write(result, task["output"], overwrite=task.get("overwrite", False), images=images)
            median, sigma = image_statistics(result)
        row.update(status="done", median=median.value, robust_std=sigma.value,
                   unit=median.unit.to_string())
    except Exception as exc:  # reported with the file's name; the batch goes on
        expected = isinstance(exc, (SpherexReduceError, OSError))
        row["error"] = _one_line(exc) if expected else f"{type(exc).__name__}: {_one_line(exc)}"
        row["kind"] = "input" if expected else "unexpected"
    row["seconds"] = time.perf_counter() - t0
    return row


def _done_output(path, config_hash):
    """The summary row of an existing output that holds this config's reduction; else raise."""
    try:
        existing = read(path, verify_checksum=True)
    except (SpherexReduceError, OSError) as exc:
        raise ConfigError(f"{path} exists and is not a reduced file ({_one_line(exc)}): pass "
                          "--overwrite to replace it, or choose another directory") from None
    made = existing.header.get("SXRCONF")
    if made != config_hash:
        raise ConfigError(f"{path} exists and was made with another pipeline config (SXRCONF "
                          f"{made}, this config's is {config_hash}): pass --overwrite to replace "
                          "it, or choose another directory")
    median, sigma = image_statistics(existing)
    return {"status": "skipped", "median": median.value, "robust_std": sigma.value,
            "unit": median.unit.to_string(), "seconds": 0.0, "error": "", "kind": "",
            "notes": []}


# -- the batch ----------------------------------------------------------------------------
@dataclass
class BatchResult:
    """What `run_batch` did: the summary table and the rows of failed files."""

    table: Table
    summary: Path | None = None
    failed: list = field(default_factory=list)
    seconds: float = 0.0

    def count(self, status):
        """How many inputs have ``status`` (``done``, ``skipped`` or ``failed``)."""
        return int(np.sum(self.table["status"] == status)) if len(self.table) else 0


def _summary(rows, pipeline):
    units = {r["unit"] for r in rows if r["status"] != "failed"}
    t = Table({
        "input": [str(r["input"]) for r in rows],
        "output": [str(r["output"]) for r in rows],
        "status": [r["status"] for r in rows],
        "median": np.array([r["median"] for r in rows], dtype=float),
        "robust_std": np.array([r["robust_std"] for r in rows], dtype=float),
        "seconds": np.array([r["seconds"] for r in rows], dtype=float),
        "error": [r["error"] for r in rows],
    })
    if len(units) == 1:
        unit = u.Unit(units.pop())
        t["median"].unit = t["robust_std"].unit = unit
    elif units:  # outputs in different units (e.g. ADU and electrons): one per row
        t.add_column([r["unit"] for r in rows], name="unit", index=5)
    t["seconds"].unit = u.s
    t["median"].description = "median of the output's finite pixels with DQ 0"
    t["robust_std"].description = "astropy.stats.mad_std of the same pixels"
    t.meta.update({"pipeline": pipeline.source, "config_hash": pipeline.config_hash,
                   "version": __version__})
    return t


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
        rewritten on every run.
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
        output that holds this pipeline's reduction (its ``SXRCONF`` is the
        config hash) is skipped, and any other existing output is refused.
    progress : bool
        A tqdm progress bar over the files.
    verify_checksum : bool
        False reads inputs whose checksums do not match (``--ignore-checksum``).

    Returns
    -------
    `BatchResult`
        The summary table (one row per input, in the order given), its path,
        and the rows of failed files (with ``error`` and ``kind``).

    Raises
    ------
    ConfigError
        Two inputs with the same output name, an output directory that is a
        file, an existing output that is not this pipeline's reduction.
    FileNotFoundError
        An input, or the output directory's parent, does not exist.
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
    rows, tasks = [], []
    for src, out in zip(inputs, outputs, strict=True):
        if out.is_dir():
            raise IsADirectoryError(f"{out} names a directory; it is the output of {src}")
        if out.exists() and not overwrite:
            rows.append({"input": str(src), "output": str(out),
                         **_done_output(out, pipeline.config_hash)})
            continue
        rows.append(None)
        tasks.append({"input": str(src.absolute()), "output": str(out.absolute()),
                      "config": pipeline.config, "source": pipeline.source,
                      "overwrite": overwrite, "threads": threads,
                      "verify_checksum": verify_checksum, "dq_bits": current_dq_bits(),
                      "index": len(rows) - 1})
    outdir.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    bar = _bar(len(inputs), progress)
    bar.update(len(inputs) - len(tasks))

    def collect(task, res):
        i = task["index"]
        for note in res.pop("notes", []):
            log.warning("%s: %s", inputs[i], note)
        res["input"], res["output"] = str(inputs[i]), str(outputs[i])  # as the user gave them
        for given, sent in ((res["input"], task["input"]), (res["output"], task["output"])):
            res["error"] = res.get("error", "").replace(sent, given)
        rows[i] = res
        bar.update(1)

    try:
        if tasks and scheduler == "serial":
            for task in tasks:
                collect(task, reduce_file(task))
        elif tasks:
            _on_dask(tasks, scheduler, workers, collect)
    finally:
        bar.close()
    table = _summary(rows, pipeline)
    with atomic_output(summary, overwrite=True) as tmp:
        table.write(tmp, format="ascii.ecsv")
    failed = [r for r in rows if r["status"] == "failed"]
    return BatchResult(table, summary, failed, time.perf_counter() - t0)


def _on_dask(tasks, scheduler, workers, collect):
    """Run `reduce_file` on every task on dask; ``collect(task, row)`` as each finishes."""
    if scheduler is None:
        workers = min(2 if workers is None else workers, len(tasks))

    def died(task, exc):  # the worker died (e.g. out of memory): report, go on
        return {"status": "failed", "median": np.nan, "robust_std": np.nan, "unit": "",
                "seconds": np.nan, "kind": "unexpected",
                "error": f"{type(exc).__name__}: {_one_line(exc)}"}

    map_on_dask(reduce_file, tasks, scheduler, workers, collect, died)


def _bar(total, progress):
    from tqdm import tqdm

    return tqdm(total=total, disable=not progress, desc="reduce", unit="file")

