"""Judge correction strategies: residual noise and sky kept, on common random numbers.

For each realisation a scene is simulated once, a sky (`sky_field`) is added
to it (`inject_sky`) and every pipeline reduces that same exposure, and the
exposure without the sky (`run_case`, paired).  Each reduced image is measured
against the sky it was given (`measure_against_sky`): the band power of
``reduced − sky`` (the noise left), and from the cross-spectrum of the
difference of the two reductions with the sky the fraction of the sky kept,
per ``k`` bin and power-weighted over the band (the noise, the same in both,
cancels: no chance correlation with a faint sky moves it).  The white floor (`white_floor`)
is the band power of the noise model's white terms alone, which no correction
removes; each pipeline's *excess* is its noise band power above it.

Comparison file (YAML or dict)::

    scene: {readout: {nframes: 74}}       # a simulator scene or a path; output.mode: slopes|ramps
    sky: {rms: 0.05, index: -2.0, seed: 11}   # e/s, P(k) ∝ k^index, on light-sensitive pixels
    pipelines: [spherex-default, median, mine.yaml]   # shipped names, paths or inline configs
    realizations: 5
    seed: 2024                            # noise seeds (realisation r: SeedSequence([seed, r]))
    measure: {kmin: 0.03, kmax: 0.13, bins: 30, exclude_horizontal: false}

Determinism: the noise of realisation ``r`` comes from ``SeedSequence([seed,
r])`` and its sky from ``SeedSequence([sky.seed, r, SKY_TAG])``; every pipeline
sees both.  One dask task runs one realisation with every pipeline, so the
results do not depend on the number of workers.
"""

import contextlib
import dataclasses
import functools
import hashlib
import json
import logging
import math
import time
import traceback
from dataclasses import dataclass, replace

import numpy as np
from astropy import units as u
from astropy.table import Table

from ..core.errors import ConfigError, SpherexReduceError
from ..core.limits import check_count
from ..core.parameters import Parameter, validate_file
from ..io import atomic_output
from ..io.config import load_yaml
from ..io.plotting import save_figure
from ..noise import expected_slope_variance
from ..reduce.pipeline import as_pipeline
from ..reduce.progress import run_tasks, task_notes
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
from .figures.plots import plot_comparison
from .forecast.engine import active_white_variance
from .light import light_sensitive
from .photon_noise import photon_noise_label, photon_noise_power
from .sky import RMS_RANGE, inject_sky, measure_against_sky, sky_field
from .spectrum import EmptyBandError, band_label, band_power, band_theta
from .tasks import PipelineRow, RealizationFailure, RealizationResult, RealizationTask

__all__ = [
    "COMPARISON_PARAMETERS",
    "SKY_PARAMETERS",
    "CompareResult",
    "Comparison",
    "compare_strategies",
    "format_summary",
    "load_comparison",
    "run_realization",
    "summarize",
    "white_floor",
]

log = logging.getLogger(__name__)

_MEASURE_KEYS = ("kmin", "kmax", "bins", "exclude_horizontal")
#: The sky's spectral index must lie in this range (steeper fields are all k = 1).
INDEX_RANGE = (-6.0, 4.0)
#: Most pipelines one comparison may name.
MAX_PIPELINES = 100
#: The ``sky:`` of a comparison file: its rms, spectral index and seed.
SKY_PARAMETERS = (
    Parameter("rms", 0.05, (float,), "rms of the sky on the light-sensitive pixels (e/s; its "
              "power must be a normal float64)", minimum=RMS_RANGE[0], maximum=RMS_RANGE[1],
              unit="e/s"),
    Parameter("index", -2.0, (float,), "spectral index: P(k) ∝ k^index",
              minimum=INDEX_RANGE[0], maximum=INDEX_RANGE[1]),
    replace(SEED, doc="seed of the sky (realisation r: SeedSequence([seed, r, SKY_TAG]))"),
)
#: The keys of a comparison file (`load_comparison`).
COMPARISON_PARAMETERS = (
    SCENE,
    Parameter("sky", None, (dict, type(None)), "the sky injected", fields=SKY_PARAMETERS),
    replace(PIPELINES, name="pipelines"),
    REALIZATIONS,
    replace(SEED, default=None, doc="seed of the noise (default: the scene's, or 0)"),
    replace(MEASURE, fields=tuple(p for p in MEASURE.fields if p.name in _MEASURE_KEYS)),
)
#: Third word of the sky's SeedSequence, so that a sky seed equal to the noise seed
#: still gives a sky independent of the noise.
SKY_TAG = 0x736B79
_POWER = (u.electron / u.s) ** 2 * u.pix**2
#: The columns summarised per pipeline (mean and standard error over realisations).
SUMMARY_COLUMNS = ("noise_band_power", "excess", "sky_transfer", "seconds")


@dataclass(frozen=True)
class Comparison:
    """A validated comparison; build it with `load_comparison`."""

    scene: dict
    mode: str
    sky: dict
    pipelines: dict
    realizations: int
    seed: int
    measure: dict
    source: str = "comparison"

    def to_dict(self):
        """The comparison as plain values (written to the results' meta)."""
        return {"scene": self.scene, "sky": dict(self.sky), "pipelines": dict(self.pipelines),
                "realizations": self.realizations, "seed": self.seed,
                "measure": {k: (list(v) if isinstance(v, (list, tuple)) else v)
                            for k, v in self.measure.items()}}

    @property
    def fingerprint(self):
        """Hash of everything that makes the results."""
        text = json.dumps(self.to_dict(), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def noise_seed(self, r):
        """The `~numpy.random.SeedSequence` of realisation ``r``'s noise."""
        return np.random.SeedSequence([int(self.seed), int(r)])

    def sky_seed(self, r):
        """The `~numpy.random.SeedSequence` of realisation ``r``'s sky."""
        return np.random.SeedSequence([int(self.sky["seed"]), int(r), SKY_TAG])

    def task(self, r):
        """The `~spherex_reduce.analysis.tasks.RealizationTask` of realisation ``r``
        (`run_realization`)."""
        scene = dict(self.scene)
        scene.pop("seed", None)
        return RealizationTask(
            realization=int(r), scene=scene, pipelines=dict(self.pipelines),
            entropy=self.noise_seed(r).entropy, sky_entropy=self.sky_seed(r).entropy,
            rms=float(self.sky["rms"]), index=float(self.sky["index"]),
            measure=dict(self.measure))


def load_comparison(source):
    """Validate a comparison file (path, YAML text or dict).

    Its keys are described by `COMPARISON_PARAMETERS` (the ``sky`` by
    `SKY_PARAMETERS`), each checked as every YAML file is
    (`~spherex_reduce.core.parameters.validate_file`).

    Raises
    ------
    ConfigError
        Unknown keys; ``sky.rms`` outside `~spherex_reduce.analysis.sky.RMS_RANGE`
        (1e-20 to 1e20 e/s), ``sky.index`` outside
        `INDEX_RANGE`; a pipeline that is not a shipped name, a file or a valid
        config; an unreadable or invalid scene.  The message names the file and
        the entry (``cmp.yaml: sky.rms: ...``).
    ResourceError
        More realisations than ``MAX_REALIZATIONS`` of a sweep or pipelines
        than `MAX_PIPELINES`, or a scene this machine cannot hold.

    Examples
    --------
    >>> from spherex_reduce.analysis.compare import load_comparison
    >>> c = load_comparison({"pipelines": ["spherex-default", "median"], "realizations": 2})
    >>> list(c.pipelines), c.mode, c.sky
    (['spherex-default', 'median'], 'slopes', {'rms': 0.05, 'index': -2.0, 'seed': 0})
    >>> load_comparison({"sky": {"rms": -1}})
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: comparison: sky.rms: must be in [1e-20, 1e+20] e/s, ...
    """
    config, label = load_yaml(source, "comparison")
    values = validate_file(config, COMPARISON_PARAMETERS, label)
    scene = scene_section(values["scene"], label)
    try:
        sc = load_scene(scene)
    except ConfigError as exc:
        raise ConfigError(f"{label}: scene: {exc}") from None
    configs = pipeline_section(values["pipelines"], label, "pipelines")
    check_count(len(configs), f"{label}: pipelines", MAX_PIPELINES)
    for i, (name, pipe) in enumerate(configs.items()):
        try:
            as_pipeline(pipe)
        except (SpherexReduceError, OSError) as exc:
            text = " ".join(str(exc).split())
            raise ConfigError(f"{label}: pipelines[{i}] ({name}): {text}") from None
    nreal = realizations_section(values["realizations"], label)
    seed = values["seed"] if values["seed"] is not None else seed_section(
        scene.get("seed") or 0, label)
    measure = measure_section(values["measure"], label, _MEASURE_KEYS)
    measure.update(kmin=float(measure["kmin"]), kmax=float(measure["kmax"]))
    rows, cols = light_sensitive(sc.schedule.geometry)
    try:  # a band with no Fourier mode on the light-sensitive area: say so now
        band_power(np.ones((rows.stop - rows.start, cols.stop - cols.start)),
                   measure["kmin"], measure["kmax"])
    except EmptyBandError as exc:
        raise ConfigError(f"{label}: measure: {exc}") from None
    return Comparison(scene, sc.mode, values["sky"], configs, nreal, seed, measure, label)


def white_floor(scene):
    """Band power of the noise model's white terms alone: what no correction can remove.

    The sum over the components the pixels see of the slope variance of
    their white part (``alpha``; `~spherex_reduce.noise.expected_slope_variance`
    of ``component.replace(beta=0, gamma=0)``), and the light-sensitive pixels' own
    white read noise (`~spherex_reduce.analysis.forecast.engine.active_white_variance`).
    Each pixel's white noise is
    independent, so the image it makes is spatially white and its power
    spectrum (`power_spectrum`'s normalisation) is flat at that variance.

    Parameters
    ----------
    scene : dict, str, path or `~spherex_reduce.simulation.Scene`

    Returns
    -------
    `~astropy.units.Quantity`
        In (e/s)² pixel², the unit of a slope image's band power.

    Examples
    --------
    The paper's case (Table 2, S = 24, r = 32 distributed, c = 4, N = 74):

    >>> from spherex_reduce.analysis.compare import white_floor
    >>> white_floor(None).round(5)
    <Quantity 0.00131 electron2 pix2 / s2>
    """
    sc = scene if hasattr(scene, "schedule") else load_scene(scene)
    white = [c.replace(beta=0.0, gamma=0.0) for c in sc.components if c.seen_by_pixels]
    var = expected_slope_variance(white, sc.schedule) if white else 0.0 * _POWER / u.pix**2
    return var * u.pix**2 + active_white_variance(sc) * _POWER


def run_realization(task):
    """Simulate one realisation, reduce it with every pipeline with and without its sky,
    measure each.

    Returns a `~spherex_reduce.analysis.tasks.RealizationResult` (one
    `~spherex_reduce.analysis.tasks.PipelineRow` per pipeline:
    `measure_against_sky`'s values, ``pipeline``, ``seconds`` of the
    reduction alone; and ``warnings``: the warnings raised and logged, one
    line each (`~spherex_reduce.reduce.progress.task_notes`), for
    `compare_strategies` to show once every realisation has succeeded), or a
    `~spherex_reduce.analysis.tasks.RealizationFailure`; never raises.
    """
    with task_notes() as notes:
        res = _realization(task)
    if isinstance(res, RealizationResult):
        res = dataclasses.replace(res, warnings=tuple(notes))
    return res


def _realization(task):
    """`run_realization` without its warnings."""
    r = task.realization
    try:
        sc = load_scene(task.scene)
        sky = sky_field(sc.schedule.geometry, task.rms, task.index,
                        np.random.SeedSequence(task.sky_entropy))
        seed = int(np.random.SeedSequence(task.entropy).generate_state(1, np.uint64)[0])
        measure = functools.partial(measure_against_sky, sky=sky,
                                    measure=SpectrumMeasure(**task.measure),
                                    light=light_sensitive(sc.schedule.geometry))
        res = run_case(sc, task.pipelines, measure, seed=seed,
                       inject=functools.partial(inject_sky, sky=sky), paired=True)
        rows = tuple(PipelineRow(pipeline=label, realization=r, **res.measured[label],
                                 seconds=res.reduce_seconds[label])
                     for label in task.pipelines)
        return RealizationResult(r, rows, seed=json.dumps(task.entropy),
                                 sky_seed=json.dumps(task.sky_entropy))
    except Exception as exc:  # reported with the realisation; the others go on
        text = " ".join(f"{type(exc).__name__}: {exc}".split())
        return RealizationFailure(r, text, traceback.format_exc(limit=6))


@dataclass
class CompareResult:
    """What `compare_strategies` did: the results table (summary in ``meta``), seconds."""

    table: Table
    seconds: float = 0.0


#: What each column of a comparison's results holds.
COMPARE_COLUMNS = {
    "pipeline": "pipeline compared (its label in the comparison file)",
    "realization": "realisation (the same simulated noise and sky for every pipeline)",
    "seed": "seed of the realisation's simulated noise",
    "sky_seed": "seed of the realisation's injected sky",
    "noise_band_power": "band power of the reduced image minus the injected sky",
    "noise_band_power_err": "standard error of noise_band_power over the band's modes",
    "sky_transfer": "sum of P_cross(image - image without sky, sky) / sum of P_sky over the "
                    "band's modes",
    "seconds": "time of the pipeline's reduction alone (of the exposure without sky)",
    "masked_fraction": "fraction of the image's pixels masked",
    "excess": "noise_band_power minus the noise model's white floor (meta: floor)",
    "k": "mean |k| of each bin",
    "power": "P(k) of the reduced image minus the injected sky, in each bin",
    "transfer": "P_cross(image - image without sky, sky) / P_sky in each bin (1: sky kept, "
                "0: removed)",
}


def _table(results, comparison, floor, photon, photon_label):
    rows = [(row, res) for res in sorted(results, key=lambda x: x.realization)
            for row in res.rows]
    order = list(comparison.pipelines)
    rows.sort(key=lambda pair: (order.index(pair[0].pipeline), pair[0].realization))
    unit = u.Unit(rows[0][0].unit) * u.one
    cols = {"pipeline": [row.pipeline for row, _ in rows],
            "realization": np.array([row.realization for row, _ in rows], dtype=int),
            "seed": [res.seed for _, res in rows], "sky_seed": [res.sky_seed for _, res in rows]}
    for c in ("noise_band_power", "noise_band_power_err", "sky_transfer", "seconds",
              "masked_fraction"):
        cols[c] = np.array([getattr(row, c) for row, _ in rows], dtype=float)
    cols["excess"] = cols["noise_band_power"] - floor.to_value(unit)
    for c in ("k", "power", "transfer"):
        cols[c] = np.array([getattr(row, c) for row, _ in rows], dtype=float)
    t = Table(cols)
    for c in ("noise_band_power", "noise_band_power_err", "excess", "power"):
        t[c].unit = unit
    t["k"].unit = u.rad / u.pix
    t["seconds"].unit = u.s
    for name, text in COMPARE_COLUMNS.items():
        t[name].description = text
    t.meta.update({
        "comparison": comparison.source, "config": comparison.to_dict(),
        "fingerprint": comparison.fingerprint, "mode": comparison.mode,
        "floor": float(floor.to_value(unit)), "photon_noise": float(photon.to_value(unit)),
        "photon_noise_label": photon_label, "unit": unit.to_string(),
        "band": [float(comparison.measure["kmin"]), float(comparison.measure["kmax"])],
        "band_label": band_label(comparison.measure["kmin"], comparison.measure["kmax"]),
        "band_theta_exact": band_theta(comparison.measure["kmin"], comparison.measure["kmax"])})
    t.meta["summary"] = summarize(t)
    return t


def summarize(table):
    """Per pipeline, mean and standard error over realisations of `SUMMARY_COLUMNS`.

    Returns
    -------
    dict
        ``{pipeline: {column: {"mean": float, "sem": float}, "realizations": n}}``
        in the table's order (``sem`` NaN for a single realisation).
    """
    out = {}
    for name in dict.fromkeys(table["pipeline"]):
        sel = np.asarray(table["pipeline"]) == name
        entry = {"realizations": int(sel.sum())}
        for c in SUMMARY_COLUMNS:
            v = np.asarray(table[c][sel], dtype=float)
            sem = float(np.std(v, ddof=1) / np.sqrt(v.size)) if v.size > 1 else math.nan
            entry[c] = {"mean": float(np.mean(v)), "sem": sem}
        out[str(name)] = entry
    return out


def format_summary(table, reference=None):
    """The summary as a text table: one line per pipeline, mean ± standard error.

    Columns: noise band power, the white floor, the excess over it, the excess
    relative to ``reference``'s (a pipeline name; default the first), sky
    transfer and seconds per exposure (the reduction alone); then a line with
    the floor and the photon-noise level and their unit.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from spherex_reduce.analysis.compare import format_summary
    >>> t = Table({"pipeline": ["mean", "mean", "wiener", "wiener"],
    ...            "noise_band_power": [3.0, 3.2, 2.2, 2.4], "excess": [2.0, 2.2, 1.2, 1.4],
    ...            "sky_transfer": [1.0, 1.0, 0.99, 0.99], "seconds": [1.0, 1.0, 2.0, 2.0]},
    ...           meta={"floor": 1.0, "photon_noise": 10.0, "unit": "(e/s)2 pix2",
    ...                 "photon_noise_label": "1 e/s"})
    >>> print(format_summary(t))  # doctest: +NORMALIZE_WHITESPACE
    pipeline   noise band power    floor    excess   excess/mean   sky transfer  s/exposure
    mean    3.100e+00 ± 1.0e-01  1.000e+00  2.100e+00 ± 1.0e-01   1.000  1.000 ± 0.000   1.00
    wiener  2.300e+00 ± 1.0e-01  1.000e+00  1.300e+00 ± 1.0e-01   0.619  0.990 ± 0.000   2.00
    white floor 1.000e+00 (e/s)2 pix2; photon noise 1.000e+01 (e/s)2 pix2 (1 e/s)
    """
    summary = summarize(table)
    names = list(summary)  # the table's order (a mapping read back from ECSV is sorted)
    reference = names[0] if reference is None or reference not in summary else reference
    ref_excess = summary[reference]["excess"]["mean"]
    floor, unit = table.meta["floor"], table.meta.get("unit", "")
    width = max(8, *(len(n) for n in names))

    def pm(entry, fmt, efmt):
        sem = entry["sem"]
        return f"{entry['mean']:{fmt}} ± {sem:{efmt}}" if math.isfinite(sem) else \
            f"{entry['mean']:{fmt}}"

    rel = f"excess/{reference}"
    lines = [f"{'pipeline':<{width}}  {'noise band power':>19}  {'floor':>9}  {'excess':>19}  "
             f"{rel:>{max(len(rel), 6)}}  {'sky transfer':>13}  {'s/exposure':>10}"]
    for name in names:
        s = summary[name]
        ratio = s["excess"]["mean"] / ref_excess if ref_excess else math.nan
        lines.append(f"{name:<{width}}  {pm(s['noise_band_power'], '.3e', '.1e'):>19}  "
                     f"{floor:>9.3e}  {pm(s['excess'], '.3e', '.1e'):>19}  "
                     f"{ratio:>{max(len(rel), 6)}.3f}  {pm(s['sky_transfer'], '.3f', '.3f'):>13}"
                     f"  {s['seconds']['mean']:>10.2f}")
    lines.append(f"white floor {floor:.3e} {unit}; photon noise "
                 f"{table.meta['photon_noise']:.3e} {unit} ({table.meta['photon_noise_label']})")
    return "\n".join(lines)


def compare_strategies(comparison, output=None, *, plot=None, scheduler=None, workers=None,
                       overwrite=False, progress=False):
    """Run a comparison: every realisation, every pipeline; write the table (and plot).

    Parameters
    ----------
    comparison : `Comparison`, dict, YAML text or path
    output : str or path, optional
        ECSV results file, written atomically at the end (refused at once if it
        exists, unless ``overwrite``).
    plot : str or path, optional
        PNG of `~spherex_reduce.analysis.figures.plots.plot_comparison`, written with
        the table (both or neither).
    scheduler, workers
        As `~spherex_reduce.analysis.sweep.run_sweep` (``"serial"``: in this
        process).
    overwrite : bool
    progress : bool
        Print the expected duration on stderr, timed on the first realisation, and
        show a progress bar on a terminal (`~spherex_reduce.reduce.progress.run_tasks`).

    Returns
    -------
    `CompareResult`
        ``table``: one row per pipeline and realisation (``pipeline``,
        ``realization``, ``seed``, ``sky_seed``, ``noise_band_power``,
        ``noise_band_power_err``, ``excess``, ``sky_transfer``, ``seconds``,
        ``masked_fraction`` and the vectors ``k``, ``power``, ``transfer``);
        ``meta``: ``summary`` (`summarize`), ``floor``, ``photon_noise``,
        ``config``, ``fingerprint``.

    Raises
    ------
    SpherexReduceError
        A realisation failed (a pipeline that leaves ramps, a plugin error, a
        plugin strategy's result that fails
        `~spherex_reduce.reduce.steps.reference.strategy_checks.check_estimate`): one line
        naming the realisation; nothing is written.  The warnings of the
        realisations are issued (each once) only when all succeeded: none is
        shown before the error.

    Examples
    --------
    >>> from spherex_reduce.analysis.compare import compare_strategies
    >>> cmp = {"scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2,
    ...                               "ref_border": 4},
    ...                  "readout": {"skip": 4, "ref_reads": 8, "nframes": 4}},
    ...        "pipelines": ["spherex-default", "median"], "measure": {"kmin": 0.2,
    ...        "kmax": 1.0, "bins": 6}, "realizations": 2}
    >>> t = compare_strategies(cmp, scheduler="serial").table
    >>> len(t), sorted(t.meta["summary"])
    (4, ['median', 'spherex-default'])
    """
    cmp = comparison if isinstance(comparison, Comparison) else load_comparison(comparison)
    for path in (output, plot):
        if path is not None:
            atomic_output(path, overwrite)  # refuse now, not after the work
    t0 = time.perf_counter()
    sc = load_scene(cmp.scene)
    floor = white_floor(sc)
    photon = photon_noise_power(1 * u.electron / u.s, schedule=sc.schedule)
    tasks = [cmp.task(r) for r in range(cmp.realizations)]
    results = []
    run_tasks(run_realization, tasks, scheduler, workers, lambda task, res: results.append(res),
              lambda task, exc: RealizationFailure(task.realization,
                                                   f"{type(exc).__name__}: {exc}"),
              noun="realisation", progress=progress)
    failed = sorted((r for r in results if isinstance(r, RealizationFailure)),
                    key=lambda r: r.realization)
    if failed:
        more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
        raise SpherexReduceError(f"{cmp.source}: realisation {failed[0].realization} "
                                 f"failed: {failed[0].error}{more}")
    shown = set()
    for res in sorted(results, key=lambda r: r.realization):  # each once, all succeeded
        for text in res.warnings:
            if text not in shown:
                shown.add(text)
                log.warning("%s", text)
    label = photon_noise_label(1 * u.electron / u.s, schedule=sc.schedule)
    table = _table(results, cmp, floor, photon, label)
    with contextlib.ExitStack() as stack:  # the table and the plot: both or neither
        if output is not None:
            tmp = stack.enter_context(atomic_output(output, overwrite))
            table.write(tmp, format="ascii.ecsv")
        if plot is not None:
            tmp = stack.enter_context(atomic_output(plot, overwrite))
            save_figure(plot_comparison(table), tmp, overwrite=True)
    return CompareResult(table, time.perf_counter() - t0)
