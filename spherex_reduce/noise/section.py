"""The ``noise:`` section of a scene file: which components, from which table.

Shared by the simulator's scenes and by reduction steps that take a noise
model (the ``wiener`` reference strategy).
"""

import numpy as np

from ..core.errors import ConfigError
from .components import NoiseComponent, noise_components

__all__ = ["COMPONENT_KEYS", "DEFAULT_COMPONENTS", "NOISE_KEYS", "section_components"]

#: The components a scene simulates when it names none (all of the paper's Table 2).
DEFAULT_COMPONENTS = ["video8", "roic", "bias_correlated", "bias_phantom_only",
                      "bias_pixels_only"]
NOISE_KEYS = ("table", "components", "acn")
COMPONENT_KEYS = ("name", "alpha", "beta", "gamma", "exponent", "scope", "visibility", "acn")
_NUM = (int, float)


def section_components(noise):
    """The components a ``noise:`` section (of a scene file) describes.

    Parameters
    ----------
    noise : dict or None
        ``{table: name or path, components: [names or mappings], acn: bool}``,
        every key optional (None: the paper's Table 2 components).

    Returns
    -------
    list of `NoiseComponent`

    Raises
    ------
    ConfigError
        Unknown keys, wrong types, negative coefficients, unknown names; the
        message names the YAML path (``noise.components[2].beta``).

    Examples
    --------
    >>> from spherex_reduce.noise.section import section_components
    >>> [c.name for c in section_components({"components": ["roic", {"name": "x", "beta": 1e-3}]})]
    ['roic', 'x']
    """
    if noise is None:
        noise = {}
    if not isinstance(noise, dict):
        raise ConfigError(f"noise: expected a mapping, got {noise!r}")
    for key in noise:
        if key not in NOISE_KEYS:
            raise ConfigError(f"noise.{key}: unknown key; valid: {', '.join(NOISE_KEYS)}")
    table_name = noise.get("table", "spherex-table2")
    if not isinstance(table_name, str):
        raise ConfigError(f"noise.table: expected a table name or path, got {table_name!r}")
    table = noise_components(table_name)
    items = noise.get("components")
    if items is None:
        items = list(table) if table_name != "spherex-table2" else DEFAULT_COMPONENTS
    if not isinstance(items, list):
        raise ConfigError(f"noise.components: expected a list, got {items!r}")
    acn = noise.get("acn")
    if acn is not None and not isinstance(acn, bool):
        raise ConfigError(f"noise.acn: expected true, false or null, got {acn!r}")
    out = []
    for i, item in enumerate(items):
        path = f"noise.components[{i}]"
        if isinstance(item, str):
            if item not in table:
                raise ConfigError(f"{path}: {item!r} is not in table {table_name}; "
                                  f"valid: {', '.join(table)}")
            comp = table[item]
        elif isinstance(item, dict):
            comp = _inline(item, path, table)
        else:
            raise ConfigError(f"{path}: expected a component name or a mapping, got {item!r}")
        if acn is not None and comp.scope == "channel":
            comp = comp.replace(acn=acn)
        out.append(comp)
    names = [c.name for c in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"noise.components: duplicate name(s) {sorted(dup)}")
    return out


def _inline(item, path, table):
    for key in item:
        if key not in COMPONENT_KEYS:
            raise ConfigError(f"{path}.{key}: unknown key; valid: {', '.join(COMPONENT_KEYS)}")
    name = item.get("name")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{path}.name: every inline component needs a name (string)")
    base = table[name].to_dict() if name in table else {"name": name}
    kw = dict(base)
    checks = {"alpha": _NUM, "beta": _NUM, "gamma": _NUM, "exponent": _NUM, "scope": (str,),
              "visibility": (str,), "acn": (bool,)}
    for key, types in checks.items():
        if key not in item:
            continue
        value = item[key]
        if types is _NUM and isinstance(value, str):
            # YAML 1.1 reads 1e-3 (no dot) as a string: accept numbers written that way
            try:
                value = float(value)
            except ValueError:
                pass
        if (isinstance(value, bool) and bool not in types) or not isinstance(value, types):
            what = "number" if types is _NUM else types[0].__name__
            raise ConfigError(f"{path}.{key}: expected {what}, got {value!r}")
        if key in ("alpha", "beta", "gamma"):
            value = float(value)
            if not np.isfinite(value) or value < 0:
                what = "a finite number >= 0" if not np.isfinite(value) else ">= 0"
                raise ConfigError(f"{path}.{key}: must be {what}, got {value!r}")
        kw[key] = value
    try:
        return NoiseComponent(**kw)
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
