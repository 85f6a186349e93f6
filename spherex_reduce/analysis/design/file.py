"""The DESIGN.yaml of ``spherex-reduce design-readout``: what is searched, for which noise.

`load_design` validates the file (every key optional) into a `Design`; a
wrong value is refused with a `~spherex_reduce.core.errors.ConfigError` whose
message names the file and the key.  Numbers are bounded so that no file asks
for unbounded time or memory.

Examples
--------
>>> from spherex_reduce.analysis.design.file import load_design
>>> d = load_design({"search": {"iterations": 10}, "pipeline": "none"})
>>> d.iterations, d.pipeline, d.frame_time, d.baseline.skip
(10, None, 1.51, 24)
>>> load_design({"search": {"iterations": -1}})
Traceback (most recent call last):
...
spherex_reduce.core.errors.ConfigError: design: search.iterations: must be in [0, 10000], got -1
"""

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from astropy import units as u

from ...core.errors import ConfigError, SpherexReduceError
from ...core.parameters import Parameter, validate_file
from ...io.config import load_yaml
from ...reduce.steps.reference.noise_models import noise_model
from ...simulation.grouping import read_schedule
from ...simulation.scene import load_scene
from ..case import (
    PIPELINES,
    REALIZATIONS,
    SCENE,
    SEED,
    pipeline_section,
    realizations_section,
    scene_section,
)
from ..forecast.steps import linear_steps
from ..spectrum import BAND_KMAX, BAND_KMIN
from .row_orders import FAMILIES, max_skip

__all__ = ["BASELINE", "DESIGN_PARAMETERS", "GAIN_ERROR", "MAX_CHOICES", "MAX_ITERATIONS",
           "MAX_TIMINGS", "MIN_PAIRS", "POPULATION_TERMS", "TOP_KEYS", "Baseline", "Design",
           "load_design"]

#: The paired Monte Carlo's default target: the standard error of its gain (1 - best /
#: baseline band power), 1 percentage point.
GAIN_ERROR = 0.01
#: Pairs the Monte Carlo runs before its gain's error may stop it (the error of fewer
#: pairs' scatter is itself too uncertain to stop on).
MIN_PAIRS = 8


@dataclass(frozen=True)
class Baseline:
    """The readout the best schedule is judged against: skip ``S``, ``r``, placement, ``c``.

    Examples
    --------
    >>> from spherex_reduce.analysis.design.file import BASELINE
    >>> BASELINE.skip, BASELINE.ref_reads, BASELINE.ref_mode, BASELINE.phantom_reads
    (24, 32, 'distributed', 4)
    """

    skip: int
    ref_reads: int
    ref_mode: str
    phantom_reads: int


#: The paper's readout (S = 24, r = 32 distributed, c = 4): what the best schedule is judged
#: against, at the same frame time.
BASELINE = Baseline(skip=24, ref_reads=32, ref_mode="distributed", phantom_reads=4)
#: Most local-search iterations (each one forecast; ~1 s at full size).
MAX_ITERATIONS = 10_000
#: Most values a list of the search (skips, c, r) may hold.
MAX_CHOICES = 1000
#: Most schedules the timing stage may forecast (finalists x c x r x placements).
MAX_TIMINGS = 10_000
_REF_MODES = ("distributed", "repeated")
_REF_READS = (0, 8, 16, 32, 48, 64, 96, 128, 176)
#: Most reads of a count of the search or the baseline (``c``, ``r``, ``S``).
_MAX_READS = 2**20


def _reads(name, default, doc, minimum=0):
    """A count of reads, or a search's list of them (``default`` a list)."""
    one = Parameter(name, default, (int,), doc, minimum=minimum, maximum=_MAX_READS)
    if not isinstance(default, list):
        return one
    return Parameter(name, default, (list,), f"{doc}: the values tried", items=one,
                     length=(1, MAX_CHOICES))


def _names(name, choices, doc):
    """A search's list of names (each one of ``choices``; default: all)."""
    return Parameter(name, list(choices), (list,), doc, length=(1, MAX_CHOICES),
                     items=Parameter(name, None, (str,), doc, choices=choices))


_BASELINE_SKIP = _reads("skip", BASELINE.skip, "skip S (below the number of active rows)",
                        minimum=1)
#: The keys of DESIGN.yaml (`load_design`), each with its own table if a mapping.
DESIGN_PARAMETERS = (
    SCENE,
    Parameter("noise", None, (str, type(None)),
              "the noise: a noise table name, an ECSV file or a scene file"),
    Parameter("band", None, (dict, type(None)), "the band minimised (rad/pixel)", fields=(
        Parameter("kmin", BAND_KMIN, (float,), "band start (rad/pixel)", minimum=0,
                  maximum=math.pi, exclusive_minimum=True),
        Parameter("kmax", BAND_KMAX, (float,), "band end (rad/pixel)", minimum=0,
                  maximum=math.pi, exclusive_minimum=True))),
    Parameter("bins", 30, (int,), "log bins of the report's P(k)", minimum=1, maximum=1000),
    replace(PIPELINES, types=(str, dict, type(None)), items=None, length=None,
            doc="the reduction the forecast follows (none: the slope image)"),
    Parameter("budget", None, (dict, type(None)), "the frame-time budget", fields=(
        Parameter("frame_time", None, (float,), "frame time (s; default: the scene's)",
                  minimum=0, maximum=1e6, exclusive_minimum=True),)),
    Parameter("baseline", None, (dict, type(None)), "the readout judged against", fields=(
        _BASELINE_SKIP,
        _reads("ref_reads", BASELINE.ref_reads, "reference reads r"),
        Parameter("ref_mode", BASELINE.ref_mode, (str,), "reference placement",
                  choices=_REF_MODES),
        _reads("phantom_reads", BASELINE.phantom_reads, "phantom reads c"))),
    Parameter("search", None, (dict, type(None)), "what is searched", fields=(
        _names("families", FAMILIES, "families of row orders"),
        _reads("skips", list(range(1, 65)), "S of the skip and nested families", minimum=1),
        _reads("phantom_reads", [0, 1, 2, 4, 8], "phantom reads c"),
        _reads("ref_reads", list(_REF_READS), "reference reads r"),
        _names("ref_modes", _REF_MODES, "reference placements"),
        Parameter("finalists", 2, (int,), "orders whose timing is searched", minimum=1,
                  maximum=100),
        Parameter("iterations", 100, (int,), "moves of the local search", minimum=0,
                  maximum=MAX_ITERATIONS),
        replace(SEED, doc="seed of the local search"))),
    replace(REALIZATIONS, default=20, minimum=0,
            doc="most realisations of the paired Monte Carlo (0: none)"),
    Parameter("gain_error", GAIN_ERROR, (float,),
              f"the paired Monte Carlo stops once its gain's standard error is at most this, "
              f"after {MIN_PAIRS} pairs at least (0: every realisation)", minimum=0, maximum=1),
    replace(SEED, doc="seed of the paired Monte Carlo"),
)
TOP_KEYS = tuple(p.name for p in DESIGN_PARAMETERS)


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
    baseline: Baseline
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
    gain_error: float
    #: one line per scene term the search leaves out (`POPULATION_TERMS`)
    notes: tuple = ()
    #: those terms as the scene gave them (in electrons), carried into the best scene
    left_out: dict = field(default_factory=dict)

    def carried(self, scene):
        """``scene`` (a candidate's, as forecast) with the terms the search left out
        (`left_out`) given back, as the design's scene had them.

        Examples
        --------
        >>> from spherex_reduce.analysis.design.file import load_design
        >>> d = load_design({"scene": {"scene": {"dark_current": 1.0,
        ...                                      "hot_pixel_fraction": 0.01}}})
        >>> d.scene["scene"], d.carried(d.scene)["scene"]
        ({'dark_current': 1.0}, {'dark_current': 1.0, 'hot_pixel_fraction': 0.01})
        """
        if not self.left_out:
            return scene
        return {**scene, "scene": {**(scene.get("scene") or {}), **self.left_out}}


#: The scene's pixel populations, each with what it is: a design minimises the readout's
#: noise, so a scene that holds them (characterize's MODEL.yaml of a real detector does) is
#: searched without them, says so in one line per term, and its best scene carries them
#: unchanged (simulate draws them; the forecast adds their white power).
POPULATION_TERMS = {
    "hot_pixel_fraction": "hot pixels",
    "hot_pixel_current_spread": "the hot pixels' current spread",
    "dark_current_spread": "the pixels' dark-current spread",
    "rtn": "telegraph pixels",
}


def _without_populations(scene):
    """``(scene, left_out, notes)``: the scene without its `POPULATION_TERMS`, those terms
    as it had them, one note per term."""
    terms = scene.get("scene")
    if not isinstance(terms, dict):
        return scene, {}, ()
    gone = {k: terms[k] for k in POPULATION_TERMS if terms.get(k) not in (None, 0, 0.0)}
    if not gone:
        return scene, {}, ()
    kept = {k: v for k, v in terms.items() if k not in gone}
    notes = []
    for k, value in gone.items():
        what = POPULATION_TERMS[k]
        if k == "rtn" and isinstance(value, list):
            what = f"{what} ({len(value)} populations)"
        notes.append(f"scene.{k}: {what} left out of the search and its Monte Carlo (the "
                     f"design is for the readout's noise, not {POPULATION_TERMS[k]}); written "
                     "unchanged into the best scene, for simulate and forecast")
    return {**scene, "scene": kept}, gone, tuple(notes)


def load_design(source):
    """Validate a DESIGN.yaml (path, YAML text or dict) into a `Design`.

    Keys, all optional:

    ``scene``
        A scene (mapping or path, relative to the file; in adu with its
        ``gain:``, converted to electrons): the geometry, the readout's other
        fields (``nframes``, ``row_overhead`` ...) and the noise; default: the
        paper's case.  Every term is validated as ``simulate`` validates it; its
        pixel populations (`POPULATION_TERMS`), not the readout's noise, are
        left out of the search with one note per term
        (`Design.notes`) and carried unchanged into the best scene
        (`Design.carried`).
    ``noise``
        The noise model, replacing the scene's: a noise table (a built-in
        name or an ECSV file), a ``fit-noise`` result of your darks (its
        ``reference`` and ``phantom`` streams; a row of another stream is
        refused) or a scene file; a path relative to the file, as ``scene``.
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
    ``realizations``, ``seed``, ``gain_error``
        Of the paired Monte Carlo confirmation: the most realisations (default
        20; 0: none), the first seed (default 0) and the standard error of the
        gain at which it stops (default `GAIN_ERROR`, 1 percentage point, once
        `MIN_PAIRS` pairs have run; 0: every realisation).  A scene read at
        given ``read_times`` is forecast at those times but not simulated: it
        needs ``realizations: 0``.

    Raises
    ------
    ConfigError
        A key that is unknown or of the wrong type or range; the message
        names the file and the key.
    """
    config, label = load_yaml(source, "design")
    v = validate_file(config, DESIGN_PARAMETERS, label)
    scene = scene_section(v["scene"], label)
    if v["noise"] is not None:
        comps, unit = noise_model(_beside(v["noise"], label), f"{label}: noise",
                                  unit=u.electron)  # a scene in adu: with its gain
        if unit != u.electron:  # the scene, the sky and the band powers are in electrons
            raise ConfigError(f"{label}: noise: {v['noise']} describes charge in {unit}, not "
                              "electrons; fit-noise darks given input.gain (or in electrons), "
                              "or a scene in adu with its gain:")
        scene = {**scene, "noise": {"components": [c.to_dict() for c in comps]}}
    try:  # every term, those the search leaves out too, validated as simulate does
        sc = load_scene(scene)
    except ConfigError as exc:
        raise ConfigError(f"{label}: scene: {exc}") from None
    scene, left_out, notes = _without_populations(scene)
    pipeline = v["pipeline"]
    if pipeline in (None, "none"):
        pipeline = None
    else:
        pipeline = next(iter(pipeline_section(pipeline, label).values()))
        try:
            linear_steps(pipeline)
        except (SpherexReduceError, OSError) as exc:
            raise ConfigError(f"{label}: pipeline: {exc}") from None
    band = v["band"]
    if not band["kmin"] < band["kmax"]:
        raise ConfigError(f"{label}: band: kmin must be below kmax, got {band['kmin']:g} and "
                          f"{band['kmax']:g}")
    frame_time = v["budget"]["frame_time"]
    if frame_time is None:
        frame_time = float(sc.schedule.frame_time.to_value(u.s))
    baseline = Baseline(**v["baseline"])
    rows = sc.schedule.geometry.n_active_rows  # S >= rows: the physical order
    try:
        replace(_BASELINE_SKIP, maximum=max_skip(rows)).check(baseline.skip, "baseline.skip")
    except ConfigError as exc:
        raise ConfigError(f"{label}: {exc}") from None
    search = {k: tuple(dict.fromkeys(x)) if isinstance(x, list) else x
              for k, x in v["search"].items()}
    timings = (search["finalists"] * len(search["phantom_reads"]) * len(search["ref_reads"])
               * len(search["ref_modes"]))
    if timings > MAX_TIMINGS:
        raise ConfigError(f"{label}: search: finalists x phantom_reads x ref_reads x "
                          f"ref_modes is {timings} schedules to forecast; at most "
                          f"{MAX_TIMINGS}")
    realizations = v["realizations"] and realizations_section(v["realizations"], label)
    if realizations:
        try:
            read_schedule(sc.schedule)  # what the Monte Carlo simulates
        except ConfigError as exc:
            raise ConfigError(f"{label}: realizations: the paired Monte Carlo simulates the "
                              f"scene: {exc}, or set realizations: 0 (the forecast "
                              "alone)") from None
    return Design(
        label=label, scene=scene, pipeline=pipeline, kmin=band["kmin"], kmax=band["kmax"],
        bins=v["bins"], frame_time=frame_time, baseline=baseline,
        families=search["families"], skips=search["skips"],
        phantom_reads=search["phantom_reads"], ref_reads=search["ref_reads"],
        ref_modes=search["ref_modes"], finalists=search["finalists"],
        iterations=search["iterations"], search_seed=search["seed"],
        realizations=realizations, seed=v["seed"], gain_error=v["gain_error"], notes=notes,
        left_out=left_out,
    )


def _beside(name, label):
    """A file ``name`` relative to the design file ``label`` when it names a file there (as
    ``scene:`` and ``pipeline:`` are read), else ``name`` itself."""
    base = Path(label).parent if Path(label).is_file() else None
    if base is None or Path(name).is_absolute() or not (base / name).is_file():
        return name
    return str(base / name)
