"""Sections a sweep file and a comparison file share: scene, pipelines, realisations, seed, measure.

Each function validates one section as read from YAML and raises a
`~spherex_reduce.core.errors.ConfigError` whose message names the file (``label``)
and the entry.
"""

from dataclasses import fields
from pathlib import Path

from ..core.errors import ConfigError
from ..core.limits import check_count
from ..io.config import load_yaml
from .case import SpectrumMeasure

__all__ = ["MAX_REALIZATIONS", "measure_section", "pipeline_section", "realizations_section",
           "scene_section", "seed_section"]

#: Most realisations a sweep (per cell) or a comparison may ask for.
MAX_REALIZATIONS = 10_000
#: the measure's keys and defaults: those of `SpectrumMeasure`
_MEASURE = {f.name: f.default for f in fields(SpectrumMeasure)}


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
    >>> from spherex_reduce.analysis.sections import scene_section
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
    >>> from spherex_reduce.analysis.sections import pipeline_section
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
    >>> from spherex_reduce.analysis.sections import realizations_section
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
    >>> from spherex_reduce.analysis.sections import seed_section
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
    >>> from spherex_reduce.analysis.sections import measure_section
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
