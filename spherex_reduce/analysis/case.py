"""Simulate, reduce and measure one case: the one route of the demo, the figures and sweeps.

`run_case` simulates a scene once (in memory, or into a FITS file that the
pipelines then stream), reduces the exposure with one or more pipelines (a
paired comparison: every pipeline sees the same simulated exposure) and
applies a measure to each reduced image.  `SpectrumMeasure` is the standard
measure: P(k) and the band power, with the options of a sweep's ``measure``.

A file of cases (a sweep, a comparison, a design) describes its keys by
`~spherex_reduce.core.parameters.Parameter` tables; the keys they share are
here: `SCENE`, `PIPELINES`, `REALIZATIONS`, `SEED` and `MEASURE`.  Their
values are then read by `scene_section` (a path read relative to the file),
`pipeline_section` (each pipeline named), `realizations_section` (at most
`MAX_REALIZATIONS`), `seed_section` and `measure_section`; each raises a
`~spherex_reduce.core.errors.ConfigError` whose message names the file
(``label``) and the key.
"""

import itertools
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError, SpherexReduceError
from ..core.limits import check_count
from ..core.parameters import Parameter, validate_file
from ..io.config import load_yaml
from ..reduce.pipeline import as_pipeline
from ..simulation import simulate, simulate_to_fits
from ..simulation.scene import scene_in_electrons
from .light import light_sensitive_image
from .spectrum import BAND_KMAX, BAND_KMIN, band_power, power_spectra

__all__ = ["MAX_BINS", "MAX_REALIZATIONS", "MEASURE", "PIPELINES", "REALIZATIONS", "SCENE",
           "SEED", "CaseResult", "SpectrumMeasure", "measure_section", "pipeline_section",
           "realizations_section", "run_case", "scene_section", "seed_section"]


@dataclass(frozen=True)
class SpectrumMeasure:
    """Spatial power spectrum and band power of a reduced image (a sweep's ``measure``).

    Parameters
    ----------
    kmin, kmax : float
        Band of `band_power`, rad/pixel (default: the paper's θ = 5–20′).
    bins : int or sequence of float
        Number of logarithmic bins from ``2π / max(ny, nx)`` to π, or the
        edges (rad/pixel), of `power_spectrum`.
    exclude_horizontal, mask_sources : bool
        As `power_spectrum`.

    Calling it on an image returns a dict: ``spectrum`` (the table of
    `power_spectrum`), ``k`` and ``power`` (every bin, empty ones NaN, so
    that measures of images of one shape share one ``k`` grid),
    ``band_power`` and ``band_power_err`` (`~astropy.units.Quantity`),
    ``std`` (of the unmasked finite pixels) and ``masked_fraction``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.case import SpectrumMeasure
    >>> m = SpectrumMeasure(bins=8)(np.random.default_rng(3).normal(0, 2, (128, 128)))
    >>> m["k"].shape, bool(abs(m["band_power"].value - 4) < 4 * m["band_power_err"].value)
    ((8,), True)
    """

    kmin: float = BAND_KMIN
    kmax: float = BAND_KMAX
    bins: object = 30
    exclude_horizontal: bool = False
    mask_sources: bool = False

    def edges(self, shape):
        """The bin edges (rad/pixel) for an image of ``shape``: fixed, so measures line up.

        Examples
        --------
        >>> from spherex_reduce.analysis.case import SpectrumMeasure
        >>> SpectrumMeasure(bins=2).edges((64, 32)).round(3).tolist()
        [0.098, 0.555, 3.142]
        """
        if isinstance(self.bins, int):
            return np.geomspace(2 * np.pi / max(shape), np.pi, self.bins + 1)
        return np.asarray(self.bins, float)

    def every_bin(self, spectrum, column="power"):
        """``(k, values)`` of a spectrum's table on every bin of `edges`, empty ones NaN.

        ``spectrum`` is a table of `power_spectrum` or
        `~spherex_reduce.analysis.forecast` (the image shape in its ``meta``), so
        that the spectra of images of one shape share one ``k`` grid.

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce.analysis import power_spectrum
        >>> from spherex_reduce.analysis.case import SpectrumMeasure
        >>> m = SpectrumMeasure(bins=12)
        >>> spec = power_spectrum(np.ones((8, 8)), bins=m.edges((8, 8)))
        >>> k, p = m.every_bin(spec)
        >>> k.size, int(np.isnan(k).sum()) == 12 - len(spec)
        (12, True)
        """
        bins = self.edges(tuple(spectrum.meta["shape"]))
        k = np.full(len(bins) - 1, np.nan)
        values = np.full(len(bins) - 1, np.nan)
        pos = np.searchsorted(bins, np.asarray(spectrum["k_lo"]) * (1 + 1e-12)) - 1
        k[pos] = np.asarray(spectrum["k"])
        values[pos] = np.asarray(spectrum[column])
        return k, values

    def __call__(self, image):
        kw = {"exclude_horizontal": bool(self.exclude_horizontal),
              "mask_sources": bool(self.mask_sources)}
        edges = self.edges(np.shape(getattr(image, "data", image)))
        spec, band = power_spectra(image, [edges, [self.kmin, self.kmax]], **kw)  # one FFT
        k, power = self.every_bin(spec)
        bp, err = band_power(band, self.kmin, self.kmax, return_error=True)
        data = np.asarray(getattr(image, "data", image), dtype=float)
        good = np.isfinite(data)
        if getattr(image, "mask", None) is not None:
            good &= np.asarray(image.mask) == 0
        return {"spectrum": spec, "k": k, "power": power, "band_power": bp,
                "band_power_err": err,
                "std": float(np.std(data[good])) if good.any() else np.nan,
                "masked_fraction": float(spec.meta["masked_fraction"])}


@dataclass
class CaseResult:
    """What `run_case` did, per pipeline label (see `run_case`)."""

    #: the seed the scene was simulated with (as given; None: the scene's own)
    seed: object
    #: label -> the measure's result (absent without a measure)
    measured: dict = field(default_factory=dict)
    #: label -> reduced `~spherex_reduce.Exposure` (only with ``keep=True``)
    reduced: dict = field(default_factory=dict)
    #: ``"simulate"`` and, per label, the reduction and measurement, in seconds
    seconds: dict = field(default_factory=dict)
    #: per label, the reduction alone (``Pipeline.run``; paired, the first of its two), in
    #: seconds
    reduce_seconds: dict = field(default_factory=dict)
    #: the simulated raw exposure (in memory, with ``keep=True``) or its FITS path
    raw: object = None

    @property
    def measurement(self):
        """The one measure's result of a case run with a single pipeline."""
        if len(self.measured) != 1:
            raise SpherexReduceError(f"the case has {len(self.measured)} measurements; "
                                     "use .measured[label]")
        return next(iter(self.measured.values()))


def run_case(scene, pipelines, measure=None, *, seed=None, mode=None, raw_path=None,
             overwrite=False, progress=False, keep=False, inject=None, paired=False):
    """Simulate a scene once, reduce it with each pipeline and measure each reduced image.

    Parameters
    ----------
    scene : dict, str, path or `~spherex_reduce.simulation.Scene`
        As `~spherex_reduce.simulation.simulate`.
    pipelines : pipeline, or a mapping of label -> pipeline
        Each a `~spherex_reduce.reduce.pipeline.Pipeline`, a shipped name, a path or an
        inline config (`as_pipeline`).  A single one is labelled as given (a
        name or path), by its ``name`` (a config) or its ``source`` (a
        `~spherex_reduce.reduce.pipeline.Pipeline`).  Every pipeline reduces the same
        simulated exposure.
    measure : callable, dict or None
        Called with the light-sensitive pixels of each reduced image
        (`~spherex_reduce.analysis.light_sensitive_image`, a
        `~astropy.nddata.CCDData`: the reference pixels are no statistic of
        the image); a dict gives the options of a `SpectrumMeasure`.  None: no
        measurement.
    seed : int or `numpy.random.SeedSequence`, optional
        Overrides the scene's seed.
    mode : {'slopes', 'ramps'}, optional
        Overrides the scene's ``output.mode``.
    raw_path : path, optional
        Simulate into this FITS file (written with `simulate_to_fits`, frame
        by frame) and reduce from it; otherwise everything is in memory.
    overwrite, progress : bool
        For the raw file and the pipelines.
    keep : bool
        Keep the reduced exposures (and the in-memory raw exposure).
    inject : callable, optional
        ``inject(raw) -> raw``: applied once to the simulated exposure before
        any pipeline sees it (e.g. `~spherex_reduce.analysis.inject_sky`
        adding a sky); it must return a new exposure, not change its input.
        In memory only (not with ``raw_path``).
    paired : bool
        With ``inject`` and a measure: every pipeline also reduces the
        exposure as simulated, before ``inject``, and the measure is called
        with both images, ``measure(image, without)``: the same noise with and
        without what was injected, so that their difference is what the
        pipeline made of it (`~spherex_reduce.analysis.measure_against_sky`).
        Each pipeline then runs twice, the exposure without first (its time
        is ``reduce_seconds``: the first exposure's, as without ``paired``).

    Returns
    -------
    `CaseResult`

    Raises
    ------
    SpherexReduceError
        A pipeline that leaves ramps when there is a measure; ``paired``
        without ``inject`` and a measure.

    Examples
    --------
    >>> from spherex_reduce.analysis import run_case
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2, "ref_border": 4},
    ...          "readout": {"skip": 4, "ref_reads": 8, "nframes": 4, "phantom_reads": 2}}
    >>> res = run_case(scene, "spherex-default", {"bins": 4}, seed=1)
    >>> m = res.measured["spherex-default"]
    >>> m["band_power"].unit, len(m["k"])
    (Unit("electron2 pix2 / s2"), 4)

    Two pipelines on one simulated exposure (a paired comparison):

    >>> raw = {"name": "raw", "steps": [{"unchop": {}}]}
    >>> res = run_case(scene, {"raw": raw, "corrected": "spherex-default"}, {"bins": 4}, seed=1)
    >>> sorted(res.measured), sorted(res.seconds)
    (['corrected', 'raw'], ['corrected', 'raw', 'simulate'])

    Paired: the measure sees each pipeline's image with and without what was injected:

    >>> def plus_one(raw):
    ...     return raw.replace(data=raw.data.data + 1.0)
    >>> res = run_case(scene, raw, lambda image, without: float((image.data - without.data).mean()),
    ...                seed=1, inject=plus_one, paired=True)
    >>> round(res.measurement, 9)
    1.0
    """
    if isinstance(pipelines, dict) and "steps" not in pipelines:
        pipes = {str(label): as_pipeline(p) for label, p in pipelines.items()}
    else:
        p = as_pipeline(pipelines)
        pipes = {str(pipelines) if isinstance(pipelines, (str, Path)) else p.source: p}
    if isinstance(measure, dict):
        measure = SpectrumMeasure(**measure)
    if inject is not None and raw_path is not None:
        raise SpherexReduceError("run_case: inject works on an exposure in memory, not with "
                                 "raw_path")
    if paired and (inject is None or measure is None):
        raise SpherexReduceError("run_case: paired needs inject and a measure")
    result = CaseResult(seed)
    t0 = time.perf_counter()
    if raw_path is not None:
        raw = Path(raw_path)
        simulate_to_fits(scene, raw, mode=mode, seed=seed, overwrite=overwrite,
                         progress=progress)
    else:
        raw = simulate(scene, mode=mode, seed=seed)
    result.seconds["simulate"] = time.perf_counter() - t0
    without = {}  # paired: each pipeline's image before inject (no second raw is kept)
    for label, pipeline in (pipes.items() if paired else ()):
        t0 = time.perf_counter()
        reduced = pipeline.run(raw, progress=progress)
        result.reduce_seconds[label] = time.perf_counter() - t0
        without[label] = _measured_image(reduced, label)
        result.seconds[label] = time.perf_counter() - t0
    if inject is not None:
        raw = inject(raw)
    result.raw = raw if raw_path is not None or keep else None
    for label, pipeline in pipes.items():
        t0 = time.perf_counter()
        reduced = pipeline.run(raw, progress=progress)
        result.reduce_seconds.setdefault(label, time.perf_counter() - t0)
        if keep:
            result.reduced[label] = reduced
        if measure is not None:
            image = _measured_image(reduced, label)
            result.measured[label] = measure(image, without.pop(label)) if paired else \
                measure(image)
        result.seconds[label] = result.seconds.get(label, 0.0) + time.perf_counter() - t0
    return result


def _measured_image(reduced, label):
    """The light-sensitive pixels of a reduced image, for a measure; ramps refused."""
    if reduced.is_ramp:
        raise SpherexReduceError(f"pipeline {label} left ramps; it must end with an "
                                 "image (fit_ramp) to be measured")
    return light_sensitive_image(reduced)


#: Most realisations a sweep (per cell), a comparison or a design may ask for.
MAX_REALIZATIONS = 10_000
#: Most k bins of a measure.
MAX_BINS = 10_000

# -- the keys a file of cases shares (a sweep, a comparison, a design) ------------------

#: ``scene:``: a scene (mapping) or the path of one, relative to the file (`scene_section`).
SCENE = Parameter("scene", None, (dict, str, type(None)),
                  "a scene (as for simulate) or the path of one")
#: ``pipeline:``: a shipped name, a path, an inline config or a list of them
#: (`pipeline_section`).
PIPELINES = Parameter("pipeline", "spherex-default", (str, dict, list),
                      "a shipped name, a path, an inline config or a list of them",
                      items=Parameter("", None, (str, dict), "a pipeline"), length=(1, None))
#: ``realizations:``: Monte Carlo realisations (the most: `realizations_section`).
REALIZATIONS = Parameter("realizations", 1, (int,), "Monte Carlo realisations", minimum=1)
#: ``seed:``: the seed of the random numbers.
SEED = Parameter("seed", 0, (int,), "seed of the random numbers", minimum=0)
#: ``measure:``: the options of a `SpectrumMeasure` (`measure_section`).
MEASURE = Parameter("measure", None, (dict, type(None)), "the measure", fields=(
    Parameter("kmin", SpectrumMeasure.kmin, (int, float), "band start (rad/pixel)", minimum=0),
    Parameter("kmax", SpectrumMeasure.kmax, (int, float), "band end (rad/pixel)", minimum=0),
    Parameter("bins", SpectrumMeasure.bins, (int, list),
              "number of log bins, or the bin edges (rad/pixel)", minimum=1, maximum=MAX_BINS,
              items=Parameter("", None, (int, float), "a bin edge (rad/pixel)", minimum=0),
              length=(2, MAX_BINS + 1)),
    Parameter("exclude_horizontal", SpectrumMeasure.exclude_horizontal, (bool,),
              "leave out the k_y = 0 row"),
    Parameter("mask_sources", SpectrumMeasure.mask_sources, (bool,), "mask sources"),
))


def scene_section(scene, label):
    """The ``scene:`` of a file of cases: a mapping, or a path (relative to the file).

    Parameters
    ----------
    scene : dict, str or None
        The section as read (None: all defaults).
    label : str
        The file's path or name, for messages and relative paths.

    Returns
    -------
    dict
        The scene in electrons: a scene in adu (``unit: adu``) converted with its
        ``gain`` (`~spherex_reduce.simulation.scene.scene_in_electrons`), since the
        cases, the forecasts and the band powers compared are in electrons.

    Raises
    ------
    ConfigError
        Not a mapping or a path, a file that cannot be read, or a scene in adu
        without a gain; the message names ``label``.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import scene_section
    >>> scene_section({"readout": {"nframes": 4}}, "sweep")
    {'readout': {'nframes': 4}}
    >>> scene_section("no-such-scene.yaml", "cmp.yaml")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: cmp.yaml: scene: scene file not found: ...
    """
    scene = validate_file({"scene": scene}, (SCENE,), label)["scene"] or {}
    if isinstance(scene, str):
        base = Path(label).parent if Path(label).is_file() else Path(".")
        path = Path(scene) if Path(scene).is_absolute() else base / scene
        try:
            scene, _ = load_yaml(path if path.is_file() else Path(scene), "scene")
        except (OSError, ConfigError) as exc:
            raise ConfigError(f"{label}: scene: {exc}") from None
    if not isinstance(scene, dict):
        return scene  # refused where it is loaded, as before
    try:
        return scene_in_electrons(scene, Path(label).name)
    except ConfigError as exc:
        raise ConfigError(f"{label}: scene: {exc}") from None


def pipeline_section(pipes, label, key="pipeline"):
    """Name -> pipeline (shipped name, path or inline dict) of a file of cases' ``key``.

    A path is taken relative to the file when it names a file there; an
    inline config is named by its ``name`` (``pipeline-<i>`` without one).

    Raises
    ------
    ConfigError
        Not a name, path, inline config or non-empty list of them (`PIPELINES`);
        a name used twice.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import pipeline_section
    >>> pipeline_section(["spherex-default", {"name": "raw", "steps": []}], "sweep")
    {'spherex-default': 'spherex-default', 'raw': {'name': 'raw', 'steps': []}}
    >>> pipeline_section([], "sweep", "pipelines")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: sweep: pipelines: expected a list of at least 1 ...
    """
    pipes = validate_file({key: pipes}, (replace(PIPELINES, name=key),), label)[key]
    pipes = [pipes] if isinstance(pipes, (str, dict)) else pipes
    base = Path(label).parent if Path(label).is_file() else None
    configs = {}
    for i, p in enumerate(pipes):
        if isinstance(p, dict):
            name = str(p.get("name") or f"pipeline-{i}")
        else:
            name = p
            p = str(base / p) if base is not None and (base / p).is_file() else p
        if name in configs:
            raise ConfigError(f"{label}: {key}[{i}]: name {name!r} is used twice")
        configs[name] = p
    return configs


def realizations_section(nreal, label):
    """The number of realisations: `REALIZATIONS`, and at most `MAX_REALIZATIONS`.

    Raises
    ------
    ConfigError
        Not a whole number >= 1; the message names ``label``.
    ResourceError
        More than `MAX_REALIZATIONS`.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import realizations_section
    >>> realizations_section(5, "sweep")
    5
    >>> realizations_section(0, "sweep")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: sweep: realizations: must be >= 1, got 0
    """
    nreal = validate_file({"realizations": nreal}, (REALIZATIONS,), label)["realizations"]
    return check_count(nreal, f"{label}: realizations", MAX_REALIZATIONS)


def seed_section(seed, label, key="seed"):
    """A seed (`SEED`): a whole number >= 0.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import seed_section
    >>> seed_section(-1, "sweep")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: sweep: seed: must be >= 0, got -1
    """
    return validate_file({key: seed}, (replace(SEED, name=key),), label)[key]


def measure_section(measure, label, allowed=None):
    """The ``measure:`` options (`MEASURE`) over `SpectrumMeasure`'s defaults.

    Parameters
    ----------
    measure : dict or None
        The section as read.
    label : str
        The file's path or name, for messages.
    allowed : sequence of str, optional
        The keys taken (default: every option of `SpectrumMeasure`).

    Returns
    -------
    dict
        Every allowed key; ``kmin`` below ``kmax``, bin edges increasing.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import measure_section
    >>> measure_section({"bins": 8}, "sweep")["bins"]
    8
    >>> measure_section({"kmin": 0.5, "kmax": 0.2}, "sweep")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: sweep: measure: kmin must be below kmax, got ...
    """
    fields = MEASURE.fields if allowed is None else tuple(
        p for p in MEASURE.fields if p.name in allowed)
    out = validate_file({"measure": measure}, (replace(MEASURE, fields=fields),),
                        label)["measure"]
    if "kmin" in out and "kmax" in out and not out["kmin"] < out["kmax"]:
        raise ConfigError(f"{label}: measure: kmin must be below kmax, got "
                          f"{out['kmin']:g} and {out['kmax']:g}")
    edges = out.get("bins")
    if isinstance(edges, list) and not all(b > a for a, b in itertools.pairwise(edges)):
        raise ConfigError(f"{label}: measure.bins: the bin edges must increase, got {edges!r}")
    return out
