"""The one table of readout-schedule and detector-geometry fields.

Every parameter of `~spherex_reduce.DetectorGeometry` and
`~spherex_reduce.ReadoutSchedule` is one `Field` of `FIELDS`: its Python
and YAML name, FITS keyword, accepted types, default, unit, bounds, choices
and one line of documentation.  Everything else is derived from the table:

- the dataclass fields, defaults and argument checks of both classes
  (:func:`table_dataclass`, :func:`check_field`);
- the ``geometry:`` and ``readout:`` YAML sections
  (`spherex_reduce.config.GEOMETRY_PARAMETERS`, ``READOUT_PARAMETERS``);
- the FITS keywords written by ``ReadoutSchedule.to_header`` and read back by
  ``from_header``, and both ``to_dict`` methods;
- the options and limits of ``spherex-reduce readout``.

Adding a field means adding one entry here (and handling its meaning in the
class that uses it).

Examples
--------
>>> from spherex_reduce.fields import FIELD
>>> f = FIELD["skip"]
>>> f.keyword, f.default, f.bounds
('ROWSKIP', 24, '>= 1')
>>> f.parameter().check(8, "readout.skip")
8
"""

import functools
import inspect
import math
import operator
from dataclasses import dataclass

import numpy as np
from astropy import units as u

from .parameters import Parameter

__all__ = ["DEFAULT_FRAME_OVERHEAD", "FIELD", "FIELDS", "REF_MODES", "Field", "check_field",
           "section_fields", "table_dataclass"]

#: The reference read modes a schedule accepts (``ref_mode``).
REF_MODES = ("none", "repeated", "distributed")

#: Frame overhead (samples) that, with the default row overhead of 4 samples,
#: gives the paper's 1.51 s frame for S = 24, r = 32, c = 4 on the SPHEREx
#: array (Table 3): 2072 reads x (4 + 64 + 4) samples + 1816 samples = 151000
#: samples at 100 kHz.  Used when neither ``frame_overhead`` nor
#: ``frame_time`` is given.
DEFAULT_FRAME_OVERHEAD = 1816

_NUM = (int, float)


@dataclass(frozen=True)
class Field:
    """One parameter of the detector geometry or the readout schedule.

    Parameters
    ----------
    name : str
        Python argument, attribute and YAML key.
    section : {'geometry', 'readout'}
        `~spherex_reduce.DetectorGeometry` and the ``geometry:`` YAML section,
        or `~spherex_reduce.ReadoutSchedule` and ``readout:``.
    keyword : str
        FITS keyword of the primary header.
    types : tuple of type
        Types accepted from YAML (``type(None)`` for fields that may be null).
    default : object
        Default of the constructor and of the YAML section.
    doc : str
        One line: the YAML documentation and the command-line help.
    unit : str
        Unit of a quantity (astropy name), ``''`` for counts and text.
    minimum : int or float, optional
        Smallest allowed value of a number.
    exclusive_minimum : bool
        ``minimum`` itself is not allowed (``> 0``).
    choices : tuple, optional
        The allowed values of a string.
    cli_max : int, optional
        Largest count ``spherex-reduce readout`` accepts for the option (a
        bound on what a schedule can hold; YAML and FITS values are bounded by
        the memory checks instead).
    comment : str, optional
        Comment of the FITS card; ``doc`` if not given.
    required : bool or str
        Whether ``from_header`` needs the keyword (or the value supplied by the
        configuration): True, False (the default is used), or the condition
        under which it is needed, as documentation text.
    none_means : str, optional
        What a default of None stands for; ``{name}`` placeholders name other
        fields (the command line shows their options).
    instead_of : str, optional
        Name of the field this one states differently (``frame_time`` instead
        of ``frame_overhead``); such a field is not part of ``to_dict``.
    """

    name: str
    section: str
    keyword: str
    types: tuple
    default: object
    doc: str
    unit: str = ""
    minimum: float | None = None
    exclusive_minimum: bool = False
    choices: tuple | None = None
    cli_max: int | None = None
    comment: str | None = None
    required: bool | str = True
    none_means: str | None = None
    instead_of: str | None = None

    @property
    def kind(self):
        """The FITS value type: `int`, `float` or `str`."""
        return float if float in self.types else int if int in self.types else str

    @property
    def nullable(self):
        """True if None is allowed (the value is then derived from other fields)."""
        return type(None) in self.types

    @property
    def bounds(self):
        """The allowed range as text (``'>= 1'``, ``'> 0'``), or ``''``."""
        return self.parameter().bounds

    @property
    def card_comment(self):
        """The comment of the FITS card."""
        return self.doc if self.comment is None else self.comment

    def parameter(self):
        """The YAML `~spherex_reduce.parameters.Parameter` of this field."""
        return Parameter(self.name, self.default, self.types, self.doc, choices=self.choices,
                         minimum=self.minimum, exclusive_minimum=self.exclusive_minimum)


#: Every field, geometry first, each section in the order of its YAML keys.
FIELDS = (
    Field("nrows", "geometry", "NROWS", (int,), 2048, "array rows", minimum=1,
          cli_max=2**16),
    Field("ncols", "geometry", "NCOLS", (int,), 2048, "array columns", minimum=1,
          cli_max=2**16),
    Field("nchannels", "geometry", "NCHAN", (int,), 32, "readout channels", minimum=1,
          cli_max=2**12),
    Field("ref_border", "geometry", "REFBORD", (int,), 4, "reference border width (pixels)",
          unit="pix", minimum=0, cli_max=2**10),
    Field("scan", "geometry", "SCANDIR", (str, list), "same",
          "fast-scan direction: same, alternate or +1/-1 list",
          comment="fast-scan direction per channel", required=False),
    Field("pixel_rate", "geometry", "PIXRATE", _NUM, 100_000.0, "pixel rate per channel (Hz)",
          unit="Hz", minimum=0, exclusive_minimum=True, comment="[Hz] pixel rate per channel"),
    Field("skip", "readout", "ROWSKIP", (int,), 24, "row-chopping skip S", minimum=1,
          cli_max=2**16),
    Field("ref_reads", "readout", "NREFRD", (int,), 32, "reference row reads per frame r",
          minimum=0, cli_max=2**16, required="unless REFMODE is none"),
    Field("ref_mode", "readout", "REFMODE", (str,), "distributed", "reference read mode",
          choices=REF_MODES),
    Field("phantom_reads", "readout", "NPHANT", (int,), 4, "phantom samples per row read c",
          minimum=0, cli_max=2**12),
    Field("row_overhead", "readout", "ROWOVH", (int,), 4, "samples of overhead per row read",
          unit="samples", minimum=0, cli_max=2**20, comment="[samples] overhead per row read",
          required=False),
    Field("frame_overhead", "readout", "FRMOVH", (int, type(None)), None,
          "samples of overhead per frame", unit="samples", minimum=0, cli_max=2**30,
          comment="[samples] overhead per frame", required="unless TFRAME is given",
          none_means=f"{DEFAULT_FRAME_OVERHEAD}, the paper's 1.51 s frame; unless "
                     "{frame_time} is given"),
    Field("nframes", "readout", "NFRAMES", (int,), 74, "frames up the ramp N", minimum=1,
          cli_max=2**20),
    Field("frame_time", "readout", "TFRAME", (int, float, type(None)), None,
          "frame time (s), instead of frame_overhead", unit="s", minimum=0,
          exclusive_minimum=True, comment="[s] frame time", required="unless FRMOVH is given",
          none_means="from {frame_overhead}", instead_of="frame_overhead"),
)

#: The fields by name.
FIELD = {f.name: f for f in FIELDS}


def section_fields(section):
    """The fields of one section (``'geometry'`` or ``'readout'``), in table order.

    Examples
    --------
    >>> from spherex_reduce.fields import section_fields
    >>> [f.name for f in section_fields("geometry")]
    ['nrows', 'ncols', 'nchannels', 'ref_border', 'scan', 'pixel_rate']
    """
    return tuple(f for f in FIELDS if f.section == section)


def table_dataclass(section, **options):
    """Class decorator: a frozen dataclass whose fields are the table's ``section``.

    Fields declared in the class body (e.g. ``geometry``) come first; then
    one field per table entry with its default, in table order (the order of
    positional arguments).
    """
    def decorate(cls):
        annotations = dict(inspect.get_annotations(cls))
        for f in section_fields(section):
            annotations[f.name] = functools.reduce(operator.or_, f.types)
            setattr(cls, f.name, f.default)
        cls.__annotations__ = annotations
        return dataclass(frozen=True, **options)(cls)
    return decorate


def _check_int(name, value, minimum, maximum=None):
    """Return ``value`` as int or raise a ValueError naming ``name`` and its range."""
    allowed = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer {allowed}, got {value!r}")
    if value < minimum or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be {allowed}, got {value}")
    return int(value)


def _positive_finite(name, value, unit):
    """``value`` (a number, or a `~astropy.units.Quantity` in ``unit``) as a float > 0.

    Raises a ValueError naming ``name`` for anything else: strings, booleans,
    arrays, NaN, infinities, zero and negative values.
    """
    try:
        if isinstance(value, u.Quantity):
            number = value.to_value(unit)
        elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
                value, (bool, np.bool_)):
            number = float(value)
        else:
            raise TypeError
        number = float(number)
    except (TypeError, ValueError, u.UnitsError):
        number = float("nan")
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"{name} must be a positive, finite number ({unit}), got {value!r}")
    return number


def check_field(field, value, maximum=None):
    """A constructor argument checked against its field: the value to store.

    Integers are checked against ``minimum`` (and ``maximum``, a bound that
    depends on other fields), quantities must be positive and finite in the
    field's unit, strings one of the ``choices``.

    Raises
    ------
    ValueError
        Naming the field, its allowed values and ``value``.

    Examples
    --------
    >>> from spherex_reduce.fields import FIELD, check_field
    >>> check_field(FIELD["pixel_rate"], 2e5)
    200000.0
    >>> check_field(FIELD["skip"], 0)
    Traceback (most recent call last):
    ...
    ValueError: skip must be >= 1, got 0
    """
    if field.kind is int:
        return _check_int(field.name, value, field.minimum, maximum)
    if field.kind is float:
        return _positive_finite(field.name, value, field.unit)
    if field.choices is not None and value not in field.choices:
        raise ValueError(f"{field.name} must be one of {field.choices}, got {value!r}")
    return value
