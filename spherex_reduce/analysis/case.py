"""Simulate, reduce and measure one case: the one route of the demo, the figures and sweeps.

`run_case` simulates a scene once (in memory, or into a FITS file that the
pipelines then stream), reduces the exposure with one or more pipelines (a
paired comparison: every pipeline sees the same simulated exposure) and
applies a measure to each reduced image.  `SpectrumMeasure` is the standard
measure: P(k) and the band power, with the options of a sweep's ``measure``.

A file of cases (a sweep, a comparison) names them in sections validated
here: its scene (`scene_section`), pipelines (`pipeline_section`),
realisations and seed (`realizations_section`, `seed_section`) and measure
(`measure_section`); each raises a `~spherex_reduce.core.errors.ConfigError`
whose message names the file (``label``) and the entry.
"""

import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError, SpherexReduceError
from ..core.limits import check_count
from ..io.config import load_yaml
from ..reduce.pipeline import as_pipeline
from ..simulation import simulate, simulate_to_fits
from .light import light_sensitive_image
from .spectrum import BAND_KMAX, BAND_KMIN, band_power, power_spectrum

__all__ = ["MAX_REALIZATIONS", "CaseResult", "SpectrumMeasure", "measure_section",
           "pipeline_section", "realizations_section", "run_case", "scene_section",
           "seed_section"]


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
        spec = power_spectrum(image, bins=self.edges(np.shape(getattr(image, "data", image))),
                              **kw)
        k, power = self.every_bin(spec)
        bp, err = band_power(image, self.kmin, self.kmax, return_error=True, **kw)
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
    #: per label, the reduction alone (``Pipeline.run``), in seconds
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
             overwrite=False, progress=False, keep=False, inject=None):
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

    Returns
    -------
    `CaseResult`

    Raises
    ------
    SpherexReduceError
        A pipeline that leaves ramps when there is a measure.

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
    result = CaseResult(seed)
    t0 = time.perf_counter()
    if raw_path is not None:
        raw = Path(raw_path)
        simulate_to_fits(scene, raw, mode=mode, seed=seed, overwrite=overwrite,
                         progress=progress)
    else:
        raw = simulate(scene, mode=mode, seed=seed)
        if inject is not None:
            raw = inject(raw)
    result.raw = raw if raw_path is not None or keep else None
    result.seconds["simulate"] = time.perf_counter() - t0
    for label, pipeline in pipes.items():
        t0 = time.perf_counter()
        reduced = pipeline.run(raw, progress=progress)
        result.reduce_seconds[label] = time.perf_counter() - t0
        if keep:
            result.reduced[label] = reduced
        if measure is not None:
            if reduced.is_ramp:
                raise SpherexReduceError(f"pipeline {label} left ramps; it must end with an "
                                         "image (fit_ramp) to be measured")
            result.measured[label] = measure(light_sensitive_image(reduced))
        result.seconds[label] = time.perf_counter() - t0
    return result


#: Most realisations a sweep (per cell) or a comparison may ask for.
MAX_REALIZATIONS = 10_000
#: the measure's keys and defaults: those of `SpectrumMeasure`
_MEASURE = {f.name: f.default for f in fields(SpectrumMeasure)}

# -- the sections of a file of cases (a sweep, a comparison) ----------------------------


def scene_section(scene, label):
    """The ``scene:`` of a sweep-like file: a mapping, or a path (relative to the file).

    Parameters
    ----------
    scene : dict, str or None
        The section as read (None: all defaults).
    label : str
        The file's path or name, for messages and relative paths.

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        Not a mapping, or a file that cannot be read; the message names ``label``.

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
    scene = scene or {}
    if isinstance(scene, str):
        base = Path(label).parent if Path(label).is_file() else Path(".")
        path = Path(scene) if Path(scene).is_absolute() else base / scene
        try:
            scene, _ = load_yaml(path if path.is_file() else Path(scene), "scene")
        except (OSError, ConfigError) as exc:
            raise ConfigError(f"{label}: scene: {exc}") from None
    if not isinstance(scene, dict):
        raise ConfigError(f"{label}: scene: expected a mapping or a path")
    return scene


def pipeline_section(pipes, label, key="pipeline"):
    """Name -> pipeline (shipped name, path or inline dict) of a sweep-like file's ``key``.

    A path is taken relative to the file when it names a file there; an
    inline config is named by its ``name`` (``pipeline-<i>`` without one).

    Raises
    ------
    ConfigError
        Not a name, path, inline config or list of them; a name used twice.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import pipeline_section
    >>> pipeline_section(["spherex-default", {"name": "raw", "steps": []}], "sweep")
    {'spherex-default': 'spherex-default', 'raw': {'name': 'raw', 'steps': []}}
    """
    pipes = [pipes] if isinstance(pipes, (str, dict)) else pipes
    if not isinstance(pipes, (list, tuple)) or not pipes or not all(isinstance(p, (str, dict))
                                                             for p in pipes):
        raise ConfigError(f"{label}: {key}: expected a shipped name, a path, an inline "
                          "config or a list of them")
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
    """The number of realisations: a whole number from 1 to `MAX_REALIZATIONS`.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import realizations_section
    >>> realizations_section(5, "sweep")
    5
    """
    if isinstance(nreal, bool) or not isinstance(nreal, int) or nreal < 1:
        raise ConfigError(f"{label}: realizations: expected an integer >= 1, got {nreal!r}")
    return check_count(nreal, f"{label}: realizations", MAX_REALIZATIONS)


def seed_section(seed, label, key="seed"):
    """A seed: a non-negative integer.

    Examples
    --------
    >>> from spherex_reduce.analysis.case import seed_section
    >>> seed_section(-1, "sweep")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: sweep: seed: expected a non-negative integer, got -1
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{label}: {key}: expected a non-negative integer, got {seed!r}")
    return seed


def measure_section(measure, label, allowed=None):
    """The ``measure:`` options over `SpectrumMeasure`'s defaults (``allowed``: the keys taken).

    Examples
    --------
    >>> from spherex_reduce.analysis.case import measure_section
    >>> measure_section({"bins": 8}, "sweep")["bins"]
    8
    """
    allowed = tuple(_MEASURE) if allowed is None else tuple(allowed)
    if measure is not None and not isinstance(measure, dict):
        raise ConfigError(f"{label}: measure: expected a mapping, got {measure!r}")
    out = {k: v for k, v in _MEASURE.items() if k in allowed}
    for key, value in (measure or {}).items():
        if key not in allowed:
            raise ConfigError(f"{label}: measure.{key}: unknown; valid: {', '.join(allowed)}")
        out[key] = value
    return out
