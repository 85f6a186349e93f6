"""Parameter sweeps on dask.distributed: grid × realisations × pipeline variants.

Each cell of a sweep is simulated (slopes by default), reduced with a pipeline
config and measured (band power and P(k)).  Cells run on a
`dask.distributed` cluster: an embedded `~distributed.LocalCluster` by
default, or an existing scheduler by address; ``scheduler="serial"`` runs them
in this process.

Determinism: the seed of a cell is a `numpy.random.SeedSequence` whose
entropy is the sweep's ``seed`` plus a hash of the cell's readout values and
realisation number (not the pipeline: pipeline variants reduce the same
simulated exposure, a paired comparison).  Results therefore do not depend on
the number of workers, the scheduling or which cells were already done.

With ``forecast`` each point also gets its exact expected band power and
P(k) (`~spherex_reduce.analysis.forecast.sweep`), drawn by `plot_sweep` as a
line beside the Monte Carlo points.

Sweep file (YAML or dict)::

    scene: {readout: {nframes: 74}}     # a scene as for simulate (or a path); the base case
    pipeline: spherex-default           # shipped name or path; a list runs variants
    grid: {skip: [1, 8, 24], ref_reads: [8, 32], ref_mode: [repeated, distributed]}
    realizations: 5                     # 0: no Monte Carlo, the forecast alone (forecast=True)
    seed: 2024
    mode: slopes                        # or ramps
    measure: {kmin: 0.03, kmax: 0.13, bins: 30, exclude_horizontal: false, mask_sources: false}
"""

import copy
import hashlib
import itertools
import json
import logging
import math
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.table import Table

from ..core.errors import ConfigError
from ..core.limits import check_count
from ..core.parameters import Parameter, validate_file
from ..io import atomic_output
from ..io.config import READOUT_PARAMETERS, load_yaml
from ..reduce.progress import run_tasks
from ..simulation import load_scene
from .case import (
    MEASURE,
    PIPELINES,
    REALIZATIONS,
    SCENE,
    SEED,
    SpectrumMeasure,
    measure_section,
    pipeline_section,
    realizations_section,
    run_case,
    scene_section,
    seed_section,
)
from .spectrum import BAND_KMAX, BAND_KMIN, band_label
from .table_cells import plain_value
from .tasks import CellFailure, CellResult, SweepTask

__all__ = ["SWEEP_PARAMETERS", "Sweep", "SweepResult", "load_sweep", "plot_sweep", "run_cell",
           "run_sweep"]

log = logging.getLogger(__name__)

#: Most cells a sweep file may ask for (realisations per cell: `.case.MAX_REALIZATIONS`).
MAX_CELLS = 100_000
#: The keys of a sweep file (`load_sweep`).  The grid maps readout keys to their values,
#: each checked by the cells (one that is invalid fails its cell only).
SWEEP_PARAMETERS = (
    SCENE,
    PIPELINES,
    Parameter("grid", None, (dict, type(None)), "readout key -> its values", fields=tuple(
        Parameter(p.name, None, (list, bool, int, float, str, dict, type(None)),
                  f"values of readout.{p.name}", length=(1, None))
        for p in READOUT_PARAMETERS)),
    replace(REALIZATIONS, minimum=0, doc="realisations per cell (0: the forecast alone)"),
    replace(SEED, default=None, doc="seed of the sweep (default: the scene's, or 0)"),
    Parameter("mode", "slopes", (str,), "the simulated output", choices=("slopes", "ramps")),
    MEASURE,
)


@dataclass(frozen=True)
class Sweep:
    """A validated sweep; build it with `load_sweep`."""

    scene: dict
    pipelines: tuple
    grid: dict
    realizations: int
    seed: int
    mode: str
    measure: dict
    source: str = "sweep"
    #: pipeline name -> shipped name, path or inline config (dict)
    pipeline_configs: dict = field(default_factory=dict)

    @property
    def keys(self):
        """Grid keys in file order."""
        return tuple(self.grid)

    @property
    def fingerprint(self):
        """Hash of what makes a cell's result (scene, seed, mode, measure, pipeline configs).

        The grid and the number of realisations are left out: a results file
        may be extended with more of either.
        """
        key = {"scene": self.scene, "seed": self.seed, "mode": self.mode,
               "measure": self.measure, "pipelines": self.pipeline_configs}
        return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[
            :16]

    def points(self):
        """Every grid point and pipeline: ``{grid values..., 'pipeline'}`` in a fixed order."""
        return [{**dict(zip(self.keys, values, strict=True)), "pipeline": pipe}
                for values in itertools.product(*self.grid.values()) for pipe in self.pipelines]

    def cells(self):
        """Every cell: ``{grid values..., 'pipeline', 'realization'}`` in a fixed order."""
        return [{**point, "realization": r} for point in self.points()
                for r in range(self.realizations)]

    def cell_seed(self, cell):
        """The `~numpy.random.SeedSequence` of a cell (from its readout values and realisation)."""
        key = {k: cell[k] for k in self.keys}
        key["realization"] = int(cell["realization"])
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).digest()
        words = [int.from_bytes(digest[i:i + 4], "little") for i in range(0, 16, 4)]
        return np.random.SeedSequence([int(self.seed), *words])

    def task(self, cell):
        """The `~spherex_reduce.analysis.tasks.SweepTask` of a cell, which `run_cell` runs."""
        scene = copy.deepcopy(self.scene)
        readout = dict(scene.get("readout") or {})
        readout.update({k: cell[k] for k in self.keys})
        scene["readout"] = readout
        scene.pop("seed", None)
        pipe = self.pipeline_configs.get(cell["pipeline"], cell["pipeline"])
        return SweepTask(cell=cell, scene=scene, pipeline=pipe,
                         entropy=self.cell_seed(cell).entropy, mode=self.mode,
                         measure=dict(self.measure))


def load_sweep(source):
    """Validate a sweep file (path, YAML text or dict).

    Raises
    ------
    ConfigError
        Unknown keys, grid keys that are not readout parameters, empty lists,
        an invalid scene (the values the grid varies are checked by each
        cell); the message names the entry.
    ResourceError
        More than `~spherex_reduce.analysis.case.MAX_REALIZATIONS`
        realisations or `MAX_CELLS` cells, or a scene that needs more memory
        than this machine has.

    Examples
    --------
    >>> from spherex_reduce.analysis.sweep import load_sweep
    >>> sw = load_sweep({"grid": {"skip": [1, 24]}, "realizations": 2})
    >>> len(sw.cells()), sw.pipelines
    (4, ('spherex-default',))
    """
    config, label = load_yaml(source, "sweep")
    values = validate_file(config, SWEEP_PARAMETERS, label)
    scene = scene_section(values["scene"], label)
    configs = pipeline_section(values["pipeline"], label, "pipeline")
    grid = config.get("grid") or {}
    clean = {key: v if isinstance(v, list) else [v]  # in the file's order
             for key, v in ((key, values["grid"][key]) for key in grid)}
    nreal = values["realizations"]
    if nreal:  # 0: forecast only (run_sweep's forecast)
        nreal = realizations_section(nreal, label)
    ncells = math.prod(len(v) for v in clean.values()) * len(configs) * max(nreal, 1)
    check_count(ncells, f"{label}: the number of cells (grid x pipelines x realizations)",
                MAX_CELLS)
    seed = values["seed"] if values["seed"] is not None else seed_section(
        scene.get("seed") or 0, label)
    mode = values["mode"]
    _check_scene(scene, clean, mode, label)
    measure = measure_section(values["measure"], label)
    return Sweep(scene, tuple(configs), clean, nreal, seed, mode, measure, label, configs)


def _check_scene(scene, grid, mode, label):
    """Validate the scene now, not in every cell at run time.

    The readout keys the grid varies take their defaults here: each cell
    checks its own values, and one that is invalid fails that cell only.
    """
    first = dict(scene)
    first["readout"] = {k: v for k, v in (scene.get("readout") or {}).items() if k not in grid}
    if isinstance(scene.get("output"), dict) or scene.get("output") is None:
        first["output"] = {**(scene.get("output") or {}), "mode": mode}
    try:
        load_scene(first)
    except ConfigError as exc:
        raise ConfigError(f"{label}: scene: {exc}") from None


# -- one cell -----------------------------------------------------------------------
def run_cell(task):
    """Simulate, reduce and measure one cell (`run_case`) of a
    `~spherex_reduce.analysis.tasks.SweepTask`; never raises.

    Returns a `~spherex_reduce.analysis.tasks.CellResult` (the cell's values,
    ``seed``: the entropy as text, ``band_power``, ``band_power_err``, ``std``
    of the unmasked pixels, ``masked_fraction``, ``k`` and ``power``: the
    binned P(k) as arrays, and ``seconds``), or a
    `~spherex_reduce.analysis.tasks.CellFailure` for a failed cell.
    """
    t0 = time.perf_counter()
    try:
        # a 64-bit integer drawn from the cell's SeedSequence: plain, printable, exact
        seed = int(np.random.SeedSequence(task.entropy).generate_state(1, np.uint64)[0])
        m = run_case(task.scene, task.pipeline, SpectrumMeasure(**task.measure),
                     seed=seed, mode=task.mode).measurement
        return CellResult(
            cell=task.cell, seed=json.dumps(task.entropy),
            band_power=float(m["band_power"].value),
            band_power_err=float(m["band_power_err"].value),
            unit=str(m["band_power"].unit), std=m["std"],
            masked_fraction=m["masked_fraction"],
            k=m["k"], power=m["power"], seconds=time.perf_counter() - t0)
    except Exception as exc:  # reported with the cell's parameters; the sweep goes on
        return CellFailure(task.cell, f"{type(exc).__name__}: {exc}",
                           traceback.format_exc(limit=6))


# -- the sweep ----------------------------------------------------------------------------
@dataclass
class SweepResult:
    """What `run_sweep` did: the full results table, and counts."""

    table: Table
    computed: int = 0
    skipped: int = 0
    failed: list = field(default_factory=list)
    seconds: float = 0.0


def _key(row, keys):
    return tuple(json.dumps(plain_value(row[k])) for k in (*keys, "pipeline", "realization"))


def _rows_to_table(rows, sweep, unit):
    keys = sweep.keys
    cols = {}
    for k in keys:
        cols[k] = [plain_value(r.cell[k]) for r in rows]
    cols["pipeline"] = [r.cell["pipeline"] for r in rows]
    cols["realization"] = np.array([r.cell["realization"] for r in rows], dtype=int)
    cols["seed"] = [r.seed for r in rows]
    for c in ("band_power", "band_power_err", "std", "masked_fraction", "seconds"):
        cols[c] = np.array([getattr(r, c) for r in rows], dtype=float)
    cols["k"] = np.array([r.k for r in rows], dtype=float) if rows else np.zeros((0, 0))
    cols["power"] = np.array([r.power for r in rows], dtype=float) if rows else np.zeros(
        (0, 0))
    t = Table(cols)
    if unit:
        for c in ("band_power", "band_power_err", "power"):
            t[c].unit = u.Unit(unit)
        t["std"].unit = u.Unit(unit) ** 0.5 / u.pix
        t["k"].unit = u.rad / u.pix
    t["seconds"].unit = u.s
    for name, text in SWEEP_COLUMNS.items():
        t[name].description = text
    return t


#: What each column of a sweep's results holds (besides the grid's own keys).
SWEEP_COLUMNS = {
    "pipeline": "pipeline of the cell (shipped name, file or label)",
    "realization": "realisation of the cell (0, 1, ...)",
    "seed": "seed of the realisation's simulation",
    "band_power": "mean P(k) over the band (band_kmin <= k <= band_kmax in meta)",
    "band_power_err": "standard error of band_power over the band's independent modes",
    "std": "standard deviation of the reduced image's unmasked pixels",
    "masked_fraction": "fraction of the image's pixels masked",
    "seconds": "time of the cell: simulation, reduction and measure",
    "k": "mean |k| of each bin of the cell's P(k)",
    "power": "P(k) of the cell in each bin (as the spectrum command's power column)",
}


def _merge(existing, new, keys):
    from astropy.table import vstack

    if existing is None or len(existing) == 0:
        out = new
    elif len(new) == 0:
        out = existing
    else:
        out = vstack([existing, new], metadata_conflicts="silent")
    if len(out):
        order = sorted(range(len(out)), key=lambda i: _key(out[i], keys))
        out = out[order]
    return out


def run_sweep(sweep, output=None, *, scheduler=None, workers=None, overwrite=False,
              progress=False, checkpoint_seconds=30.0, forecast=False):
    """Run every cell of a sweep not yet in ``output``; write and return the results.

    Parameters
    ----------
    sweep : `Sweep`, dict, YAML text or path
    output : str or `pathlib.Path`, optional
        ECSV results file.  If it exists (and not ``overwrite``), the cells it
        holds are skipped and the new rows added; it is rewritten atomically
        (also every ``checkpoint_seconds`` while running).
    scheduler : str or `distributed.Client`, optional
        ``None``: an embedded `~distributed.LocalCluster` of ``workers``
        processes (one thread each); an address (``tcp://host:8786``): an
        existing dask scheduler; a ``Client``: used as it is (not closed);
        ``"serial"``: in this process, no dask.
    workers : int, optional
        Worker processes of the LocalCluster (default 2; at most
        `spherex_reduce.core.limits.MAX_WORKERS`).
    overwrite : bool
        Ignore and replace an existing ``output``.
    progress : bool
        Print the expected duration on stderr, timed on the first cell, and show a
        progress bar on a terminal (`~spherex_reduce.reduce.progress.run_tasks`).
    forecast : bool
        Add the forecast of every row's point: the columns
        ``band_power_forecast`` and ``power_forecast``
        (`~spherex_reduce.analysis.forecast.sweep.SweepForecast`, in this
        process).  With ``realizations: 0`` the table is the forecast alone, one
        row per point (or ``output``'s Monte Carlo rows with the forecast added).

    Returns
    -------
    `SweepResult`
        ``table`` (one row per cell and realisation, sorted by cell), the
        numbers of cells computed and skipped, and the failures
        (``{"cell": ..., "error": ...}``), which are not written as rows, so a
        re-run tries them again.

    Raises
    ------
    ConfigError
        ``realizations: 0`` without ``forecast``; with ``forecast``, a pipeline
        or measure the forecast refuses (before any cell runs).

    Examples
    --------
    >>> from spherex_reduce.analysis.sweep import run_sweep
    >>> res = run_sweep({"scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4},
    ...                            "readout": {"nframes": 8}}, "pipeline": "unchop",
    ...                  "grid": {"skip": [1, 8]}, "realizations": 0}, forecast=True)
    >>> len(res.table), res.computed, "band_power" in res.table.colnames
    (2, 0, False)
    """
    sw = sweep if isinstance(sweep, Sweep) else load_sweep(sweep)
    if sw.realizations == 0 and not forecast:
        raise ConfigError(f"{sw.source}: realizations: 0 runs no Monte Carlo: it needs the "
                          "forecast (--forecast)")
    if forecast:
        from .forecast.sweep import SweepForecast

        forecast = SweepForecast(sw)  # refuses what it cannot forecast before any cell runs
    output = None if output is None else Path(output)
    existing = _read_results(output, sw, overwrite)
    todo = _cells_to_run(sw, existing)
    results = _Results(sw, existing, output, checkpoint_seconds, forecast or None)
    t0 = time.perf_counter()
    _run_cells(sw, todo, scheduler, workers, progress, results.add)
    table = results.table()  # the same table and metadata as the file: plot_sweep needs both
    results.write()
    failed = results.failed + (forecast.failed if forecast else [])
    return SweepResult(table, computed=len(results.rows), skipped=len(sw.cells()) - len(todo),
                       failed=failed, seconds=time.perf_counter() - t0)


def _read_results(output, sweep, overwrite):
    """The rows an earlier run of ``sweep`` left in ``output`` (None: none to extend).

    Raises
    ------
    ConfigError
        ``output`` is not a results table, or holds another sweep's.
    FileNotFoundError
        The directory of ``output`` does not exist.
    """
    if output is None:
        return None
    if overwrite or not output.exists():
        if not output.parent.is_dir():
            raise FileNotFoundError(f"output directory {output.parent} does not exist")
        return None
    try:
        existing = Table.read(output, format="ascii.ecsv")
    except (ValueError, KeyError, IndexError, TypeError) as exc:  # damaged or not ECSV
        reason = " ".join(str(exc).split())[:200]
        raise ConfigError(
            f"{output} is not a sweep's results table ({type(exc).__name__}: {reason}); "
            "choose another output or pass overwrite") from None
    if "realization" not in existing.colnames and "band_power_forecast" in existing.colnames:
        return None  # a forecast-only table: no Monte Carlo rows to extend
    missing = [c for c in (*sweep.keys, "pipeline", "realization", "band_power")
               if c not in existing.colnames]
    if missing:
        raise ConfigError(
            f"{output} has no column(s) {missing}: it holds another sweep; choose "
            "another output or pass overwrite"
        )
    old = existing.meta.get("fingerprint")
    if old is not None and old != sweep.fingerprint:
        raise ConfigError(
            f"{output} was made with a different scene, seed, mode, measure or "
            "pipeline config; its rows would not match this sweep: choose another "
            "output or pass overwrite"
        )
    return existing


def _cells_to_run(sweep, existing):
    """The cells of ``sweep`` whose rows are not in ``existing``, in the sweep's order."""
    done = set() if existing is None else {_key(r, sweep.keys) for r in existing}
    return [c for c in sweep.cells() if _key(c, sweep.keys) not in done]


def _run_cells(sweep, cells, scheduler, workers, progress, collect):
    """Run ``cells`` (in this process, or on dask) and pass each result row to ``collect``."""
    tasks = [sweep.task(c) for c in cells]

    def cell_failed(task, exc):  # a worker died: report the cell, go on
        return CellFailure(task.cell, f"{type(exc).__name__}: {exc}")

    run_tasks(run_cell, tasks, scheduler, workers, lambda task, res: collect(res), cell_failed,
              noun="cell", progress=progress)


class _Results:
    """The rows of a running sweep: the earlier ones, the new ones and the failures.

    `add` takes each cell's result row; the table (`table`) is written to
    ``output`` (`write`) at most every ``checkpoint_seconds`` while cells come
    in, and once more at the end.
    """

    def __init__(self, sweep, existing, output, checkpoint_seconds, forecast=None):
        self.sweep = sweep
        self.forecast = forecast
        self.existing = existing
        self.output = output
        self.checkpoint_seconds = checkpoint_seconds
        self.rows = []
        self.failed = []
        self.unit = None
        self.last_write = time.perf_counter()

    def add(self, res):
        """Keep a cell's `~spherex_reduce.analysis.tasks.CellResult` (or its failure, as
        `SweepResult` reports it); write a checkpoint when one is due."""
        if isinstance(res, CellFailure):
            self.failed.append(res.as_dict())
            log.warning("sweep cell %s failed: %s", res.cell, res.error)
            return
        self.unit = self.unit or res.unit
        self.rows.append(res)
        if time.perf_counter() - self.last_write > self.checkpoint_seconds:
            self.write()

    def table(self):
        """Every row so far, with the sweep's metadata (grid, measure, ...) in ``meta``."""
        sw = self.sweep
        table = _merge(self.existing, _rows_to_table(self.rows, sw, self.unit), sw.keys)
        if self.forecast is not None:
            table = (self.forecast.add_columns(table) if len(table)
                     else self.forecast.points())
        else:  # an earlier run's forecast columns would not cover the new rows
            from .forecast.sweep import FORECAST_COLUMNS

            table.remove_columns([c for c in FORECAST_COLUMNS if c in table.colnames])
        table.meta.update({"sweep": sw.source, "grid": {k: [plain_value(v) for v in vals]
                                                         for k, vals in sw.grid.items()},
                           "pipelines": list(sw.pipelines), "realizations": sw.realizations,
                           "seed": sw.seed, "mode": sw.mode, "measure": _jsonable(sw.measure),
                           "fingerprint": sw.fingerprint})
        return table

    def write(self):
        """Write the table, with the failures so far in ``meta``, atomically to ``output``."""
        if self.output is None:
            return
        table = self.table()
        if self.failed:
            table.meta["failed"] = [{"cell": f["cell"], "error": f["error"]}
                                    for f in self.failed]
        else:
            table.meta.pop("failed", None)
        with atomic_output(self.output, overwrite=True) as tmp:
            table.write(tmp, format="ascii.ecsv")
        self.last_write = time.perf_counter()


def _jsonable(d):
    return {k: (list(v) if isinstance(v, (list, tuple, np.ndarray)) else v) for k, v in d.items()}


def plot_sweep(table, x=None, title=""):
    """Band power against the first grid key, mean ± standard error over realisations.

    One series per combination of the other grid keys and the pipeline.  A
    table with the forecast columns (`run_sweep` with ``forecast``) also has
    the forecast of each series as a line, in the series' colour, the Monte
    Carlo means as points with error bars beside it; a forecast-only table
    (``realizations: 0``) has the lines alone.

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    from matplotlib.figure import Figure

    from ..io.plotting import unit_label

    # grid keys in column order: the sweep's order (a mapping read back from ECSV is sorted)
    grid = [c for c in table.colnames if c in table.meta.get("grid", {})]
    x = x or (grid[0] if grid else "realization")
    others = [k for k in grid if k != x] + ["pipeline"]
    mc, fc = "band_power" in table.colnames, "band_power_forecast" in table.colnames
    fig = Figure(figsize=(7, 5))
    ax = fig.subplots()
    groups, lines = {}, {}
    for row in table:
        label = ", ".join(f"{k}={plain_value(row[k])}" for k in others
                          if len(set(table[k])) > 1 or k != "pipeline")
        if mc:
            groups.setdefault(label, {}).setdefault(plain_value(row[x]), []).append(
                row["band_power"])
        if fc:
            lines.setdefault(label, {})[plain_value(row[x])] = float(row["band_power_forecast"])
    series = groups or lines
    numeric = all(isinstance(v, (int, float)) for g in series.values() for v in g)
    for label in series:
        xs = sorted(series[label]) if numeric else list(series[label])
        pos = xs if numeric else np.arange(len(xs))
        color = None
        if fc:
            (line,) = ax.plot(pos, [lines[label][v] for v in xs], "-",
                              label=f"{label}{', ' if label else ''}forecast")
            color = line.get_color()
        if mc:
            points = groups[label]
            mean = np.array([np.mean(points[v]) for v in xs])
            err = np.array([np.std(points[v], ddof=1) / np.sqrt(len(points[v]))
                            if len(points[v]) > 1 else 0.0 for v in xs])
            name = f"{label}{', ' if label else ''}Monte Carlo" if fc else label
            ax.errorbar(pos, mean, yerr=err, fmt="o" if fc else "o-", capsize=3, color=color,
                        label=name or None)
        if not numeric:
            ax.set_xticks(pos, [str(v) for v in xs])
    unit = table["band_power" if mc else "band_power_forecast"].unit
    ax.set_xlabel(x)
    ax.set_ylabel(f"band power ({unit_label(unit)})" if unit_label(unit) else "band power")
    ax.set_yscale("log")
    if any(series) or fc:
        ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    m = table.meta.get("measure", {})
    band = band_label(m.get("kmin", BAND_KMIN), m.get("kmax", BAND_KMAX))
    what = ("\nlines: forecast; points: Monte Carlo, mean ± s.e. over realisations"
            if fc and mc else " (forecast)" if fc else " (mean ± s.e. over realisations)")
    ax.set_title(title or f"band power {band}{what}", fontsize=10)
    return fig
