"""A plugin's step or reference strategy takes part in the forecast when its class declares its
noise effect (``noise_effect``), and is refused in one line when it does not: the forecast reads
the declarations from the pipeline's plugin registry (analysis/forecast/steps.py)."""

import pytest
from _forecast_scenes import (
    BOTH,
    BOTH_COMMON,
    PHANTOM,
    PINK,
    PINK_ACN,
    PIPELINES,
    check_against_brute_force,
    tiny,
)
from _toy_steps import registry_with

from spherex_reduce import Pipeline
from spherex_reduce.analysis import forecast
from spherex_reduce.core.errors import ConfigError, PluginError
from spherex_reduce.plugin import NoiseEffect, Parameter, ReferenceEffect, Step, hookimpl
from spherex_reduce.reduce.steps.reference.strategies import MeanReference


class Copy(Step):
    """Leaves the exposure as it is: declared as the identity."""

    name, keyword = "copy", "S_COPY"
    noise_effect = NoiseEffect("identity")

    def run(self, exposure):
        return exposure


class Undeclared(Copy):
    """The same step under another name, declaring nothing of its own (not inherited)."""

    name, keyword = "undeclared_copy", "S_UCOPY"


class DeclaredMean(MeanReference):
    """The mean strategy under another name, declared as the mean."""

    name = "declared_mean"
    noise_effect = ReferenceEffect("mean", linear=MeanReference.noise_effect.linear)


class UndeclaredMean(MeanReference):
    name = "undeclared_mean"


class Plugin:
    @hookimpl
    def register_steps(self):
        return [Copy, Undeclared]

    @hookimpl
    def register_strategies(self):
        return [DeclaredMean, UndeclaredMean]


def pipeline(*steps):
    return Pipeline({"steps": list(steps)}, registry=registry_with(Plugin()))


SCENE = [PINK_ACN, BOTH, BOTH_COMMON, PHANTOM]


@pytest.mark.parametrize("where", [0, 1, 2, 3])
def test_a_step_declared_identity_is_forecast_as_the_pipeline_without_it(where):
    """``copy`` anywhere in spherex-default's steps: the brute force of that reduction."""
    steps = [{"unchop": {}}, {"subtract_phantom": {}}, {"correct_reference": {}},
             {"fit_ramp": {}}]
    steps.insert(where, {"copy": {}})
    subtract, _ = PIPELINES["spherex-default"]
    check_against_brute_force(tiny(SCENE, scan="alternate"), subtract, pipeline(*steps))


def test_a_strategy_declared_mean_is_forecast_as_the_mean():
    subtract, _ = PIPELINES["spherex-default"]
    check_against_brute_force(tiny(SCENE), subtract, pipeline(
        {"subtract_phantom": {}}, {"correct_reference": {"strategy": "declared_mean"}}))


def test_an_undeclared_step_is_refused_in_one_line():
    with pytest.raises(ConfigError) as err:
        forecast(tiny([PINK]), pipeline({"unchop": {}}, {"undeclared_copy": {}}))
    assert str(err.value) == (
        "forecast: steps[1].undeclared_copy (config) is not forecast so far; forecast steps: "
        "unchop, subtract_phantom, correct_reference, fit_ramp, sigma_clip, pair_difference, "
        "copy")


def test_an_undeclared_strategy_is_refused_in_one_line():
    with pytest.raises(ConfigError) as err:
        forecast(tiny([PINK]), pipeline(
            {"unchop": {}}, {"correct_reference": {"strategy": "undeclared_mean"}}))
    assert str(err.value) == (
        "forecast: steps[1].correct_reference.strategy: 'undeclared_mean' is not forecast "
        "(not linear, or not yet); only 'mean', 'acn', 'wiener', 'declared_mean'")


def test_a_plugin_strategy_is_held_to_its_own_declaration():
    with pytest.raises(ConfigError, match=r"steps\[0\]\.correct_reference\.sigma: 2\.0 is not "
                                          r"forecast .*only a number >= 3$"):
        forecast(tiny([PINK]), pipeline(
            {"correct_reference": {"strategy": "declared_mean", "sigma": 2.0}}))


class Misspelt(Copy):
    """A declaration naming a parameter the step does not have ("facter" for "factor")."""

    name, keyword = "misspelt", "S_MISSP"
    parameters = (Parameter("factor", 1.0, (float,), "multiply by this"),)
    noise_effect = NoiseEffect("identity", linear={"facter": (1.0,)})

    def run(self, exposure, factor):
        return exposure.replace(data=exposure.data.data * factor)


class WithoutDefault(Misspelt):
    """A declaration whose allowed values leave out the parameter's default."""

    name, keyword = "without_default", "S_WDEF"
    noise_effect = NoiseEffect("identity", linear={"factor": (2.0,)})


class BadPlugin:
    @hookimpl
    def register_steps(self):
        return [Misspelt, WithoutDefault]


@pytest.mark.parametrize(("step", "match"), [
    ("misspelt", r"^misspelt \(.*\): noise_effect\.linear names 'facter', which is not one of "
                 r"its parameters \(factor\)$"),
    ("without_default", r"^without_default \(.*\): noise_effect\.linear\.factor leaves out "
                        r"the parameter's default 1\.0$")])
def test_a_declaration_that_cannot_be_right_is_refused_in_one_line(step, match):
    # A misspelt key would keep every value of the real parameter "linear" (a factor of 7
    # forecast as the identity); a default left out would refuse the step as written.
    pipe = Pipeline({"steps": [{step: {"factor": 7.0}}]}, registry=registry_with(BadPlugin()))
    with pytest.raises(PluginError, match=match):
        forecast(tiny([PINK]), pipe)
