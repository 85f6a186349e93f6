"""Every default of a step's or strategy's parameter is the one its `Parameter` table declares.

The tables (``Step.parameters``, ``Strategy.parameters``, ``COMBINE_PARAMETERS``)
are the one declaration.  Functions and methods that spell a default out in
their signature (``fit_ramp(exposure, *, gain=1.0)``) hold a copy: these
tests fail when a copy differs from its table, and when a signature has a
default the tests do not know (a new copy to declare here).
"""

import inspect

import pytest

from spherex_reduce import (
    ConfigError,
    combine_darks,
    correct_reference,
    detect_jumps,
    fit_ramp,
    pair_difference,
    sigma_clip,
    subtract_dark,
    subtract_phantom,
    unchop,
)
from spherex_reduce.cli import build_parser
from spherex_reduce.reduce.plugins import Registry, get_plugin_manager
from spherex_reduce.reduce.steps.dark import COMBINE_PARAMETERS
from spherex_reduce.reduce.steps.fit_ramp.step import FitRampStep, RampFit
from spherex_reduce.reduce.steps.reference.strategies import (
    MeanReference,
    clipped_mean,
    reference_offsets,
)

BUILTIN = Registry(get_plugin_manager(entry_points=False))
#: the function that runs each built-in step alone
FUNCTIONS = {
    "unchop": unchop,
    "subtract_phantom": subtract_phantom,
    "correct_reference": correct_reference,
    "detect_jumps": detect_jumps,
    "fit_ramp": fit_ramp,
    "sigma_clip": sigma_clip,
    "pair_difference": pair_difference,
    "subtract_dark": subtract_dark,
}
#: keyword defaults that are not parameters of a table
NOT_PARAMETERS = {"registry": None, "threads": None, "strategies": None, "exposure": None}
#: the methods of steps and strategies that receive parameters
METHODS = ("__init__", "run", "kernel", "consumer", "estimate", "__call__")


def _defaults(table, **more):
    return {**{p.name: p.default for p in table}, **NOT_PARAMETERS, **more}


def mismatches(func, expected):
    """``{name: (default in the signature, expected)}`` for every keyword default of ``func``
    that differs from ``expected[name]`` or that ``expected`` does not name."""
    out = {}
    for name, p in inspect.signature(func).parameters.items():
        if p.default is inspect.Parameter.empty:
            continue
        want = expected.get(name, "<not declared>")
        if not (want == p.default and isinstance(want, bool) == isinstance(p.default, bool)):
            out[name] = (p.default, want)
    return out


def _own_methods(cls):
    """The parameter-receiving methods ``cls`` defines or inherits from the package."""
    return [getattr(cls, m) for m in METHODS
            if m in vars(cls) or any(m in vars(base) for base in cls.__mro__[1:-1])]


def test_every_builtin_step_has_its_function_here():
    assert set(FUNCTIONS) == set(BUILTIN.steps)


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_step_defaults_are_its_tables(name):
    cls = BUILTIN.step(name)
    expected = _defaults(cls.parameters)
    if cls.strategy_kind:
        expected["strategy"] = cls.default_strategy
    for func in [FUNCTIONS[name], *_own_methods(cls)]:
        assert mismatches(func, expected) == {}, func.__qualname__


@pytest.mark.parametrize("kind_name", sorted(BUILTIN.providers["strategy"]))
def test_strategy_defaults_are_its_tables(kind_name):
    kind, name = kind_name.split("/")
    cls = BUILTIN.strategy(kind, name)
    for func in _own_methods(cls):
        assert mismatches(func, _defaults(cls.parameters)) == {}, func.__qualname__


@pytest.mark.parametrize("kind_name", sorted(BUILTIN.providers["strategy"]))
def test_strategy_constructors_check_their_parameters_against_the_table(kind_name):
    cls = BUILTIN.strategy(*kind_name.split("/"))
    valid = ", ".join(p.name for p in cls.parameters)
    with pytest.raises(ConfigError, match=rf"{cls.__name__}\.nonesuch: unknown parameter; "
                                          f"valid: {valid}"):
        cls(nonesuch=1)
    assert cls().params == {p.name: p.default for p in cls.parameters}


def test_ramp_fit_checks_its_parameters_against_the_table():
    with pytest.raises(ConfigError, match=r"fit_ramp\.gain: must be > 0, got -1\.0"):
        RampFit(None, gain=-1.0)


def test_public_functions_take_every_parameter_of_their_table():
    for func, table in ((fit_ramp, FitRampStep.parameters),
                        (sigma_clip, BUILTIN.step("sigma_clip").parameters),
                        (combine_darks, COMBINE_PARAMETERS)):
        keywords = {n for n, p in inspect.signature(func).parameters.items()
                    if p.kind is inspect.Parameter.KEYWORD_ONLY}
        assert keywords == {p.name for p in table}, func.__name__
    assert {p.name for p in MeanReference.parameters} <= set(
        inspect.signature(reference_offsets).parameters)


def test_other_functions_defaults_are_the_tables():
    clip = MeanReference.parameters
    for func, expected in (
            (combine_darks, _defaults(COMBINE_PARAMETERS)),
            (reference_offsets, _defaults(clip, acn=MeanReference.acn)),
            (clipped_mean, _defaults(clip)),
            (RampFit.__init__, _defaults(FitRampStep.parameters))):
        assert mismatches(func, expected) == {}, func.__qualname__


def test_the_combine_command_defaults_are_the_table():
    args = build_parser().parse_args(["combine", "a.fits", "b.fits", "-o", "master.fits"])
    assert {p.name: getattr(args, p.name) for p in COMBINE_PARAMETERS} == {
        "method": "average", "sigma": 3.0}
    assert all(getattr(args, p.name) == p.default for p in COMBINE_PARAMETERS)


def test_every_declared_default_is_a_valid_value():
    tables = [COMBINE_PARAMETERS, *(r.obj.parameters for r in BUILTIN.steps.values()),
              *(r.obj.parameters for d in BUILTIN.strategies.values() for r in d.values())]
    for table in tables:
        for p in table:
            assert p.check(p.default, p.name) == p.default


def test_a_copy_that_differs_from_its_table_is_found(monkeypatch):
    expected = _defaults(FitRampStep.parameters)
    assert mismatches(fit_ramp, expected) == {}
    monkeypatch.setitem(fit_ramp.__kwdefaults__, "gain", 2.0)
    assert mismatches(fit_ramp, expected) == {"gain": (2.0, 1.0)}
    monkeypatch.setitem(fit_ramp.__kwdefaults__, "gain", True)  # a bool is not the number 1
    assert mismatches(fit_ramp, expected) == {"gain": (True, 1.0)}

    def scaled(exposure, *, gain=1.0, offset=0.0):  # a default no table declares
        return exposure

    assert mismatches(scaled, expected) == {"offset": (0.0, "<not declared>")}
