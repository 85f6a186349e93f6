"""YAML configuration shared by pipelines, scenes and sweeps.

The ``geometry:``, ``readout:`` and ``window:`` sections use the same keys everywhere.
Errors name the YAML path of the offending entry.
"""

import copy
import importlib.resources
from collections.abc import Mapping
from pathlib import Path

import yaml

from ..core.errors import ConfigError, ResourceError
from ..core.fields import section_fields
from ..core.geometry import DetectorGeometry
from ..core.parameters import validate_parameters
from ..core.presets import apply_preset, apply_window_preset
from ..core.readout.read_order import ORDER_REPLACES, order_conflict
from ..core.readout.schedule import ReadoutSchedule
from ..core.recently_used import RecentlyUsed
from ..core.window import fill_window_geometry, geometry_of

__all__ = [
    "GEOMETRY_PARAMETERS",
    "MAX_YAML_BYTES",
    "MAX_YAML_DEPTH",
    "MAX_YAML_EXPANDED",
    "PARSED_DOCUMENTS",
    "PARSED_TEXT_CHARACTERS",
    "READOUT_PARAMETERS",
    "WINDOW_PARAMETERS",
    "load_yaml",
    "parse_yaml",
    "read_yaml_text",
    "schedule_from_config",
    "shipped_configs",
]

#: Keys of the ``geometry:`` section, with defaults (the SPHEREx H2RG); from the field table.
GEOMETRY_PARAMETERS = tuple(f.parameter() for f in section_fields("geometry"))
#: Keys of the ``readout:`` section, with defaults (the paper's Table 3); from the field table.
READOUT_PARAMETERS = tuple(f.parameter() for f in section_fields("readout"))
#: Keys of the ``window:`` section (a window of a larger array; none by default).
WINDOW_PARAMETERS = tuple(f.parameter() for f in section_fields("window"))


#: Largest YAML file (or text) accepted, in bytes.
MAX_YAML_BYTES = 1 << 20
#: Deepest nesting of lists and mappings accepted (aliases included).
MAX_YAML_DEPTH = 100
#: Largest size a document may reach with every alias expanded: characters of
#: its scalars plus one per value.  A file without aliases stays below its own
#: size; only aliases (a "billion laughs" file) can exceed it.
MAX_YAML_EXPANDED = 4 << 20
#: Documents `parse_yaml` keeps parsed, by their text (the same text, e.g. a noise model
#: read once per exposure, is parsed once; an edited file is new text, parsed anew), and
#: the longest text kept (a config or a noise model is a few KiB).  The text and the
#: document of 16 Ki characters take at most ~0.4 MiB (a list of empty mappings): ~13 MiB
#: for all.
PARSED_DOCUMENTS, PARSED_TEXT_CHARACTERS = 32, 1 << 14
_MERGE_TAG = "tag:yaml.org,2002:merge"
_parsed = RecentlyUsed(PARSED_DOCUMENTS)  # document by text


class _BoundedLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses what would exhaust memory, time or the stack.

    While the document is composed (before any Python object is built) every
    node gets its *expanded* size and depth, counting an alias as a full copy
    of what it refers to, as `json.dumps` or a hash of the configuration would
    see it.  A node nested deeper than `MAX_YAML_DEPTH` or larger than
    `MAX_YAML_EXPANDED`, an alias to a node that contains it, and a key given
    twice in one mapping raise `ConfigError` at once, naming the line.
    """

    def __init__(self, text, label):
        super().__init__(text)
        self._label = label
        self._depth = 0
        self._measure = {}  # id(node) -> (expanded size, expanded depth)

    def _refuse(self, problem, mark):
        where = f"line {mark.line + 1}: " if mark is not None else ""
        return ConfigError(f"{self._label}: {where}{problem}")

    def compose_node(self, parent, index):
        event = self.peek_event()
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise self._refuse(f"nested deeper than {MAX_YAML_DEPTH} levels",
                                   event.start_mark)
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        measure = self._measure.get(id(node))
        if measure is None:
            if isinstance(event, yaml.AliasEvent):
                raise self._refuse(f"alias *{event.anchor} refers to a node that contains it",
                                   event.start_mark)
            measure = self._measure_new(node)
        size, depth = measure
        if size > MAX_YAML_EXPANDED:
            raise self._refuse(f"aliases expand the document beyond {MAX_YAML_EXPANDED >> 20} "
                               "MiB (an alias bomb?)", event.start_mark)
        if depth > MAX_YAML_DEPTH:
            raise self._refuse(f"nested deeper than {MAX_YAML_DEPTH} levels (through aliases)",
                               event.start_mark)
        return node

    def _measure_new(self, node):
        if isinstance(node, yaml.ScalarNode):
            measure = (len(node.value) + 1, 1)
        else:
            if isinstance(node, yaml.MappingNode):
                self._check_keys(node)
                children = [n for pair in node.value for n in pair]
            else:
                children = node.value
            sizes = [self._measure[id(c)] for c in children]
            measure = (1 + sum(s for s, _ in sizes), 1 + max((d for _, d in sizes), default=0))
        self._measure[id(node)] = measure
        return measure

    def _check_keys(self, node):
        first = {}  # (tag, text) of a key -> its line
        for key, _ in node.value:
            if not isinstance(key, yaml.ScalarNode) or key.tag == _MERGE_TAG:
                continue
            ident = (key.tag, key.value)
            if ident in first:
                raise self._refuse(f"key {key.value!r} appears twice in one mapping "
                                   f"(first on line {first[ident]})", key.start_mark)
            first[ident] = key.start_mark.line + 1


def _yaml_error(label, exc):
    """One line for a PyYAML error: the problem and where it is."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if problem and mark is not None:
        context = getattr(exc, "context", None)
        text = f"{context}, {problem}" if context else problem
        text = f"{text} (line {mark.line + 1}, column {mark.column + 1})"
    else:
        text = " ".join(str(exc).split())
    return ConfigError(f"{label}: not valid YAML: {text}")


def read_yaml_text(path, label=None):
    """The text of a YAML file: at most `MAX_YAML_BYTES`, UTF-8.

    Raises
    ------
    FileNotFoundError
        If ``path`` is not a file.
    ConfigError
        If the file is larger than the limit, is a FITS file, or is not UTF-8 text.
    """
    path = Path(path)
    label = str(path) if label is None else label
    if not path.is_file():
        raise FileNotFoundError(f"{label}: file not found")
    with open(path, "rb") as fh:
        data = fh.read(MAX_YAML_BYTES + 1)
    return _decode(data, label)


def _decode(data, label):
    if len(data) > MAX_YAML_BYTES:
        raise ConfigError(f"{label}: larger than {MAX_YAML_BYTES >> 20} MiB, the limit for a "
                          "YAML file")
    if data.startswith(b"SIMPLE  ="):
        raise ConfigError(f"{label}: a FITS file, not YAML text")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{label}: not UTF-8 text (byte {exc.start}: "
                          f"{data[exc.start:exc.start + 1]!r}); is it a YAML file?") from None


def parse_yaml(text, label="config"):
    """Parse YAML text safely: the one YAML parser of the package.

    Only plain data (no ``!!python`` tags), at most `MAX_YAML_BYTES` of text
    nested at most `MAX_YAML_DEPTH` deep; aliases may not expand the
    document beyond `MAX_YAML_EXPANDED` (a "billion laughs" file is refused
    at once, not expanded); a key given twice in a mapping is an error.

    Parameters
    ----------
    text : str
        The YAML text.
    label : str
        Names the source in error messages (e.g. the file name).

    Returns
    -------
    object
        The document (None for an empty one).

    Raises
    ------
    ConfigError
        One line naming ``label``, the problem and its line.

    Examples
    --------
    >>> from spherex_reduce.io.config import parse_yaml
    >>> parse_yaml("base: &b {skip: 8}\\nother: *b")
    {'base': {'skip': 8}, 'other': {'skip': 8}}
    >>> parse_yaml("skip: 8\\nskip: 24", "my.yaml")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: my.yaml: line 2: key 'skip' appears twice ...
    """
    if len(text) > MAX_YAML_BYTES or len(text.encode("utf-8", "surrogatepass")) > MAX_YAML_BYTES:
        raise ConfigError(f"{label}: larger than {MAX_YAML_BYTES >> 20} MiB, the limit for a "
                          "YAML file")
    if len(text) > PARSED_TEXT_CHARACTERS:  # a large document: not kept
        return _parse(text, label)
    # a copy of the document kept for this text (callers may change what they are given)
    return copy.deepcopy(_parsed.get(text, lambda: _parse(text, label)))


def _parse(text, label):
    """`parse_yaml` of text within the size limit."""
    loader = None
    try:
        loader = _BoundedLoader(text, label)  # checks the characters at once
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        raise _yaml_error(label, exc) from None
    finally:
        if loader is not None:
            loader.dispose()


def load_yaml(source, what="config"):
    """Load a YAML mapping from a path, a YAML string or a dict (copied).

    Files and text are read with `read_yaml_text` and parsed with
    `parse_yaml` (size, depth and alias limits, UTF-8, no duplicate keys).

    Parameters
    ----------
    source : path, str or dict
        A `~pathlib.Path`, a string naming an existing file or ending in
        ``.yaml``/``.yml``, YAML text, or a mapping.
    what : str
        What the source is, for messages (``config``, ``scene``, ``sweep``).

    Returns
    -------
    mapping : dict
    label : str
        Names the source in messages (the path, or ``what``).

    Raises
    ------
    FileNotFoundError
        A path that is not a file.
    ConfigError
        Not UTF-8, too large, not valid YAML, or not a mapping at the top level.

    Examples
    --------
    >>> from spherex_reduce.io.config import load_yaml
    >>> load_yaml("readout: {skip: 8}", "scene")
    ({'readout': {'skip': 8}}, 'scene')
    """
    if isinstance(source, dict):
        return dict(source), what
    path = Path(source) if "\n" not in str(source) else None
    if isinstance(source, Path) or (path is not None and (path.is_file() or str(source).endswith(
            (".yaml", ".yml")))):
        if not path.is_file():
            raise FileNotFoundError(f"{what} file not found: {path}")
        label = str(path)
        text = read_yaml_text(path, label)
    else:
        text, label = str(source), what
    data = parse_yaml(text, label)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: the top level must be a mapping, got {type(data).__name__}")
    return data, label


def section_values(config, name, declared):
    """Validated values of section ``name`` (only the keys present, no defaults); for
    ``geometry`` and ``window``, with the values of the geometry's ``preset``
    (`preset_sections`)."""
    section = config.get(name)
    if section is None:
        return {}
    if name in ("geometry", "window"):
        geometry, window = preset_sections(config.get("geometry"), config.get("window"))
        section = geometry if name == "geometry" else window
    full = validate_parameters(section, declared, name)
    return {k: v for k, v in full.items() if k in section}


def preset_sections(geometry, window=None):
    """The ``geometry:`` and ``window:`` mappings with the values of the geometry's
    ``preset`` filled in (keys given win): into the geometry
    (`~spherex_reduce.core.presets.apply_preset`), or, with a window, the preset's
    array into the window's ``full_*`` fields and the rest into the geometry
    (`~spherex_reduce.core.presets.apply_window_preset`).

    Raises
    ------
    ConfigError
        An unknown preset, naming the known ones.

    Examples
    --------
    >>> from spherex_reduce.io.config import preset_sections
    >>> preset_sections({"preset": "SIDECAR-science"})[0]["channels"]
    'rows'
    >>> g, w = preset_sections({"preset": "H4RG-10", "nrows": 64, "ncols": 64},
    ...                        {"first_row": 0, "first_column": 0})
    >>> g["nrows"], w["full_ncols"]
    (64, 4096)
    """
    if not isinstance(geometry, Mapping) or "preset" not in geometry:
        return geometry, window
    try:
        if isinstance(window, Mapping) and window:
            return apply_window_preset(geometry, window)
        return apply_preset(geometry), window
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def schedule_from_config(geometry=None, readout=None, window=None):
    """Build a `ReadoutSchedule` from ``geometry:``, ``readout:`` and ``window:`` mappings.

    Missing keys take the SPHEREx / Table 3 defaults.  With a ``window:``
    (`spherex_reduce.core.window`), the geometry's ``nrows`` and ``ncols``
    are the window's and its channels, scan and reference border are derived
    from the full array's.

    Examples
    --------
    >>> from spherex_reduce.io.config import schedule_from_config
    >>> s = schedule_from_config({"nrows": 64, "ncols": 64, "nchannels": 4},
    ...                          {"skip": 8, "ref_reads": 8, "nframes": 10})
    >>> s.n_reads, s.skip
    (64, 8)
    """
    geometry, window = preset_sections(geometry, window)
    g = validate_parameters(geometry, GEOMETRY_PARAMETERS, "geometry")
    r = validate_parameters(readout, READOUT_PARAMETERS, "readout")
    both = [k for k in ORDER_REPLACES if r["order"] is not None and k in (readout or {})]
    if both:
        raise ConfigError(f"readout: {order_conflict(both)}")
    try:
        if window:
            w = validate_parameters(window, WINDOW_PARAMETERS, "window")
            given = {k: g[k] for k in (geometry or {}) if k in g}  # validated
            geo = geometry_of(fill_window_geometry(
                {**{k: g[k] for k in ("nrows", "ncols", "pixel_rate")}, **given, **w}))
        else:
            geo = DetectorGeometry(**g)
        return ReadoutSchedule(geo, **r)
    except ResourceError:
        raise
    except ValueError as exc:
        raise ConfigError(f"geometry/readout: {exc}") from exc


def _configs_dir():
    return importlib.resources.files("spherex_reduce") / "data" / "configs"


def shipped_configs():
    """Names of the pipeline configurations shipped with the package.

    Examples
    --------
    >>> from spherex_reduce.io.config import shipped_configs
    >>> "unchop" in shipped_configs()
    True
    """
    return sorted(p.name[: -len(".yaml")] for p in _configs_dir().iterdir()
                  if p.name.endswith(".yaml"))


def resolve_config(name_or_path):
    """Text and label of a pipeline config given as a shipped name or a path."""
    path = Path(name_or_path)
    if path.is_file():
        return read_yaml_text(path), str(path)
    if str(name_or_path) in shipped_configs():
        res = _configs_dir() / f"{name_or_path}.yaml"
        return res.read_text(encoding="utf-8"), f"{name_or_path} (shipped)"
    raise FileNotFoundError(
        f"no pipeline config file {name_or_path!r} and no shipped config of that name; "
        f"shipped: {', '.join(shipped_configs())}"
    )
