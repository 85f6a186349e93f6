"""The kinds of a `Parameter`: numbers, lists of items of a kind, mappings with their own table.

Every refusal names the key path of the value (``a.b[2].c``) and, through
`validate_file`, the file; valid values come back converted (integers to
floats where a number is declared) with defaults filled in.  The expected
messages are written out here, not built from the code's own text.
"""

import re

import pytest

from spherex_reduce.core.errors import ConfigError
from spherex_reduce.core.parameters import Parameter, validate_file, validate_parameters

COUNT = Parameter("count", 3, (int,), "a count", minimum=1, maximum=10)
READS = Parameter("reads", [0, 8], (list,), "reads tried", length=(1, 3),
                  items=Parameter("", None, (int,), "reads", minimum=0, maximum=100))
MODES = Parameter("modes", ["a"], (list,), "modes tried", length=(1, None),
                  items=Parameter("", None, (str,), "a mode", choices=("a", "b")))
EDGES = Parameter("edges", 4, (int, list), "bins or edges", minimum=1, maximum=50,
                  items=Parameter("", None, (float,), "an edge", minimum=0),
                  length=(2, 5))
POINT = (Parameter("x", 0.0, (float,), "x", minimum=-1, maximum=1),
         Parameter("label", "p", (str,), "its name"))
SEARCH = Parameter("search", None, (dict, type(None)), "the search", fields=(
    COUNT, READS, MODES,
    Parameter("points", [], (list,), "points", items=Parameter(
        "", None, (dict,), "a point", fields=POINT)),
    Parameter("sky", None, (dict, type(None)), "a sky", fields=(
        Parameter("rms", 0.05, (float,), "rms", minimum=1e-20, maximum=1e20, unit="e/s"),)),
))
TABLE = (Parameter("seed", 0, (int,), "seed", minimum=0), SEARCH, EDGES)


def refused(config, message):
    with pytest.raises(ConfigError, match=f"^{re.escape(message)}$"):
        validate_file(config, TABLE, "f.yaml")


def test_valid_values_pass_converted_with_defaults_filled_in():
    assert validate_file({}, TABLE, "f.yaml") == {
        "seed": 0,
        "search": {"count": 3, "reads": [0, 8], "modes": ["a"], "points": [],
                   "sky": {"rms": 0.05}},
        "edges": 4}
    got = validate_file({"seed": 7, "edges": [0, 1, 2.5], "search": {
        "count": 10, "reads": [0, 100, 5], "modes": ["b", "a", "b"],
        "points": [{"x": 1}, {"label": "q"}], "sky": None}}, TABLE, "f.yaml")
    assert got == {"seed": 7, "edges": [0.0, 1.0, 2.5], "search": {
        "count": 10, "reads": [0, 100, 5], "modes": ["b", "a", "b"],
        "points": [{"x": 1.0, "label": "p"}, {"x": 0.0, "label": "q"}],
        "sky": {"rms": 0.05}}}
    assert [type(e) for e in got["edges"]] == [float, float, float]
    # text that reads as a number, where a number is declared (YAML 1.1 reads 5e-2 as text)
    assert validate_file({"search": {"sky": {"rms": "5e-2"}}}, TABLE, "f")["search"]["sky"] == {
        "rms": 0.05}


@pytest.mark.parametrize(("config", "message"), [
    # the file's own keys: named without a leading dot, after the file
    ({"sede": 1}, "f.yaml: sede: unknown parameter; valid: seed, search, edges"),
    ({"seed": -1}, "f.yaml: seed: must be >= 0, got -1"),
    ({"seed": 1.0}, "f.yaml: seed: expected integer, got 1.0"),
    ({"seed": True}, "f.yaml: seed: expected integer, got True"),
    # a mapping: its type, an unknown key, each bound of a field
    ({"search": [1]}, "f.yaml: search: expected mapping or null, got [1]"),
    ({"search": {"cont": 1}},
     "f.yaml: search.cont: unknown parameter; valid: count, reads, modes, points, sky"),
    ({"search": {"count": 0}}, "f.yaml: search.count: must be in [1, 10], got 0"),
    ({"search": {"count": 11}}, "f.yaml: search.count: must be in [1, 10], got 11"),
    # a list: its type, fewest and most items, each item's type, bounds and choices
    ({"search": {"reads": 8}}, "f.yaml: search.reads: expected list, got 8"),
    ({"search": {"reads": []}}, "f.yaml: search.reads: expected a list of 1 to 3 items, got []"),
    ({"search": {"reads": [1, 2, 3, 4]}},
     "f.yaml: search.reads: expected a list of 1 to 3 items, got [1, 2, 3, 4]"),
    ({"search": {"reads": [0, -1]}}, "f.yaml: search.reads[1]: must be in [0, 100], got -1"),
    ({"search": {"reads": [0, 8, 101]}},
     "f.yaml: search.reads[2]: must be in [0, 100], got 101"),
    ({"search": {"reads": [0.5]}}, "f.yaml: search.reads[0]: expected integer, got 0.5"),
    ({"search": {"modes": []}}, "f.yaml: search.modes: expected a list of at least 1 item, got []"),
    ({"search": {"modes": ["a", "c"]}},
     "f.yaml: search.modes[1]: 'c' is not one of ['a', 'b']"),
    ({"search": {"modes": ["a", 2]}}, "f.yaml: search.modes[1]: expected string, got 2"),
    # nesting: a mapping in a list in a mapping, a mapping in a mapping
    ({"search": {"points": [{"x": 0}, {"y": 1}]}},
     "f.yaml: search.points[1].y: unknown parameter; valid: x, label"),
    ({"search": {"points": [{"x": 0}, {"x": 2}]}},
     "f.yaml: search.points[1].x: must be in [-1, 1], got 2.0"),
    ({"search": {"points": [{"x": float("nan")}]}},
     "f.yaml: search.points[0].x: must be a finite number in [-1, 1], got nan"),
    ({"search": {"points": ["p"]}}, "f.yaml: search.points[0]: expected mapping, got 'p'"),
    ({"search": {"sky": {"rms": 0}}},
     "f.yaml: search.sky.rms: must be in [1e-20, 1e+20] e/s, got 0.0"),
    ({"search": {"sky": {"rms": float("inf")}}},
     "f.yaml: search.sky.rms: must be a finite number in [1e-20, 1e+20] e/s, got inf"),
    ({"search": {"sky": {"rms": "big"}}}, "f.yaml: search.sky.rms: expected number, got 'big'"),
    # a number or a list: the number's bounds, the list's length and items
    ({"edges": 0}, "f.yaml: edges: must be in [1, 50], got 0"),
    ({"edges": 51}, "f.yaml: edges: must be in [1, 50], got 51"),
    ({"edges": [1]}, "f.yaml: edges: expected a list of 2 to 5 items, got [1]"),
    ({"edges": [0, 1, 2, 3, 4, 5]},
     "f.yaml: edges: expected a list of 2 to 5 items, got [0, 1, 2, 3, 4, 5]"),
    ({"edges": [0, -1]}, "f.yaml: edges[1]: must be >= 0, got -1.0"),
    ({"edges": "many"}, "f.yaml: edges: expected integer or list, got 'many'"),
])
def test_each_bound_choice_type_and_nesting_is_refused_with_its_key_path(config, message):
    refused(config, message)


def test_every_type_is_named_as_before_and_integers_are_not_numbers_converted():
    # the words of the step and readout tables before the file tables joined them
    either = Parameter("k", 1, (int, float, type(None)), "k")
    with pytest.raises(ConfigError, match=r"^k: expected integer or number or null, got 'x'$"):
        either.check("x", "k")
    assert type(either.check(2, "k")) is int and either.check(None, "k") is None
    assert Parameter("n", 1, (int,), "n").check(5, "n") == 5
    with pytest.raises(ConfigError, match=r"^n: expected integer, got '5'$"):
        Parameter("n", 1, (int,), "n").check("5", "n")  # text is read as a number only


def test_validate_parameters_keeps_its_dotted_path():
    with pytest.raises(ConfigError, match=r"^steps\[0\]\.x\.search\.count: must be in "):
        validate_parameters({"search": {"count": 0}}, TABLE, "steps[0].x")
