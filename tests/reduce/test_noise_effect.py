"""What each step and reference strategy declares about the noise (``noise_effect``,
reduce/noise_effect.py), against what the steps do: a step declared linear is linear on real
exposures at every value its declaration allows, a value it leaves out is not, and the
``wiener`` strategy's phantom rule is the one its runs follow."""

import numpy as np
import pytest
from _forecast_scenes import BOTH, PHANTOM, PINK_ACN, ROIC, tiny

from spherex_reduce import Pipeline, Step
from spherex_reduce.reduce.noise_effect import (
    MEASURED_SIGMA,
    AtLeast,
    NoiseEffect,
    ReferenceEffect,
    declared_effect,
)
from spherex_reduce.reduce.plugins import get_registry
from spherex_reduce.reduce.steps.reference import wiener
from spherex_reduce.simulation import simulate

REGISTRY = get_registry(entry_points=False)

#: what the package's steps and reference strategies do to the noise, written out by hand
STEPS = {"unchop": "identity", "subtract_phantom": "subtract_phantom",
         "correct_reference": "reference", "detect_jumps": None, "fit_ramp": "slope_fit",
         "sigma_clip": "identity", "pair_difference": "identity", "subtract_dark": None}
STRATEGIES = {"mean": "mean", "acn": "acn", "median": None, "wiener": "wiener"}


def test_the_package_declares_what_each_step_and_strategy_does():
    steps = {n: getattr(declared_effect(r.obj), "action", None)
             for n, r in REGISTRY.steps.items()}
    kinds = {n: getattr(declared_effect(r.obj), "kind", None)
             for n, r in REGISTRY.strategies["reference"].items()}
    assert (steps, kinds) == (STEPS, STRATEGIES)


def test_declarations_name_parameters_the_class_takes_and_allow_their_defaults():
    classes = [r.obj for r in REGISTRY.steps.values()]
    classes += [r.obj for r in REGISTRY.strategies["reference"].values()]
    for cls in classes:
        effect = declared_effect(cls)
        if effect is None:
            continue
        defaults = {p.name: p.default for p in cls.parameters}
        assert set(effect.linear) <= set(defaults), cls
        assert effect.outside(defaults) is None, cls  # the default pipeline is forecast


def test_a_declaration_is_not_inherited_and_the_base_classes_declare_nothing():
    class Mine(REGISTRY.step("unchop")):
        name = "mine"

    assert Step.noise_effect is None and declared_effect(Mine) is None
    assert declared_effect(REGISTRY.step("unchop")) is not None


def test_a_declaration_refuses_an_unknown_action_or_values_that_are_not_a_tuple():
    with pytest.raises(ValueError, match="unknown action 'scale'; valid: identity, "):
        NoiseEffect("scale")
    with pytest.raises(ValueError, match="unknown kind 'median'"):
        ReferenceEffect("median")
    with pytest.raises(TypeError, match=r"linear\['weighting'\]: expected a tuple"):
        NoiseEffect("slope_fit", linear={"weighting": "uniform"})
    assert NoiseEffect("identity", linear={"x": [1, 2]}).linear == {"x": (1, 2)}


def test_at_least_holds_none_and_numbers_from_its_minimum():
    assert [v in MEASURED_SIGMA for v in (None, 3, 3.0, 1e6, 2.99, True, "5")] == [
        True, True, True, True, False, False, False]
    assert repr(AtLeast(2.5)) == "a number >= 2.5"


@pytest.fixture(scope="module")
def ramps():
    """Two independent ramps of a tiny scene with dark current and phantom values."""
    scene = tiny([ROIC, PINK_ACN, BOTH, PHANTOM], terms={"dark_current": 20.0})
    return [simulate(scene, seed=s, mode="ramps") for s in (1, 2)]


def combine(a, b, f):
    """``a + f b``: pixels and phantom values."""
    return a.replace(data=np.asarray(a.data.data, float) + f * np.asarray(b.data.data, float),
                     phantom=a.phantom + f * b.phantom)


def image(steps, exposure):
    return np.asarray(Pipeline({"steps": steps}).run(exposure).data.data, float)


def linear(steps, a, b):
    """Whether the reduction of ``a + 3 b`` is that of ``a`` plus 3 times that of ``b``."""
    x, y, z = image(steps, a), image(steps, b), image(steps, combine(a, b, 3.0))
    assert np.isfinite(z).mean() > 0.5  # most pixels have a slope
    return np.allclose(z, x + 3.0 * y, rtol=0, atol=1e-6 * np.nanstd(z), equal_nan=True)


LINEAR = {
    "unchop": [{"unchop": {}}],
    "subtract_phantom": [{"unchop": {}}, {"subtract_phantom": {}}],
    "mean": [{"unchop": {}}, {"subtract_phantom": {}},
             {"correct_reference": {"strategy": "mean", "sigma": 1e6}}],
    "acn side columns": [{"correct_reference": {"strategy": "acn", "sigma": 1e6,
                                                "side_columns": True}}],
    "wiener": [{"unchop": {}}, {"correct_reference": {"strategy": "wiener", "sigma": 1e6,
                                                      "noise": "spherex-table2"}}],
    "fit_ramp uniform": [{"unchop": {}}, {"fit_ramp": {"weighting": "uniform"}}],
}


@pytest.mark.parametrize("case", LINEAR)
def test_what_is_declared_linear_is_linear(case, ramps):
    """Each step and strategy at values its declaration allows (the clips at 1e6 σ, which the
    forecast neglects from 3 σ up) on real ramps."""
    steps = LINEAR[case]
    for item in steps:
        (name, params), = item.items()
        cls = REGISTRY.step(name)
        assert declared_effect(cls).outside(params) is None
        if "strategy" in params:
            strategy = REGISTRY.strategy("reference", params["strategy"])
            assert declared_effect(strategy).outside(params) is None
    assert linear(steps, *ramps)


NOT_LINEAR = {
    "fit_ramp optimal": ("weighting", {"weighting": "optimal", "read_noise": 5.0}),
    "fit_ramp saturation": ("saturation", {"saturation": "p90"}),
}


@pytest.mark.parametrize("case", NOT_LINEAR)
def test_what_a_declaration_leaves_out_is_not_linear(case, ramps):
    key, params = NOT_LINEAR[case]
    if params.get("saturation") == "p90":  # the highest tenth of the reads of a + 3 b dropped
        params = {"saturation": float(np.percentile(combine(*ramps, 3.0).data.data, 90))}
    fit = declared_effect(REGISTRY.step("fit_ramp"))
    assert fit.outside(params)[0] == key
    assert not linear([{"unchop": {}}, {"fit_ramp": params}], *ramps)


@pytest.mark.parametrize("phantom", ["auto", "ignore"])
def test_the_wiener_phantom_rule_lives_with_the_strategy_and_its_runs_follow_it(phantom,
                                                                                 ramps):
    """A later subtract_phantom is skipped exactly when the rule says the estimate consumed the
    phantom values; subtracted first, they are never consumed."""
    effect = declared_effect(wiener.WienerReference)
    assert effect.consumes_phantom is wiener.phantom_consumed
    ref = {"correct_reference": {"strategy": "wiener", "phantom": phantom,
                                 "noise": "spherex-table2"}}
    out = Pipeline({"steps": [{"unchop": {}}, ref, {"subtract_phantom": {}}]}).run(ramps[0])
    consumed = out.header["S_PHANTM"] == "SKIPPED"
    assert consumed == (phantom == "auto")
    assert effect.consumes_phantom(ref["correct_reference"], False) == consumed
    assert not effect.consumes_phantom(ref["correct_reference"], True)
