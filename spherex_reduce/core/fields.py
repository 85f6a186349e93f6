"""The one table of readout-schedule and detector-geometry fields.

Every parameter of `~spherex_reduce.DetectorGeometry` and
`~spherex_reduce.ReadoutSchedule` is one `Field` of `FIELDS`: its Python
and YAML name, FITS keyword, accepted types, default, unit, bounds, choices
and one line of documentation.  Everything else is derived from the table:

- the dataclass fields, defaults and argument checks of both classes
  (:func:`table_dataclass`, :func:`check_field`);
- the ``geometry:`` and ``readout:`` YAML sections
  (`spherex_reduce.io.config.GEOMETRY_PARAMETERS`, ``READOUT_PARAMETERS``);
- the FITS keywords written by ``ReadoutSchedule.to_header`` (:func:`field_cards`)
  and read back by ``from_header`` (:func:`read_field`): one keyword per field,
  or for a field that may differ per side of the array (``ref_border``,
  `Field.side_keywords`) one keyword when the sides are equal and one per side
  when they differ; and both ``to_dict`` methods;
- the options and limits of ``spherex-reduce readout``.

Adding a field means adding one entry here (and handling its meaning in the
class that uses it).

Examples
--------
>>> from spherex_reduce.core.fields import FIELD
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
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from astropy import units as u

from .channel_layout import CHANNEL_LAYOUTS, FAST_AXES, FIRST_CORNERS
from .errors import FormatError
from .parameters import Parameter
from .readout.frame_times import format_read_times, parse_read_times
from .readout.groups import format_groups, parse_groups
from .readout.read_order import order_text, parse_order_text

__all__ = ["DEFAULT_FRAME_OVERHEAD", "FIELD", "FIELDS", "REF_MODES", "SIDES", "Field",
           "card_text", "check_field", "check_sides", "field_cards", "header_keyword",
           "read_field", "section_fields", "table_dataclass"]

#: The sides of the array a per-side field (``ref_border``) has a value for: ``top`` is
#: the rows from row 0 (read first), ``bottom`` the last rows, ``left`` the columns from
#: column 0 (left of the first channel), ``right`` the last columns.
SIDES = ("top", "bottom", "left", "right")

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
    section : {'geometry', 'readout', 'window'}
        `~spherex_reduce.DetectorGeometry` and the ``geometry:`` YAML section,
        `~spherex_reduce.ReadoutSchedule` and ``readout:``, or the
        `~spherex_reduce.core.window.Window` of a larger array and ``window:``.
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
    side_keywords : tuple of str, optional
        For a count that may differ on each side of the array (`SIDES`): the
        FITS keyword of each side, in `SIDES` order.  ``to_header`` writes
        them when the sides differ and ``keyword`` alone when all are equal;
        ``from_header`` reads either form.  The YAML value is then one number
        (every side) or a mapping of sides (missing sides 0).
    written_if_set : bool
        ``to_header`` writes the card only when the value is not the default
        (fields added later: a schedule that does not use them keeps the
        header it always had).
    to_text, from_text : callable, optional
        For a value that is a structure (``groups``): its text in a FITS card
        and on the command line, and back (``from_text`` raises ValueError).
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
    side_keywords: tuple | None = None
    written_if_set: bool = False
    to_text: object = None
    from_text: object = None

    @property
    def keywords(self):
        """The field's keyword and, for a per-side field, the keyword of each side."""
        return (self.keyword, *(self.side_keywords or ()))

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
        """The YAML `~spherex_reduce.core.parameters.Parameter` of this field."""
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
    Field("ref_border", "geometry", "REFBORD", (int, dict), 4,
          "reference border width (pixels): one for every side, or per side",
          unit="pix", minimum=0, cli_max=2**10, comment="reference border width (pixels)",
          required=False, side_keywords=("REFBTOP", "REFBBOT", "REFBLEFT", "REFBRIGH")),
    Field("scan", "geometry", "SCANDIR", (str, list), "same",
          "fast-scan direction: same, alternate or +1/-1 list",
          comment="fast-scan direction per channel", required=False),
    Field("pixel_rate", "geometry", "PIXRATE", _NUM, 100_000.0, "pixel rate per channel (Hz)",
          unit="Hz", minimum=0, exclusive_minimum=True, comment="[Hz] pixel rate per channel"),
    Field("channels", "geometry", "CHANLAY", (str,), "columns",
          "how the channels lie on the stored image: columns, rows or quadrants",
          choices=CHANNEL_LAYOUTS, comment="channels: columns, rows or quadrants",
          required=False, written_if_set=True),
    Field("first_corner", "geometry", "FIRSTCRN", (str,), "outer",
          "quadrants: the corner each quadrant is read from, outer or inner",
          choices=FIRST_CORNERS, comment="quadrants read from the outer or inner corner",
          required=False, written_if_set=True),
    Field("fast_axis", "geometry", "FASTAXIS", (str,), "rows",
          "quadrants: the fast scan runs along rows or columns", choices=FAST_AXES,
          comment="quadrants: fast scan along rows or columns", required=False,
          written_if_set=True),
    Field("preset", "geometry", "GEOPRSET", (str, type(None)), None,
          "named detector layout the other geometry keys start from",
          comment="geometry preset the fields start from", required=False,
          none_means="no preset", written_if_set=True),
    Field("skip", "readout", "ROWSKIP", (int,), 24, "row-chopping skip S", minimum=1,
          cli_max=2**16, required="unless ROWORDER is given"),
    Field("ref_reads", "readout", "NREFRD", (int,), 32, "reference row reads per frame r",
          minimum=0, cli_max=2**16, required="unless REFMODE is none or ROWORDER is given"),
    Field("ref_mode", "readout", "REFMODE", (str,), "distributed", "reference read mode",
          choices=REF_MODES, required="unless ROWORDER is given"),
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
    Field("frames_per_group", "readout", "NFRGRP", (int,), 1,
          "frames averaged into each stored frame (group)", minimum=1, cli_max=2**16,
          required=False, written_if_set=True),
    Field("group_gap", "readout", "NFRGAP", (int,), 0,
          "frames read and discarded between groups", minimum=0, cli_max=2**16,
          required=False, written_if_set=True),
    Field("groups", "readout", "GRPREADS", (list, type(None)), None,
          "reads (0-based frames) averaged into each group, instead of frames_per_group",
          comment="reads of each group: ';' between groups", required=False,
          none_means="groups of {frames_per_group} frames, {group_gap} apart",
          written_if_set=True, to_text=format_groups, from_text=parse_groups),
    Field("read_times", "readout", "RDTIMES", (list, type(None)), None,
          "time (s) of every stored frame's read, for reads at uneven times",
          unit="s", comment="[s] time of each read: ',' between reads", required=False,
          none_means="every frame_time (or the groups' mean reads)",
          written_if_set=True, to_text=format_read_times, from_text=parse_read_times),
    Field("order", "readout", "ROWORDER", (list, str, type(None)), None,
          "explicit read order: the physical row of every read (reference rows any number of "
          "times), or an ECSV file of them; instead of skip, ref_reads and ref_mode",
          comment="READOUT table gives the read order",
          required="unless ROWSKIP and REFMODE are given",
          none_means="from {skip}, {ref_reads} and {ref_mode}", written_if_set=True,
          to_text=order_text, from_text=parse_order_text),
    # A window of a larger array (`spherex_reduce.core.window`): the ``window:`` YAML
    # section; geometry.nrows/ncols are then the window's size, its channels, scan and
    # reference border are derived from the full array's.
    Field("first_row", "window", "WINROW", (int, type(None)), None,
          "window: its first row in the full array", minimum=0, cli_max=2**16,
          required=False, none_means="no window", written_if_set=True),
    Field("first_column", "window", "WINCOL", (int, type(None)), None,
          "window: its first column in the full array", minimum=0, cli_max=2**16,
          required=False, none_means="no window", written_if_set=True),
    Field("full_nrows", "window", "FULLROWS", (int, type(None)), None,
          "window: rows of the full array", minimum=1, cli_max=2**16, required=False,
          none_means="no window", written_if_set=True),
    Field("full_ncols", "window", "FULLCOLS", (int, type(None)), None,
          "window: columns of the full array", minimum=1, cli_max=2**16, required=False,
          none_means="no window", written_if_set=True),
    Field("full_nchannels", "window", "FULLCHAN", (int, type(None)), None,
          "window: readout channels of the full array", minimum=1, cli_max=2**12,
          required=False, none_means="no window", written_if_set=True),
    Field("full_scan", "window", "FULLSCAN", (str, list, type(None)), None,
          "window: fast-scan direction of the full array's channels",
          comment="full array's fast-scan direction", required=False,
          none_means="same", written_if_set=True),
    Field("full_ref_border", "window", "FULLBORD", (int, dict, type(None)), None,
          "window: reference border of the full array (pixels)", unit="pix", minimum=0,
          cli_max=2**10, comment="full array's reference border width (pixels)",
          required=False, none_means="4 on every side", written_if_set=True,
          side_keywords=("FULLBTOP", "FULLBBOT", "FULLBLFT", "FULLBRGT")),
)

#: The fields by name.
FIELD = {f.name: f for f in FIELDS}


def section_fields(section):
    """The fields of one section (``'geometry'`` or ``'readout'``), in table order.

    Examples
    --------
    >>> from spherex_reduce.core.fields import section_fields
    >>> [f.name for f in section_fields("geometry")][:6]
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


def check_sides(field, value):
    """A per-side value (`Field.side_keywords`) as a dict of `SIDES`, each side checked.

    ``value`` is one number (every side) or a mapping of sides to numbers
    (sides left out are 0).

    Raises
    ------
    ValueError
        An unknown side, or a side that is not an integer >= the field's
        minimum; the message names ``field.side``.

    Examples
    --------
    >>> from spherex_reduce.core.fields import FIELD, check_sides
    >>> check_sides(FIELD["ref_border"], {"top": 4, "left": 4})
    {'top': 4, 'bottom': 0, 'left': 4, 'right': 0}
    >>> check_sides(FIELD["ref_border"], {"up": 4})
    Traceback (most recent call last):
    ...
    ValueError: ref_border has no side 'up'; the sides are top, bottom, left, right
    """
    if not isinstance(value, Mapping):
        number = _check_int(field.name, value, field.minimum)
        return dict.fromkeys(SIDES, number)
    unknown = [k for k in value if k not in SIDES]
    if unknown:
        raise ValueError(f"{field.name} has no side {unknown[0]!r}; the sides are "
                         f"{', '.join(SIDES)}")
    return {side: _check_int(f"{field.name}.{side}", value.get(side, 0), field.minimum)
            for side in SIDES}


def field_cards(field, value):
    """The FITS cards ``(keyword, value, comment)`` of a field's value.

    A per-side field (`Field.side_keywords`) is one card ``field.keyword``
    when every side is equal, else one card per side.

    Examples
    --------
    >>> from spherex_reduce.core.fields import FIELD, field_cards
    >>> field_cards(FIELD["ref_border"], 4)
    [('REFBORD', 4, 'reference border width (pixels)')]
    >>> [card[:2] for card in field_cards(FIELD["ref_border"], {"top": 4, "left": 4})]
    [('REFBTOP', 4), ('REFBBOT', 0), ('REFBLEFT', 4), ('REFBRIGH', 0)]
    """
    if field.side_keywords is None:
        if field.to_text is None:
            return [(field.keyword, value, field.card_comment)]
        text = field.to_text(value)
        return [(field.keyword, text, _fitting_comment(text, field.card_comment))]
    sides = check_sides(field, value)
    if len(set(sides.values())) == 1:
        return [(field.keyword, sides["top"], field.card_comment)]
    return [(key, sides[side], f"{field.card_comment.removesuffix(' (pixels)')}, {side} "
             "side (pixels)") for side, key in zip(SIDES, field.side_keywords, strict=True)]


def _fitting_comment(text, comment):
    """``comment`` cut to fit on the card of string ``text`` when the text fits on one card
    (a text longer than 68 characters goes on CONTINUE cards, the comment on the last one):
    a card is 80 characters, the keyword and ``= `` take 10, the quoted text at least 10,
    `` / `` 3."""
    if len(text) > 68:
        return comment
    return comment[:max(0, 80 - 10 - (max(len(text), 8) + 2) - 3)]


def read_field(header, field):
    """A field's value from a FITS header (checked), or None if the header has none.

    A per-side field is read from ``field.keyword`` (every side) and from its
    side keywords (sides whose keyword is absent take ``field.keyword``'s
    value, or 0); the result is an int when every side is equal, else a dict
    of `SIDES`.

    Raises
    ------
    FormatError
        A keyword of the wrong type or below the minimum, or both forms in
        the header with values that disagree; the message names them.

    Examples
    --------
    >>> from astropy.io import fits
    >>> from spherex_reduce.core.fields import FIELD, read_field
    >>> read_field(fits.Header({"REFBTOP": 4, "REFBLEFT": 4}), FIELD["ref_border"])
    {'top': 4, 'bottom': 0, 'left': 4, 'right': 0}
    >>> read_field(fits.Header({"REFBORD": 4, "REFBBOT": 0}), FIELD["ref_border"])
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.FormatError: keywords REFBORD=4 and REFBBOT=0 disagree: ... not both
    """
    def read(key):
        return header_keyword(header, key, field.kind, positive=field.exclusive_minimum,
                              minimum=None if field.exclusive_minimum else field.minimum)

    one = read(field.keyword) if field.keyword in header else None
    if field.from_text is not None and one is not None:
        try:
            return field.from_text(one)
        except ValueError as exc:
            raise FormatError(f"keyword {field.keyword}: {exc}") from None
    if field.side_keywords is None:
        return one
    given = {side: (key, read(key)) for side, key in zip(SIDES, field.side_keywords,
                                                          strict=True) if key in header}
    if not given:
        return one
    for key, value in given.values():
        if one is not None and value != one:
            raise FormatError(
                f"keywords {field.keyword}={one} and {key}={value} disagree: give "
                f"{field.keyword} for every side or {' '.join(field.side_keywords)}, not both")
    sides = {side: given[side][1] if side in given else (one or 0) for side in SIDES}
    return sides["top"] if len(set(sides.values())) == 1 else sides


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
    >>> from spherex_reduce.core.fields import FIELD, check_field
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


_MISSING = object()


def header_keyword(header, key, kind, minimum=None, default=_MISSING, positive=False):
    """``header[key]`` checked for type, finiteness and range.

    Parameters
    ----------
    header : `astropy.io.fits.Header`
    key : str
        Keyword.
    kind : {int, float, str}
        Expected type.  An integer may be written as a real with no fraction
        (``16.0``); booleans and strings are never numbers.
    minimum : int or float, optional
        Smallest allowed value (numbers).
    default : optional
        Returned when the keyword is absent; without it, absence is an error.
    positive : bool
        The number must be > 0.

    Returns
    -------
    int, float or str

    Raises
    ------
    FormatError
        Naming the keyword and the value (also for a card astropy cannot
        parse, e.g. ``NAN``).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from spherex_reduce.core.fields import header_keyword
    >>> header_keyword(fits.Header({"NFRAMES": 10}), "NFRAMES", int, minimum=1)
    10
    >>> header_keyword(fits.Header({"NFRAMES": 5.5}), "NFRAMES", int, minimum=1)
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.FormatError: keyword NFRAMES must be an integer, got 5.5
    """
    if key not in header:
        if default is _MISSING:
            raise FormatError(f"keyword {key} is missing")
        return default
    try:
        value = header.cards[key].value
    except Exception as exc:  # VerifyError: a card astropy cannot parse (NAN, 1E999x, ...)
        raise FormatError(f"keyword {key} has an unreadable value "
                          f"{card_text(header.cards[key])!r}") from exc
    if kind is str:
        if not isinstance(value, str):
            raise FormatError(f"keyword {key} must be a string, got {value!r}")
        return value
    number = (isinstance(value, (int, float, np.integer, np.floating))
              and not isinstance(value, (bool, np.bool_)))
    if not number or not math.isfinite(value):
        what = "an integer" if kind is int else "a finite number"
        raise FormatError(f"keyword {key} must be {what}, got {value!r}")
    if kind is int:
        if value != int(value):
            raise FormatError(f"keyword {key} must be an integer, got {value!r}")
        value = int(value)
    else:
        value = float(value)
    if minimum is not None and value < minimum:
        raise FormatError(f"keyword {key} must be >= {minimum}, got {value!r}")
    if positive and value <= 0:
        raise FormatError(f"keyword {key} must be > 0, got {value!r}")
    return value


def card_text(card):
    """The value of a header card as written in the file (for a card astropy cannot parse).

    Parameters
    ----------
    card : `astropy.io.fits.Card`

    Returns
    -------
    str
        The characters of the value field, comment left out (empty for a card
        made in memory, which has no image yet).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from spherex_reduce.core.fields import card_text
    >>> card_text(fits.Card.fromstring("NROWS   = 12x / rows of the array"))
    '12x'
    """
    return str(getattr(card, "_image", "") or "")[10:].split("/")[0].strip()
