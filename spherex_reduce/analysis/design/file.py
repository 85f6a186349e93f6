"""The DESIGN.yaml of ``spherex-reduce design-readout``: what is searched, for which noise.

`load_design` validates the file (every key optional) into a `Design`; a
wrong value is refused with a `~spherex_reduce.core.errors.ConfigError` whose
message names the file and the key.  Numbers are bounded so that no file asks
for unbounded time or memory.

Examples
--------
>>> from spherex_reduce.analysis.design.file import load_design
>>> d = load_design({"search": {"iterations": 10}, "pipeline": "none"})
>>> d.iterations, d.pipeline, d.frame_time, d.baseline["skip"]
(10, None, 1.51, 24)
>>> load_design({"search": {"iterations": -1}})
Traceback (most recent call last):
...
spherex_reduce.core.errors.ConfigError: design: search.iterations: expected an integer from 0 ...
"""

import math
from dataclasses import dataclass

from astropy import units as u

from ...core.errors import ConfigError, SpherexReduceError
from ...io.config import load_yaml
from ...reduce.steps.reference.noise_models import noise_model
from ...simulation.scene import load_scene
from ..case import pipeline_section, realizations_section, scene_section, seed_section
from ..forecast.steps import linear_steps
from ..spectrum import BAND_KMAX, BAND_KMIN
from .row_orders import FAMILIES, max_skip

__all__ = ["BASELINE", "MAX_CHOICES", "MAX_ITERATIONS", "MAX_TIMINGS", "TOP_KEYS", "Design",
           "load_design"]

TOP_KEYS = ("scene", "noise", "band", "bins", "pipeline", "budget", "baseline", "search",
            "realizations", "seed")
SEARCH_KEYS = ("families", "skips", "phantom_reads", "ref_reads", "ref_modes", "finalists",
               "iterations", "seed")
#: The paper's readout (S = 24, r = 32 distributed, c = 4): what the best schedule is judged
#: against, at the same frame time.
BASELINE = {"skip": 24, "ref_reads": 32, "ref_mode": "distributed", "phantom_reads": 4}
#: Most local-search iterations (each one forecast; ~1 s at full size).
MAX_ITERATIONS = 10_000
#: Most values a list of the search (skips, c, r) may hold.
MAX_CHOICES = 1000
#: Most schedules the timing stage may forecast (finalists x c x r x placements).
MAX_TIMINGS = 10_000
_REF_MODES = ("distributed", "repeated")
_REF_READS = (0, 8, 16, 32, 48, 64, 96, 128, 176)


@dataclass(frozen=True)
class Design:
    """A validated DESIGN.yaml (see `load_design` for the keys)."""

    label: str
    scene: dict
    pipeline: object
    kmin: float
    kmax: float
    bins: int
    frame_time: float
    baseline: dict
    families: tuple
    skips: tuple
    phantom_reads: tuple
    ref_reads: tuple
    ref_modes: tuple
    finalists: int
    iterations: int
    search_seed: int
    realizations: int
    seed: int


def load_design(source):
    """Validate a DESIGN.yaml (path, YAML text or dict) into a `Design`.

    Keys, all optional:

    ``scene``
        A scene (mapping or path, relative to the file): the geometry, the
        readout's other fields (``nframes``, ``row_overhead`` ...) and the
        noise; default: the paper's case.
    ``noise``
        The noise model, replacing the scene's: a noise table (a built-in
        name or an ECSV file), a ``fit-noise`` result of your darks (its
        ``reference`` and ``phantom`` streams) or a scene file.
    ``band``
        ``{kmin, kmax}`` in rad/pixel: the band whose power is minimised
        (default the paper's 5-20').
    ``bins``
        Log bins of the report's P(k) (default 30).
    ``pipeline``
        The reduction the forecast follows (default ``spherex-default``;
        ``none``: the slope image as simulated); one whose steps the forecast
        cannot follow (`~spherex_reduce.analysis.forecast.steps.linear_steps`)
        is refused here.
    ``budget``
        ``{frame_time: s}``: every schedule takes this frame time (default
        the scene's, the paper's 1.51 s); a schedule whose reads do not fit
        in it is not considered.
    ``baseline``
        The readout the best schedule is judged against (``skip``,
        ``ref_reads``, ``ref_mode``, ``phantom_reads``; default the paper's
        S = 24, r = 32 distributed, c = 4), at the budget's frame time; ``skip``
        below the number of active rows (a larger one reads them in physical
        order, `~spherex_reduce.analysis.design.row_orders.max_skip`).
    ``search``
        ``families`` (of `~spherex_reduce.analysis.design.row_orders.FAMILIES`),
        ``skips`` (the S of the skip and nested families, default 1 ... 64),
        ``phantom_reads`` and ``ref_reads`` (the c and r tried, default
        0, 1, 2, 4, 8 and 0, 8, 16, 32, 48, 64, 96, 128, 176; those whose reads do not
        fit in the frame time are left out), ``ref_modes`` (``distributed``,
        ``repeated``), ``finalists`` (orders whose timing is searched,
        default 2), ``iterations`` (of the local search, default 100) and
        ``seed``.
    ``realizations``, ``seed``
        Of the paired Monte Carlo confirmation (default 20 and 0; 0
        realisations: none).

    Raises
    ------
    ConfigError
        A key that is unknown or of the wrong type or range; the message
        names the file and the key.
    """
    config, label = load_yaml(source, "design")
    for key in config:
        if key not in TOP_KEYS:
            raise ConfigError(f"{label}: {key}: unknown key; valid: {', '.join(TOP_KEYS)}")
    scene = scene_section(config.get("scene"), label)
    if config.get("noise") is not None:
        scene = {**scene, "noise": _noise(config["noise"], label)}
    try:
        sc = load_scene(scene)
    except ConfigError as exc:
        raise ConfigError(f"{label}: scene: {exc}") from None
    pipeline = config.get("pipeline", "spherex-default")
    if pipeline in (None, "none"):
        pipeline = None
    elif isinstance(pipeline, list):
        _refuse(label, "pipeline", "expected one pipeline", pipeline)
    else:
        pipeline = next(iter(pipeline_section(pipeline, label).values()))
        try:
            linear_steps(pipeline)
        except (SpherexReduceError, OSError) as exc:
            raise ConfigError(f"{label}: pipeline: {exc}") from None
    band = _mapping(config, "band", label, ("kmin", "kmax"))
    kmin = _number(band.get("kmin", BAND_KMIN), label, "band.kmin", 0, math.pi)
    kmax = _number(band.get("kmax", BAND_KMAX), label, "band.kmax", 0, math.pi)
    if not kmin < kmax:
        _refuse(label, "band", "kmin must be below kmax", band)
    budget = _mapping(config, "budget", label, ("frame_time",))
    frame_time = _number(budget.get("frame_time", sc.schedule.frame_time.to_value(u.s)), label,
                         "budget.frame_time", 0, 1e6)
    base = _mapping(config, "baseline", label, tuple(BASELINE))
    baseline = {**BASELINE, **base}
    _integer(baseline["skip"], label, "baseline.skip", 1,
             max_skip(sc.schedule.geometry.n_active_rows))
    for key in ("ref_reads", "phantom_reads"):
        _integer(baseline[key], label, f"baseline.{key}", 0, 2**20)
    if baseline["ref_mode"] not in _REF_MODES:
        _refuse(label, "baseline.ref_mode", f"expected one of {', '.join(_REF_MODES)}",
                baseline["ref_mode"])
    search = _mapping(config, "search", label, SEARCH_KEYS)
    families = tuple(_choices(search, "families", label, FAMILIES, str))
    for f in families:
        if f not in FAMILIES:
            _refuse(label, "search.families", f"valid: {', '.join(FAMILIES)}", f)
    phantom_reads = tuple(_choices(search, "phantom_reads", label, (0, 1, 2, 4, 8), int, 0))
    ref_reads = tuple(_choices(search, "ref_reads", label, _REF_READS, int, 0))
    ref_modes = tuple(_choices(search, "ref_modes", label, _REF_MODES, str))
    finalists = _integer(search.get("finalists", 2), label, "search.finalists", 1, 100)
    timings = finalists * len(phantom_reads) * len(ref_reads) * len(ref_modes)
    if timings > MAX_TIMINGS:
        raise ConfigError(f"{label}: search: finalists x phantom_reads x ref_reads x "
                          f"ref_modes is {timings} schedules to forecast; at most "
                          f"{MAX_TIMINGS}")
    return Design(
        label=label, scene=scene, pipeline=pipeline, kmin=kmin, kmax=kmax,
        bins=_integer(config.get("bins", 30), label, "bins", 1, 1000),
        frame_time=frame_time, baseline=baseline, families=families,
        skips=tuple(_choices(search, "skips", label, range(1, 65), int, 1)),
        phantom_reads=phantom_reads, ref_reads=ref_reads, ref_modes=ref_modes,
        finalists=finalists,
        iterations=_integer(search.get("iterations", 100), label, "search.iterations", 0,
                            MAX_ITERATIONS),
        search_seed=seed_section(search.get("seed", 0), label, "search.seed"),
        realizations=_realizations(config.get("realizations", 20), label),
        seed=seed_section(config.get("seed", 0), label),
    )


def _realizations(value, label):
    """A sweep's realisations (`~spherex_reduce.analysis.case.realizations_section`), or 0:
    no Monte Carlo."""
    return 0 if type(value) is int and value == 0 else realizations_section(value, label)


def _noise(source, label):
    """The ``noise:`` section of a scene holding the components of a table, a fit-noise
    result or a scene file, inline (so the best scene needs no other file)."""
    if not isinstance(source, str):
        _refuse(label, "noise", "expected a noise table name, an ECSV file or a scene file",
                source)
    comps, _ = noise_model(source, f"{label}: noise")
    return {"components": [c.to_dict() for c in comps]}


def _refuse(label, key, why, value):
    raise ConfigError(f"{label}: {key}: {why}, got {value!r}")


def _mapping(config, key, label, keys):
    value = config.get(key) or {}
    if not isinstance(value, dict):
        _refuse(label, key, "expected a mapping", value)
    for k in value:
        if k not in keys:
            raise ConfigError(f"{label}: {key}.{k}: unknown key; valid: {', '.join(keys)}")
    return value


def _number(value, label, key, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and low < value <= high):
        _refuse(label, key, f"expected a number in ({low:g}, {high:g}]", value)
    return float(value)


def _integer(value, label, key, low, high):
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        _refuse(label, key, f"expected an integer from {low} to {high}", value)
    return int(value)


def _choices(search, key, label, default, kind, low=None):
    """A non-empty list of at most `MAX_CHOICES` distinct values (integers >= ``low``)."""
    value = search.get(key, list(default))
    if not isinstance(value, list) or not value or len(value) > MAX_CHOICES:
        _refuse(label, f"search.{key}", f"expected a list of 1 to {MAX_CHOICES} values", value)
    for v in value:
        if kind is int:
            _integer(v, label, f"search.{key}", low, 2**20)
        elif not isinstance(v, str):
            _refuse(label, f"search.{key}", "expected names", v)
        elif key == "ref_modes" and v not in _REF_MODES:
            _refuse(label, f"search.{key}", f"expected {' or '.join(_REF_MODES)}", v)
    return list(dict.fromkeys(value))
