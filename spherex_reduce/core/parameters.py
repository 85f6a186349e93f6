"""Declared parameters of steps, strategies and simulators, and their validation."""

import contextlib
import math
from dataclasses import dataclass

from .errors import ConfigError

__all__ = ["OPTIONAL_NUMBER", "Parameter", "validate_file", "validate_parameters"]

#: Types of a number parameter that may be null (``None``).
OPTIONAL_NUMBER = (int, float, type(None))

_TYPE_NAMES = {bool: "boolean", int: "integer", float: "number", str: "string", list: "list",
               dict: "mapping", type(None): "null"}


@dataclass(frozen=True)
class Parameter:
    """One parameter a step accepts from the YAML file.

    Parameters
    ----------
    name : str
        Key in the YAML mapping.
    default : object
        Value used when the YAML file leaves it out.
    types : tuple of type
        Accepted Python types (``int`` is accepted where ``float`` is).
    doc : str
        One line, with the unit.
    choices : tuple, optional
        The allowed values.
    minimum : float, optional
        Smallest allowed value for numbers.
    maximum : float, optional
        Largest allowed value for numbers.
    exclusive_minimum : bool
        If true, ``minimum`` itself is not allowed (``> minimum``: for
        quantities where zero is meaningless, such as a rate or a threshold).
    unit : str
        Unit of a number, written after its bounds in messages (``'e/s'``).
    items : `Parameter`, optional
        A list's kind of item (its types, bounds and choices; its name is
        not used): each item is checked as ``path[i]``.
    length : tuple of (int, int or None), optional
        Fewest and most items of a list (None: no most).
    fields : sequence of `Parameter`, optional
        A mapping's own table: the mapping is checked by
        `validate_parameters` as ``path.key``, and its result (every field,
        defaults filled in) is the value; left out, the value is the fields'
        defaults.
    quiet_default : bool
        A parameter added after outputs were made: at its default it is left
        out of a pipeline's configuration hash (``SXRCONF``), so that a batch
        still recognises those outputs; the effective configuration, the step
        and the provenance have it as any other.

    Numbers must be finite (``.nan`` and ``.inf`` are refused) and within the
    bounds.  Where a number is expected and text is not, text that reads as a
    number is taken as it (YAML 1.1 reads ``5e-2``, without a dot, as text).

    Examples
    --------
    >>> from spherex_reduce.core.parameters import Parameter
    >>> rate = Parameter("pixel_rate", 1e5, (float,), "Hz", minimum=0, exclusive_minimum=True)
    >>> rate.bounds
    '> 0'
    >>> rate.check(2e5, "geometry.pixel_rate")
    200000.0
    >>> rate.check(float("nan"), "geometry.pixel_rate")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: geometry.pixel_rate: must be a finite number > 0, ...

    A list of items of a kind, and a mapping with its own table:

    >>> reads = Parameter("ref_reads", [8], (list,), "reference reads", length=(1, 3),
    ...                   items=Parameter("", None, (int,), minimum=0))
    >>> reads.check([0, 8], "search.ref_reads")
    [0, 8]
    >>> reads.check([8, -1], "search.ref_reads")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: search.ref_reads[1]: must be >= 0, got -1
    >>> sky = Parameter("sky", None, (dict, type(None)), "the sky", fields=(
    ...     Parameter("rms", 0.05, (float,), "rms", minimum=1e-20, maximum=1e20, unit="e/s"),))
    >>> sky.check(None, "sky"), sky.check({"rms": "1e-2"}, "sky")
    ({'rms': 0.05}, {'rms': 0.01})
    >>> sky.check({"rms": 0}, "sky")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: sky.rms: must be in [1e-20, 1e+20] e/s, got 0.0
    """

    name: str
    default: object
    types: tuple
    doc: str = ""
    choices: tuple | None = None
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    unit: str = ""
    items: "Parameter | None" = None
    length: tuple | None = None
    fields: tuple | None = None
    quiet_default: bool = False

    @property
    def bounds(self):
        """The allowed range as text (``'>= 1'``, ``'> 0'``, ``'in [0, 1]'``), or ``''``."""
        lo, hi = self.minimum, self.maximum
        if lo is None and hi is None:
            return ""
        if hi is None:
            return f"{'>' if self.exclusive_minimum else '>='} {lo:g}"
        if lo is None:
            return f"<= {hi:g}"
        return f"in {'(' if self.exclusive_minimum else '['}{lo:g}, {hi:g}]"

    def check(self, value, path):
        """Return ``value`` converted for use, or raise `ConfigError` naming ``path``."""
        types = self.types
        if isinstance(value, str) and float in types and str not in types:
            with contextlib.suppress(ValueError):  # YAML 1.1 reads 5e-2 (no dot) as text
                value = float(value)
        ok = isinstance(value, types) and not (isinstance(value, bool) and bool not in types)
        if not ok and float in types and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        if not ok:
            names = " or ".join(_TYPE_NAMES.get(t, t.__name__) for t in types)
            raise ConfigError(f"{path}: expected {names}, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise ConfigError(f"{path}: {value!r} is not one of {list(self.choices)}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            self._check_number(value, path)
        elif isinstance(value, list) and (self.items is not None or self.length is not None):
            value = self._check_list(value, path)
        elif self.fields is not None and isinstance(value, (dict, type(None))):
            value = validate_parameters(value, self.fields, path)
        return value

    def _check_number(self, value, path):
        unit = f" {self.unit}" if self.unit else ""
        if not math.isfinite(value):
            raise ConfigError(f"{path}: must be a finite number {self.bounds}".rstrip()
                              + f"{unit}, got {value!r}")
        lo, hi = self.minimum, self.maximum
        if ((lo is not None and (value < lo or (self.exclusive_minimum and value == lo)))
                or (hi is not None and value > hi)):
            raise ConfigError(f"{path}: must be {self.bounds}{unit}, got {value!r}")

    def _check_list(self, value, path):
        lo, hi = self.length or (0, None)
        if len(value) < lo or (hi is not None and len(value) > hi):
            many = f"at least {lo}" if hi is None else f"{lo} to {hi}"
            raise ConfigError(f"{path}: expected a list of {many} "
                              f"{'item' if (hi or lo) == 1 else 'items'}, got {value!r}")
        if self.items is None:
            return value
        return [self.items.check(v, f"{path}[{i}]") for i, v in enumerate(value)]


def validate_parameters(params, declared, path):
    """Check a mapping of parameters against declared ones and fill in defaults.

    Parameters
    ----------
    params : dict or None
        Values from the YAML file.
    declared : sequence of `Parameter`
    path : str
        YAML path of the mapping, for error messages (e.g. ``steps[1].fit_ramp``).

    Returns
    -------
    dict
        Every declared parameter, in declaration order.

    Raises
    ------
    ConfigError
        Unknown key (the message lists the valid names) or invalid value.

    Examples
    --------
    >>> from spherex_reduce.core.parameters import Parameter, validate_parameters
    >>> p = [Parameter("sigma", 5.0, (float,), "clip threshold (sigma)", minimum=0)]
    >>> validate_parameters({"sigma": 3}, p, "steps[0].sigma_clip")
    {'sigma': 3.0}
    >>> validate_parameters({"sgima": 3}, p, "steps[0].sigma_clip")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: steps[0].sigma_clip.sgima: unknown parameter; ...
    """
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise ConfigError(f"{path}: expected a mapping of parameters, got {params!r}")
    by_name = {p.name: p for p in declared}
    for key in params:
        if key not in by_name:
            valid = ", ".join(by_name) or "(none: this takes no parameters)"
            raise ConfigError(f"{_key_path(path, key)}: unknown parameter; valid: {valid}")
    out = {}
    for name, p in by_name.items():
        where = _key_path(path, name)
        if name in params:
            out[name] = p.check(params[name], where)
        elif p.fields is not None:
            out[name] = validate_parameters(None, p.fields, where)
        else:
            out[name] = p.default
    return out


def validate_file(config, declared, label):
    """Check a whole file's mapping against its table: `validate_parameters` naming the file.

    Parameters
    ----------
    config : dict
        The file as read (`~spherex_reduce.io.config.load_yaml`).
    declared : sequence of `Parameter`
        Its top-level keys (mappings and lists described by their own kinds).
    label : str
        The file's path or name: every message starts ``label: key.path: ...``.

    Returns
    -------
    dict
        Every declared key, in declaration order, defaults filled in.

    Examples
    --------
    >>> from spherex_reduce.core.parameters import Parameter, validate_file
    >>> table = [Parameter("seed", 0, (int,), "seed", minimum=0),
    ...          Parameter("search", None, (dict, type(None)), "the search", fields=(
    ...              Parameter("iterations", 100, (int,), "moves", minimum=0),))]
    >>> validate_file({"search": {"iterations": 5}}, table, "design.yaml")
    {'seed': 0, 'search': {'iterations': 5}}
    >>> validate_file({"search": {"iterations": -5}}, table, "design.yaml")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: design.yaml: search.iterations: must be >= 0, got -5
    """
    try:
        return validate_parameters(config, declared, "")
    except ConfigError as exc:
        raise ConfigError(f"{label}: {exc}") from None


def _key_path(path, key):
    """``path.key``, or ``key`` at the top of a file (``path`` empty)."""
    return f"{path}.{key}" if path else key
