"""Noise models for the ``wiener`` reference strategy: read from a table, a ``fit-noise``
result or a scene, with the unit of the charge each describes, and checked.

A model's coefficients come from a built-in table (``spherex-table2``, the
paper's Table 2 in electrons at 100 kHz, the default), an ECSV noise table,
the ECSV ``fit-noise`` writes (its ``reference`` and ``phantom`` streams, in
the unit of the data it was fitted to), or a scene file's ``noise:`` section.
"""

import contextlib
import math
from pathlib import Path

from astropy import units as u
from astropy.table import Table

from ....core.errors import ConfigError
from ....core.fields import FIELD
from ....io.charge_unit import UNITS, scene_unit
from ....io.config import load_yaml
from ....noise import BUILTIN_TABLES, NoiseComponent, noise_components
from ....noise.section import section_components

__all__ = ["DEFAULT_NOISE", "FIT_STREAMS", "NEGATIVE_SIGMAS", "PAPER_PIXEL_RATE",
           "load_noise_model", "noise_model"]

#: A fit-noise coefficient below zero by at most this many standard errors is zero within
#: its error (used as 0); further below it is refused.
NEGATIVE_SIGMAS = 3.0
#: The streams of a ``fit-noise`` result and the samples the component of each is seen by;
#: a row of another stream, or a stream twice, is refused.
FIT_STREAMS = {"reference": "pixels", "phantom": "phantom"}
#: The noise model used when none is named: the paper's Table 2.
DEFAULT_NOISE = "spherex-table2"
#: The pixel rate (Hz) of the paper's electronics, which the default noise model describes.
PAPER_PIXEL_RATE = float(FIELD["pixel_rate"].default)


def load_noise_model(source, where="correct_reference.noise"):
    """Noise components from a table name, a noise table or ``fit-noise`` result, or a scene.

    Parameters
    ----------
    source : str or path
        A built-in table (``'spherex-table2'``), an ECSV noise table (columns
        ``name alpha beta gamma ...``), an ECSV written by ``spherex-reduce
        fit-noise`` (its ``reference`` stream becomes a channel component seen
        by the pixels, its ``phantom`` stream one seen by the phantom reads; a
        row of any other stream, or a stream twice, is refused),
        or a scene file (YAML; its ``noise:`` section).
    where : str
        Where the value came from, for error messages.

    Returns
    -------
    list of `~spherex_reduce.noise.NoiseComponent`

    Raises
    ------
    ConfigError
        The source cannot be read or describes no noise, or a ``fit-noise`` result has
        a row of another stream than ``reference`` and ``phantom`` (or one twice).

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.reference.wiener import load_noise_model
    >>> [c.name for c in load_noise_model("spherex-table2")][:2]
    ['video8', 'roic']
    """
    return noise_model(source, where)[0]


def noise_model(source, where="correct_reference.noise", unit=None):
    """The components of a noise model (`load_noise_model`) and the unit of the charge they
    describe: electrons, except for a ``fit-noise`` result of data in another unit (the
    square root of its ``alpha``'s unit times Hz) and a scene with ``unit: adu``.

    ``unit`` (electron or adu), if given, is the unit wanted: a scene in the other
    one is converted with its ``gain`` (``alpha beta gamma`` times or over
    ``gain²``); without a gain, or for another kind of model, the components are
    returned in their own unit (the caller refuses the mismatch).

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.reference.noise_models import noise_model
    >>> components, unit = noise_model("spherex-table2")
    >>> unit
    Unit("electron")
    """
    wanted, text = unit, str(source)
    unit = u.electron
    if text.lower().endswith((".yaml", ".yml")):
        config, _ = load_yaml(Path(text), "noise model")
        if "noise" not in config:  # a pipeline or other file: not the paper's table silently
            raise ConfigError(f"{where}: {text} has no noise: section (a scene file's noise "
                              "model); name spherex-table2 for the paper's Table 2")
        try:
            unit, gain = scene_unit(config)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {text}: {exc}") from None
        comps = section_components(config["noise"])
        want = None if wanted is None else u.Unit(wanted)
        if gain is not None and want is not None and want != unit and want in UNITS:
            factor = gain * gain if want == u.electron else 1 / (gain * gain)
            comps = [c.replace(alpha=c.alpha * factor, beta=c.beta * factor,
                               gamma=c.gamma * factor) for c in comps]
            unit = want
    elif text in BUILTIN_TABLES or not text.lower().endswith(".fits"):
        comps, unit = _table_components(text, where)
    else:
        raise ConfigError(f"{where}: expected a noise table name, an ECSV table or a scene "
                          f"YAML file, got {text!r}")
    if not comps or all(c.is_zero for c in comps):
        raise ConfigError(f"{where}: {text} describes no noise (every coefficient is zero)")
    return comps, unit


def _table_components(source, where):
    if source not in BUILTIN_TABLES:
        path = Path(source)
        if not path.is_file():
            raise ConfigError(f"{where}: {source!r} is neither a built-in table "
                              f"({', '.join(BUILTIN_TABLES)}) nor an existing file")
        try:
            head = Table.read(path, format="ascii.ecsv")
        except Exception as exc:  # many kinds for a file that is not ECSV
            raise ConfigError(f"{where}: {source} is not a readable ECSV table "
                              f"({type(exc).__name__})") from None
        if "stream" in head.colnames:  # a fit-noise result, in the unit of its data
            unit = u.electron
            alpha = head["alpha"].unit if "alpha" in head.colnames else None
            if alpha is not None:
                with contextlib.suppress(ValueError, TypeError):
                    unit = u.Unit((alpha * u.Hz) ** 0.5)
            comps = []
            for i, row in enumerate(head):
                stream = str(row["stream"])
                if stream not in FIT_STREAMS or stream in [c.name for c in comps]:
                    raise ConfigError(
                        f"{where}: {source}: row {i}: stream {stream!r} "
                        + ("twice" if stream in FIT_STREAMS else "is not a stream fit-noise "
                           f"writes ({', '.join(FIT_STREAMS)})")
                        + ": the model would leave out or double a component")
                try:
                    coefficients = {name: _fitted(row, stream, name, f"{where}: {source}")
                                    for name in ("alpha", "beta", "gamma")}
                    comps.append(NoiseComponent(stream, **coefficients,
                                                exponent=float(row["exponent"]),
                                                visibility=FIT_STREAMS[stream]))
                except ConfigError:
                    raise
                except (KeyError, ValueError) as exc:
                    raise ConfigError(f"{where}: {source}: {exc}") from None
            return comps, unit
    return list(noise_components(source).values()), u.electron


def _fitted(row, stream, name, where):
    """A fit-noise coefficient: below zero by at most `NEGATIVE_SIGMAS` standard errors
    (column ``NAME_err``; 0 without one) it is zero within its error and becomes 0; further
    below, or not finite, the fit describes no noise (`ConfigError`)."""
    value = float(row[name])
    err = float(row[f"{name}_err"]) if f"{name}_err" in row.colnames else 0.0
    if math.isfinite(value) and (value >= 0 or (math.isfinite(err) and
                                                  value >= -NEGATIVE_SIGMAS * err)):
        return max(value, 0.0)
    raise ConfigError(f"{where}: the fitted {stream} {name} = {value:g} ± {err:g} is below "
                      f"zero by more than {NEGATIVE_SIGMAS:g} standard errors (or not finite): "
                      "not a noise model; fit again (more frames, another band) or give a table")
