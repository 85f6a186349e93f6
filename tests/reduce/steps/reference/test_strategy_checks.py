"""What a reference strategy returns is checked before it is used (one check, every route)."""

import numpy as np
import pytest
from _toy_steps import registry_with

from spherex_reduce import Pipeline, Strategy
from spherex_reduce.core.block import Context
from spherex_reduce.core.errors import PluginError
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.reduce.hookspecs import hookimpl
from spherex_reduce.reduce.steps.reference.strategies import ReferenceOffsets
from spherex_reduce.reduce.steps.reference.strategy_checks import (
    StrategyOrigin,
    check_corrected,
    check_estimate,
)


class Shaped(Strategy):
    """Offsets of a given shape (one per frame, channel and group when right)."""

    kind, name = "reference", "shaped"
    shape = None

    def estimate(self, side, context, exposure=None):
        shape = self.shape or (side.data.shape[0], context.geometry.nchannels, 1)
        return ReferenceOffsets(np.full(shape, 2.0), np.ones(shape, int),
                                np.zeros(shape, int), [-1])


class ShapedPlugin:
    @hookimpl
    def register_strategies(self):
        return [Shaped]


def _pipeline():
    return Pipeline({"steps": [{"unchop": {}}, {"correct_reference": {"strategy": "shaped"}}]},
                    registry=registry_with(ShapedPlugin()))


def test_a_right_estimate_is_subtracted():
    raw = example_raw_exposure()
    out = _pipeline().run(raw)
    ref = Pipeline({"steps": [{"unchop": {}}]}).run(raw)
    # subtracted in float64 (issue 31), not rounded back to the input's float32
    np.testing.assert_array_equal(out.data.data, ref.data.data.astype(np.float64) - 2.0)


@pytest.mark.parametrize("shape", [(1, 1, 1), (2, 1)])
def test_a_plugin_estimate_of_another_shape_names_the_plugin(monkeypatch, shape):
    monkeypatch.setattr(Shaped, "shape", shape)
    with pytest.raises(PluginError, match=rf"reference strategy 'shaped' of plugin "
                                          rf"'ShapedPlugin' returned offsets of shape "
                                          rf"\({shape[0]}, {shape[1]}"):
        _pipeline().run(example_raw_exposure())


def test_a_builtin_strategy_fault_is_our_bug():
    context = Context(example_raw_exposure().schedule, "readout", True)
    with pytest.raises(RuntimeError, match=r"reference strategy 'mean' of plugin "
                                           r"'builtin\.reference' returned None"):
        check_estimate(None, context, 3, StrategyOrigin("reference", "mean",
                                                        "builtin.reference"))


def test_rows_of_another_shape_are_refused():
    raw = example_raw_exposure()
    context = Context(raw.schedule, "readout", True)
    nch = raw.schedule.geometry.nchannels
    est = ReferenceOffsets(np.zeros((3, nch, 1)), np.ones((3, nch, 1)), np.zeros((3, nch, 1)),
                           [-1], rows=np.zeros((3, 2, nch, 1)))
    with pytest.raises(PluginError, match=rf"per-read offsets \(rows\) of shape \(3, 2, {nch}, "
                                          rf"1\); expected \(3, {raw.schedule.n_reads}"):
        check_estimate(est, context, 3, StrategyOrigin("reference", "toy", "toy"))


def test_a_corrected_exposure_keeps_its_shape_and_some_finite_pixel():
    raw = example_raw_exposure()
    origin = StrategyOrigin("reference", "toy", "toy")
    assert check_corrected(raw, raw, origin) is raw
    with pytest.raises(PluginError, match="without a finite pixel"):
        check_corrected(raw.replace(data=np.full(raw.shape, np.inf)), raw, origin)
