"""Simulate, reduce and measure one case: the one route of the demo, the figures and sweeps.

`run_case` simulates a scene once (in memory, or into a FITS file that the
pipelines then stream), reduces the exposure with one or more pipelines (a
paired comparison: every pipeline sees the same simulated exposure) and
applies a measure to each reduced image.  `SpectrumMeasure` is the standard
measure: P(k) and the band power, with the options of a sweep's ``measure``.
"""

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import SpherexReduceError
from ..reduce.pipeline import as_pipeline
from ..simulation import simulate, simulate_to_fits
from .spectrum import BAND_KMAX, BAND_KMIN, band_power, power_spectrum

__all__ = ["CaseResult", "SpectrumMeasure", "run_case"]


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

    def __call__(self, image):
        kw = {"exclude_horizontal": bool(self.exclude_horizontal),
              "mask_sources": bool(self.mask_sources)}
        bins = self.edges(np.shape(getattr(image, "data", image)))
        spec = power_spectrum(image, bins=bins, **kw)
        # every bin, empty ones as NaN
        k = np.full(len(bins) - 1, np.nan)
        power = np.full(len(bins) - 1, np.nan)
        pos = np.searchsorted(bins, np.asarray(spec["k_lo"]) * (1 + 1e-12)) - 1
        k[pos] = np.asarray(spec["k"])
        power[pos] = np.asarray(spec["power"])
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
        Called with each reduced image (`~astropy.nddata.CCDData`); a dict
        gives the options of a `SpectrumMeasure`.  None: no measurement.
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
            result.measured[label] = measure(reduced.to_ccddata())
        result.seconds[label] = time.perf_counter() - t0
    return result
