"""Declared parameters of steps, strategies and simulators, and their validation."""

import math
from dataclasses import dataclass

from .errors import ConfigError

__all__ = ["OPTIONAL_NUMBER", "Parameter", "validate_parameters"]

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

    Numbers must be finite (``.nan`` and ``.inf`` are refused) and within the
    bounds.

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
    """

    name: str
    default: object
    types: tuple
    doc: str = ""
    choices: tuple | None = None
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False

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
        ok = isinstance(value, types) and not (isinstance(value, bool) and bool not in types)
        if not ok and float in types and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        if not ok:
            names = " or ".join(_TYPE_NAMES.get(t, t.__name__) for t in types)
            raise ConfigError(f"{path}: expected {names}, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise ConfigError(f"{path}: {value!r} is not one of {list(self.choices)}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ConfigError(f"{path}: must be a finite number {self.bounds}".rstrip()
                                  + f", got {value!r}")
            lo, hi = self.minimum, self.maximum
            if ((lo is not None and (value < lo or (self.exclusive_minimum and value == lo)))
                    or (hi is not None and value > hi)):
                raise ConfigError(f"{path}: must be {self.bounds}, got {value!r}")
        return value


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
            raise ConfigError(f"{path}.{key}: unknown parameter; valid: {valid}")
    return {
        name: p.check(params[name], f"{path}.{name}") if name in params else p.default
        for name, p in by_name.items()
    }
