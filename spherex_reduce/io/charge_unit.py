"""The unit of a scene's charges: ``unit:`` (electron or adu) and ``gain:`` (e-/adu).

A scene (``simulate``'s file, the MODEL.yaml ``characterize`` writes) states
the unit of every charge it holds: its noise coefficients (``unit²/Hz``,
``unit²``, ...), its currents (``unit/s``) and telegraph steps.  Electrons by
default; ``adu`` for a model of darks in adu, with ``gain`` where it is known.
Read here, below the simulator, so that the reduction steps that take a
scene's noise model (``wiener``) read the same keys.
"""

import math

from astropy import units as u

from ..core.errors import ConfigError
from .input import parse_unit

__all__ = ["MAX_GAIN", "MIN_GAIN", "UNITS", "scene_unit"]

#: The units a scene's charges may be in (``unit:``; ``gain:`` e-/adu with ``adu``).
UNITS = (u.electron, u.adu)
#: Largest and smallest gain (e-/adu) a scene accepts (far beyond any detector: a gain
#: of 1e-300 made ramps of inf in adu).
MAX_GAIN = 1e9
MIN_GAIN = 1e-9
_NUM = (int, float)


def scene_unit(config):
    """The unit (`UNITS`) and gain (e-/adu, or None) of a scene mapping's ``unit:`` and
    ``gain:`` (default electrons, no gain).

    Raises
    ------
    ConfigError
        A unit other than electron or adu (any spelling `~spherex_reduce.io.input.parse_unit`
        reads), a gain that is not a finite number > 0, a gain with electrons, or a
        scene in adu whose noise components are not all inline (a table's are in
        electrons).

    Examples
    --------
    >>> from spherex_reduce.io.charge_unit import scene_unit
    >>> scene_unit({"unit": "DN", "gain": 1.5, "noise": {"components": [{"name": "w"}]}})
    (Unit("adu"), 1.5)
    >>> scene_unit({})
    (Unit("electron"), None)
    >>> scene_unit({"unit": "furlong"})
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: unit: expected electron or adu, got 'furlong'
    """
    text, gain = config.get("unit", "electron"), config.get("gain")
    unit = None
    if isinstance(text, str):
        try:
            unit = parse_unit(text)
        except ValueError:
            unit = None
    if unit not in UNITS:
        raise ConfigError(f"unit: expected electron or adu, got {text!r}")
    if gain is not None:
        if isinstance(gain, str):  # YAML 1.1 reads 2e0 as text
            try:
                gain = float(gain)
            except ValueError:
                pass
        if isinstance(gain, bool) or not isinstance(gain, _NUM) or not (
                math.isfinite(gain) and MIN_GAIN <= gain <= MAX_GAIN):
            raise ConfigError(f"gain: expected a number of e- per adu in [{MIN_GAIN:g}, "
                              f"{MAX_GAIN:g}], got {gain!r}")
        if unit != u.adu:
            raise ConfigError("gain: the scene is in electrons; a gain (e-/adu) is for a "
                              "scene in adu (unit: adu)")
        gain = float(gain)
    if unit == u.adu:
        items = (config.get("noise") or {}).get("components") if isinstance(
            config.get("noise"), dict) else None
        if config.get("noise") is None or items is None or any(
                not isinstance(c, dict) for c in items):
            raise ConfigError("noise.components: a scene in adu gives its components inline "
                              "(name and numbers, in adu): a table's are in electrons")
    return unit, gain
