"""YAML configuration shared by pipelines, scenes and sweeps.

The ``geometry:`` and ``readout:`` sections use the same keys everywhere.
Errors name the YAML path of the offending entry.
"""

import importlib.resources
from pathlib import Path

import yaml

from .errors import ConfigError
from .geometry import DetectorGeometry
from .parameters import Parameter, validate_parameters
from .schedule import REF_MODES, ReadoutSchedule

__all__ = [
    "GEOMETRY_PARAMETERS",
    "READOUT_PARAMETERS",
    "load_yaml",
    "schedule_from_config",
    "shipped_configs",
]

_NUM = (int, float)
#: Keys of the ``geometry:`` section, with defaults (the SPHEREx H2RG).
GEOMETRY_PARAMETERS = (
    Parameter("nrows", 2048, (int,), "array rows", minimum=1),
    Parameter("ncols", 2048, (int,), "array columns", minimum=1),
    Parameter("nchannels", 32, (int,), "readout channels", minimum=1),
    Parameter("ref_border", 4, (int,), "reference border width (pixels)", minimum=0),
    Parameter("scan", "same", (str, list), "fast-scan direction: same, alternate or +1/-1 list"),
    Parameter("pixel_rate", 100_000.0, _NUM, "pixel rate per channel (Hz)", minimum=0),
)
#: Keys of the ``readout:`` section, with defaults (the paper's Table 3).
READOUT_PARAMETERS = (
    Parameter("skip", 24, (int,), "row-chopping skip S", minimum=1),
    Parameter("ref_reads", 32, (int,), "reference row reads per frame r", minimum=0),
    Parameter("ref_mode", "distributed", (str,), "reference read mode", choices=REF_MODES),
    Parameter("phantom_reads", 4, (int,), "phantom samples per row read c", minimum=0),
    Parameter("row_overhead", 4, (int,), "samples of overhead per row read", minimum=0),
    Parameter("frame_overhead", None, (int, type(None)), "samples of overhead per frame",
              minimum=0),
    Parameter("nframes", 74, (int,), "frames up the ramp N", minimum=1),
    Parameter("frame_time", None, (int, float, type(None)), "frame time (s), instead of "
              "frame_overhead", minimum=0),
)


def load_yaml(source, what="config"):
    """Load a YAML mapping from a path, a YAML string or a dict (copied).

    Returns ``(mapping, label)`` where ``label`` names the source in messages.
    """
    if isinstance(source, dict):
        return dict(source), what
    path = Path(source) if "\n" not in str(source) else None
    if isinstance(source, Path) or (path is not None and (path.is_file() or str(source).endswith(
            (".yaml", ".yml")))):
        if not path.is_file():
            raise FileNotFoundError(f"{what} file not found: {path}")
        text, label = path.read_text(), str(path)
    else:
        text, label = str(source), what
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{label}: not valid YAML: {exc}") from exc
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: the top level must be a mapping, got {type(data).__name__}")
    return data, label


def section_values(config, name, declared):
    """Validated values of section ``name`` (only the keys present, no defaults)."""
    section = config.get(name)
    if section is None:
        return {}
    full = validate_parameters(section, declared, name)
    return {k: v for k, v in full.items() if k in section}


def schedule_from_config(geometry=None, readout=None):
    """Build a `ReadoutSchedule` from ``geometry:`` and ``readout:`` mappings.

    Missing keys take the SPHEREx / Table 3 defaults.

    Examples
    --------
    >>> from spherex_reduce.config import schedule_from_config
    >>> s = schedule_from_config({"nrows": 64, "ncols": 64, "nchannels": 4},
    ...                          {"skip": 8, "ref_reads": 8, "nframes": 10})
    >>> s.n_reads, s.skip
    (64, 8)
    """
    g = validate_parameters(geometry, GEOMETRY_PARAMETERS, "geometry")
    r = validate_parameters(readout, READOUT_PARAMETERS, "readout")
    try:
        geo = DetectorGeometry(**g)
        return ReadoutSchedule(geo, **r)
    except ValueError as exc:
        raise ConfigError(f"geometry/readout: {exc}") from exc


def _configs_dir():
    return importlib.resources.files("spherex_reduce") / "data" / "configs"


def shipped_configs():
    """Names of the pipeline configurations shipped with the package.

    Examples
    --------
    >>> from spherex_reduce.config import shipped_configs
    >>> "unchop" in shipped_configs()
    True
    """
    return sorted(p.name[: -len(".yaml")] for p in _configs_dir().iterdir()
                  if p.name.endswith(".yaml"))


def resolve_config(name_or_path):
    """Text and label of a pipeline config given as a shipped name or a path."""
    path = Path(name_or_path)
    if path.is_file():
        return path.read_text(), str(path)
    if str(name_or_path) in shipped_configs():
        res = _configs_dir() / f"{name_or_path}.yaml"
        return res.read_text(), f"{name_or_path} (shipped)"
    raise FileNotFoundError(
        f"no pipeline config file {name_or_path!r} and no shipped config of that name; "
        f"shipped: {', '.join(shipped_configs())}"
    )
