"""Declared parameters of steps, strategies and simulators, and their validation."""

from dataclasses import dataclass

from .errors import ConfigError

__all__ = ["Parameter", "validate_parameters"]

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
    """

    name: str
    default: object
    types: tuple
    doc: str = ""
    choices: tuple | None = None
    minimum: float | None = None

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
        if (self.minimum is not None and isinstance(value, (int, float))
                and not isinstance(value, bool) and value < self.minimum):
            raise ConfigError(f"{path}: must be >= {self.minimum}, got {value!r}")
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
    >>> from spherex_reduce.parameters import Parameter, validate_parameters
    >>> p = [Parameter("sigma", 5.0, (float,), "clip threshold (sigma)", minimum=0)]
    >>> validate_parameters({"sigma": 3}, p, "steps[0].sigma_clip")
    {'sigma': 3.0}
    >>> validate_parameters({"sgima": 3}, p, "steps[0].sigma_clip")
    Traceback (most recent call last):
    ...
    spherex_reduce.errors.ConfigError: steps[0].sigma_clip.sgima: unknown parameter; valid: sigma
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
