"""The field table against everything derived from it: dataclasses, FITS, YAML, CLI and docs.

Each test starts from `spherex_reduce.core.fields.FIELDS` and checks a derived description
through its public behaviour (a header read by keyword, a YAML file, a command line), so
a field added to one description but not to another fails here.
"""

import argparse
import dataclasses
import inspect

import pytest
import yaml
from _paths import ROOT
from astropy import units as u
from astropy.table import Table

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.cli import main
from spherex_reduce.cli import readout as readout_cli
from spherex_reduce.core.errors import ConfigError, FormatError
from spherex_reduce.core.fields import FIELD, FIELDS, SIDES, section_fields
from spherex_reduce.core.parameters import validate_parameters
from spherex_reduce.core.readout.read_order import ORDER_REPLACES
from spherex_reduce.io.config import (
    GEOMETRY_PARAMETERS,
    READOUT_PARAMETERS,
    WINDOW_PARAMETERS,
    load_yaml,
    schedule_from_config,
)

DOCS = ROOT / "docs"

#: Today's public names, FITS keywords and defaults, written out by hand: a rename or a
#: changed default must be deliberate.  New fields need no entry here.
KNOWN = {
    "nrows": ("NROWS", 2048), "ncols": ("NCOLS", 2048), "nchannels": ("NCHAN", 32),
    "ref_border": ("REFBORD", 4), "scan": ("SCANDIR", "same"),
    "pixel_rate": ("PIXRATE", 100_000.0), "skip": ("ROWSKIP", 24), "ref_reads": ("NREFRD", 32),
    "ref_mode": ("REFMODE", "distributed"), "phantom_reads": ("NPHANT", 4),
    "row_overhead": ("ROWOVH", 4), "frame_overhead": ("FRMOVH", None),
    "nframes": ("NFRAMES", 74), "frame_time": ("TFRAME", None),
    "frames_per_group": ("NFRGRP", 1), "group_gap": ("NFRGAP", 0), "groups": ("GRPREADS", None),
}

#: A small array every field's test starts from (fast to build).
BASE_GEOMETRY = {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 2}

#: A valid value other than the default (and than BASE_GEOMETRY) where the generic rule
#: of `other_value` would not give one.
OTHER = {"nrows": 40, "ncols": 32, "nchannels": 4, "ref_border": 3, "scan": "alternate",
         "ref_mode": "repeated", "frame_overhead": 123, "frame_time": 0.05,
         "groups": [[0, 1], *([k] for k in range(3, 75)), [76, 77, 78]],  # 74 groups
         "read_times": [3.0 * k + 0.25 * (k % 3) for k in range(74)],  # uneven
         "preset": "H2RG",
         # reference row 0 three times, the active rows 2..29 backwards, reference row 31
         "order": [0, 0, *range(29, 1, -1), 31, 0]}


#: The fields of a constructor (the window's: tests/core/test_window.py).
CONSTRUCTED = [f for f in FIELDS if f.section != "window"]


def other_value(field):
    """A valid value of ``field`` that is neither its default nor the base geometry's."""
    if field.name in OTHER:
        return OTHER[field.name]
    if field.choices:
        return next(c for c in field.choices if c != field.default)
    if field.kind is int:
        return field.default + 3
    if field.kind is float:
        return field.default * 2
    raise AssertionError(f"add a non-default value of the new field {field.name!r} to OTHER")


def base_geometry(name=None, value=None):
    """The base geometry, on 4 quadrants when ``name`` is a field of quadrants only."""
    if name in ("first_corner", "fast_axis") or (name, value) == ("channels", "quadrants"):
        return {**BASE_GEOMETRY, "channels": "quadrants", "nchannels": 4}
    return dict(BASE_GEOMETRY)


def build(name=None, value=None):
    """A schedule on the base geometry with field ``name`` set to ``value``."""
    geometry = base_geometry(name, value)
    readout = {}
    if name is not None:
        (geometry if FIELD[name].section == "geometry" else readout)[name] = value
    return ReadoutSchedule(DetectorGeometry(**geometry), **readout)


def holder(schedule, field):
    return schedule.geometry if field.section == "geometry" else schedule


def stored(value):
    """A field value as plain Python (a frame time in s)."""
    return value.to_value(u.s) if isinstance(value, u.Quantity) else value


def same(field, a, b):
    """Equal values of ``field`` (reals to rounding; a structure as its FITS text)."""
    if field.to_text is not None:
        a, b = (x if isinstance(x, str) else field.to_text(x) for x in (a, b))
    a, b = stored(a), stored(b)
    return a == pytest.approx(b, rel=1e-12) if field.kind is float else a == b


def names(section):
    return [f.name for f in section_fields(section)]


# -- the table itself ----------------------------------------------------------------------
def test_known_names_keywords_and_defaults_are_kept():
    for name, (keyword, default) in KNOWN.items():
        assert (FIELD[name].keyword, FIELD[name].default) == (keyword, default), name
        assert FIELD[name].section == ("geometry" if name in BASE_GEOMETRY
                                       or name in ("scan", "pixel_rate") else "readout")
    keywords = [k for f in FIELDS for k in (f.keyword, *(f.side_keywords or ()))]
    assert len(set(keywords)) == len(keywords)
    assert all(len(k) <= 8 and k.isupper() for k in keywords)
    assert all(len(f.side_keywords) == len(SIDES) for f in FIELDS if f.side_keywords)
    assert {f.section for f in FIELDS} == {"geometry", "readout", "window"}


def test_every_default_passes_its_own_checks():
    for f in FIELDS:
        assert f.parameter().check(f.default, f.name) == f.default


# -- the dataclasses -----------------------------------------------------------------------
def test_dataclass_fields_are_the_table():
    fields = dataclasses.fields(DetectorGeometry)  # plus three keyword-only ones
    assert [f.name for f in fields if not f.kw_only] == names("geometry")
    assert [f.name for f in fields if f.kw_only] == ["window", "channel_border", "stored"]
    assert [f.name for f in dataclasses.fields(ReadoutSchedule)] == ["geometry",
                                                                      *names("readout")]
    for cls, section in ((DetectorGeometry, "geometry"), (ReadoutSchedule, "readout")):
        params = inspect.signature(cls).parameters
        for f in section_fields(section):
            assert params[f.name].default == f.default, f.name


@pytest.mark.parametrize("field", [f for f in CONSTRUCTED if f.minimum is not None],
                         ids=lambda f: f.name)
def test_constructor_refuses_just_below_the_minimum(field):
    value = field.minimum if field.exclusive_minimum else field.minimum - 1
    with pytest.raises(ValueError, match=field.name):
        build(field.name, value)
    if field.kind is int and field.name not in BASE_GEOMETRY:
        assert stored(getattr(holder(build(field.name, field.minimum), field), field.name)) \
            == field.minimum


@pytest.mark.parametrize("field", [f for f in FIELDS if f.choices], ids=lambda f: f.name)
def test_constructor_accepts_exactly_the_choices(field):
    for choice in field.choices:
        assert getattr(holder(build(field.name, choice), field), field.name) == choice
    with pytest.raises(ValueError, match=f"{field.name} must be one of"):
        build(field.name, "no such choice")


# -- FITS ----------------------------------------------------------------------------------
@pytest.mark.parametrize("field", CONSTRUCTED, ids=lambda f: f.name)
def test_header_round_trip_of_a_non_default_value(field):
    value = other_value(field)
    s = build(field.name, value)
    got = getattr(holder(s, field), field.name)
    assert same(field, got, value)
    assert s != build()
    h = s.to_header()
    assert h.comments[field.keyword] == field.card_comment
    if field.name == "scan":
        assert h[field.keyword] == s.geometry.scan_label
    else:
        assert same(field, h[field.keyword], got)
    again = ReadoutSchedule.from_header(h, s.to_table())
    assert again == s
    assert same(field, getattr(holder(again, field), field.name), got)


@pytest.mark.parametrize("field", [f for f in CONSTRUCTED if f.side_keywords],
                         ids=lambda f: f.name)
def test_per_side_field_round_trips_through_header_yaml_and_command_line(field):
    value = {"top": 3, "left": 2}
    s = build(field.name, value)
    sides = [value.get(side, 0) for side in SIDES]
    h = s.to_header()
    assert field.keyword not in h and [h[k] for k in field.side_keywords] == sides
    assert ReadoutSchedule.from_header(h, s.to_table()) == s
    section = s.geometry.to_dict() if field.section == "geometry" else s.to_dict()
    assert section[field.name] == dict(zip(SIDES, sides, strict=True))
    config, _ = load_yaml(yaml.safe_dump({field.section: section}), "scene")
    assert schedule_from_config(config.get("geometry"), config.get("readout")) == s
    args = [x for k, v in BASE_GEOMETRY.items() if k != field.name
            for x in ("--" + k.replace("_", "-"), v)]
    flag = "--" + field.name.replace("_", "-")
    assert readout_cli.schedule_from_args(_parse(flag, "top=3,left=2", *args)) == s
    equal = build(field.name, dict.fromkeys(SIDES, 2))  # all sides equal: the one keyword
    assert equal == build(field.name, 2) and field.keyword in equal.to_header()
    assert not set(field.side_keywords) & set(equal.to_header())


def test_header_has_one_card_per_field_and_the_channel_width():
    h = build().to_header()  # fields written only when set are not, at their defaults
    assert list(h) == [*(k for f in FIELDS if not f.written_if_set
                         for k in ((f.keyword, "CHANW") if f.name == "nchannels"
                                   else (f.keyword,)))]


@pytest.mark.parametrize("field", CONSTRUCTED, ids=lambda f: f.name)
def test_missing_keyword_is_required_or_supplied_or_defaulted(field):
    s = build(field.name, other_value(field))
    h = s.to_header()
    del h[field.keyword]
    if field.name in ("channels", "first_corner", "fast_axis"):
        del h["CHANW"]  # the channel width of that layout's readout frame, checked on read
    value = stored(getattr(holder(s, field), field.name))
    if field.name == "scan":
        value = s.geometry.scan_label if isinstance(s.geometry.scan, str) else list(value)
    assert ReadoutSchedule.from_header(h, **{field.name: value}) == s
    if field.required is True:
        with pytest.raises(FormatError, match=f"missing readout keyword\\(s\\) {field.keyword}"):
            ReadoutSchedule.from_header(h)
    elif field.required is False:
        del h["TFRAME"]  # else it would disagree with a default overhead
        again = ReadoutSchedule.from_header(h)
        assert getattr(holder(again, field), field.name) == field.default
    else:  # needed unless another keyword says it: TFRAME or FRMOVH, NREFRD unless REFMODE none
        try:
            assert ReadoutSchedule.from_header(h) == s
        except FormatError as exc:
            assert "missing readout keyword(s)" in str(exc) and field.keyword in str(exc)


def test_reference_reads_are_needed_unless_the_mode_is_none():
    h = build("ref_mode", "none").to_header()
    del h["NREFRD"]
    assert ReadoutSchedule.from_header(h) == build("ref_mode", "none")
    h["REFMODE"] = "repeated"
    with pytest.raises(FormatError, match=r"missing readout keyword\(s\) NREFRD"):
        ReadoutSchedule.from_header(h)


@pytest.mark.parametrize("field", [f for f in FIELDS if f.kind in (int, float)],
                         ids=lambda f: f.name)
def test_header_refuses_a_keyword_below_its_minimum(field):
    h = build().to_header()
    h[field.keyword] = (field.minimum - 1) if field.kind is int else -1.0
    with pytest.raises(FormatError, match=field.keyword):
        ReadoutSchedule.from_header(h)


def test_unknown_supplied_parameter_lists_the_table():
    with pytest.raises(FormatError) as info:
        ReadoutSchedule.from_header(build().to_header(), skp=3)
    assert str(info.value) == (f"unknown readout parameter(s) ['skp']; valid: "
                               f"{sorted(f.name for f in FIELDS)}")


# -- YAML ----------------------------------------------------------------------------------
def test_yaml_sections_are_the_table():
    assert [p.name for p in GEOMETRY_PARAMETERS] == names("geometry")
    assert [p.name for p in READOUT_PARAMETERS] == names("readout")
    assert [p.name for p in WINDOW_PARAMETERS] == names("window")
    for p in (*GEOMETRY_PARAMETERS, *READOUT_PARAMETERS, *WINDOW_PARAMETERS):
        f = FIELD[p.name]
        assert (p.default, p.types, p.doc, p.choices, p.minimum, p.exclusive_minimum) == (
            f.default, f.types, f.doc, f.choices, f.minimum, f.exclusive_minimum)


@pytest.mark.parametrize("field", CONSTRUCTED, ids=lambda f: f.name)
def test_yaml_text_round_trip_of_a_non_default_value(field):
    s = build(field.name, other_value(field))
    sections = {"geometry": s.geometry.to_dict(), "readout": s.to_dict()}
    assert set(sections["geometry"]) == set(names("geometry"))
    replaced = ORDER_REPLACES if field.name == "order" else ()  # an order replaces them
    assert set(sections["readout"]) == {n for n in names("readout")
                                        if not FIELD[n].instead_of and n not in replaced}
    config, _ = load_yaml(yaml.safe_dump(sections), "scene")
    assert schedule_from_config(config["geometry"], config["readout"]) == s


@pytest.mark.parametrize("field", [f for f in FIELDS if f.minimum is not None],
                         ids=lambda f: f.name)
def test_yaml_accepts_exactly_the_minimum(field):
    section = [field.parameter()]
    inside = field.minimum + (1e-9 if field.exclusive_minimum else 0)
    assert validate_parameters({field.name: inside}, section, field.section)[field.name] == inside
    outside = field.minimum if field.exclusive_minimum else field.minimum - 1
    with pytest.raises(ConfigError, match=f"{field.section}.{field.name}: must be"):
        validate_parameters({field.name: outside}, section, field.section)


# -- the readout command -------------------------------------------------------------------
def _parse(*argv):
    parser = argparse.ArgumentParser(exit_on_error=False)
    readout_cli.add_parser(parser.add_subparsers())
    return parser.parse_args(["readout", *map(str, argv)])


def test_readout_has_one_option_per_field():
    assert [(flag, section, key) for flag, section, key, _ in readout_cli.OPTIONS] == [
        ("--" + f.name.replace("_", "-"), f.section, f.name) for f in FIELDS]


@pytest.mark.parametrize("field", [f for f in FIELDS if f.kind in (int, float)],
                         ids=lambda f: f.name)
def test_readout_accepts_exactly_the_bounds(field, capsys):
    flag = "--" + field.name.replace("_", "-")
    if field.kind is int:
        inside = [field.minimum, field.cli_max]
        outside = [field.minimum - 1, field.cli_max + 1]
        message = f"must be a whole number from {field.minimum} to {field.cli_max}"
    else:
        inside, outside, message = [1e-9], [0, -1], "must be > 0"
    for value in inside:
        assert getattr(_parse(flag, value), field.name) == value
    for value in outside:
        assert main(["readout", flag, str(value)]) == 2
        assert f"argument {flag}: {message}" in capsys.readouterr().err


@pytest.mark.parametrize("field", CONSTRUCTED, ids=lambda f: f.name)
def test_readout_option_sets_the_field(field, tmp_path):
    value = other_value(field)
    args = [x for k, v in base_geometry(field.name, value).items() if k != field.name
            for x in ("--" + k.replace("_", "-"), v)]
    text = value if field.to_text is None else field.to_text(value)
    if str in field.types and field.to_text is not None:  # a file's path (``--order``)
        text = tmp_path / "value.ecsv"
        Table({field.name: value}).write(text, format="ascii.ecsv")
    s = readout_cli.schedule_from_args(_parse("--" + field.name.replace("_", "-"), text, *args))
    assert s == build(field.name, value)


# -- the docs ------------------------------------------------------------------------------
def _type_text(field):
    words = {int: "integer", float: "number", str: "string", list: "list", dict: "mapping"}
    kinds = [words[t] for t in field.types if t in words and not (t is int and float in
                                                                    field.types)]
    text = " or ".join(kinds)
    if field.bounds:
        text += " " + field.bounds.replace(">=", "≥")
    if field.side_keywords:  # "integer ≥ 0 or mapping of top, ...": the bound is each side's
        text = text.replace(" or mapping", "") + f" or mapping of {', '.join(SIDES)}"
    if field.nullable:
        text += " or null"
    return text


def _default_text(field):
    if field.default is None:
        return "null: " + field.none_means.format(**{f.name: f"``{f.name}``" for f in FIELDS})
    if isinstance(field.default, float):
        return f"{field.default:g}"
    return f"``{field.default}``" if isinstance(field.default, str) else str(field.default)


def _choices_text(field):
    return f"; one of {', '.join(f'``{c}``' for c in field.choices)}" if field.choices else ""


def fits_keyword_table():
    """The readout keyword table of docs/fits.rst, from the field table."""
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 10 14 8 36 32", "",
             "   * - Keyword", "     - YAML name", "     - Unit", "     - Meaning",
             "     - When absent"]
    for f in FIELDS:
        if f.required is True:
            absent = "required"
        elif f.required is False:
            absent = f"default {_default_text(f)}"
        else:
            absent = f"required {f.required}"
        meaning = f.card_comment.removeprefix(f"[{f.unit}] ")  # the unit has its column
        keyword = f"``{f.keyword}``"
        if f.side_keywords:
            keyword += f" or {' '.join(f'``{k}``' for k in f.side_keywords)}"
        lines += [f"   * - {keyword}", f"     - ``{f.name}``", f"     - {f.unit}".rstrip(),
                  f"     - {meaning}{_choices_text(f)}", f"     - {absent}"]
    return "\n".join(lines) + "\n"


def yaml_section_table(section):
    """The table of one section of docs/yaml.rst, from the field table."""
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 16 20 20 8 36", "",
             "   * - Key", "     - Type", "     - Default", "     - Unit", "     - Meaning"]
    for f in section_fields(section):
        lines += [f"   * - ``{f.name}``", f"     - {_type_text(f)}",
                  f"     - {_default_text(f)}", f"     - {f.unit}".rstrip(),
                  f"     - {f.doc}{_choices_text(f)}"]
    return "\n".join(lines) + "\n"


def test_docs_fits_lists_every_keyword_as_the_table_says():
    text = (DOCS / "fits.rst").read_text(encoding="utf-8")
    assert fits_keyword_table() in text, (
        "regenerate with tests/core/test_fields.py:fits_keyword_table")


@pytest.mark.parametrize("section", ["geometry", "readout", "window"])
def test_docs_yaml_lists_every_key_as_the_table_says(section):
    text = (DOCS / "yaml.rst").read_text(encoding="utf-8")
    assert yaml_section_table(section) in text, \
        "regenerate with tests/core/test_fields.py:yaml_section_table"
