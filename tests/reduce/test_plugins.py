"""Plugin discovery and registration: entry points, broken plugins, hooks, the example plugin."""

import importlib.metadata
import types

import numpy as np
import pytest
from _toy_steps import Offset, OffsetPlugin, registry_with

import spherex_reduce
from spherex_reduce import Pipeline, PluginError, Step
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.reduce.hookspecs import hookimpl
from spherex_reduce.reduce.plugins import Registry, get_plugin_manager


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=5)


class FakeEntryPoint:
    def __init__(self, name, value, loader):
        self.name, self.value, self._loader = name, value, loader

    def load(self):
        return self._loader()


def _fake_entry_points(monkeypatch, eps):
    real = importlib.metadata.entry_points

    def entry_points(**kwargs):
        if kwargs.get("group") == "spherex_reduce":
            return list(eps)
        return real(**kwargs)

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)


def test_broken_plugin_is_named_and_can_be_blocked(monkeypatch):
    def boom():
        raise ImportError("No module named 'numpyy'")

    _fake_entry_points(monkeypatch, [FakeEntryPoint("brokenplug", "broken.mod:plugin", boom)])
    with pytest.raises(PluginError) as info:
        get_plugin_manager()
    assert "'brokenplug'" in str(info.value) and "numpyy" in str(info.value)
    assert "SPHEREX_REDUCE_BLOCK_PLUGINS=brokenplug" in str(info.value)
    monkeypatch.setenv("SPHEREX_REDUCE_BLOCK_PLUGINS", "other, brokenplug")
    pm = get_plugin_manager()
    assert pm.is_blocked("brokenplug")


def test_plugin_with_bad_hook_signature_is_named(monkeypatch):
    bad = types.SimpleNamespace()

    @hookimpl
    def before_step(step, exposure, params, unexpected):
        pass

    bad.before_step = before_step
    _fake_entry_points(monkeypatch, [FakeEntryPoint("badsig", "bad:plugin", lambda: bad)])
    with pytest.raises(PluginError, match="'badsig' failed to register"):
        get_plugin_manager()


def test_unknown_hook_name_is_an_error_naming_the_plugin():
    class Typo:
        @hookimpl
        def register_stepz(self):
            return [Offset]

    with pytest.raises(PluginError, match=r"plugin 'Typo' failed to register.*register_stepz"):
        registry_with(Typo())


def test_registration_errors_are_named():
    class NoKeyword(Step):
        name = "nokw"

    class Bad:
        @hookimpl
        def register_steps(self):
            return [NoKeyword]

    with pytest.raises(PluginError, match="step 'nokw' needs a FITS status keyword"):
        registry_with(Bad())

    class Dup:
        @hookimpl
        def register_steps(self):
            return [Offset]

    with pytest.raises(PluginError, match="registered by both"):
        registry_with(OffsetPlugin(), Dup())

    class Raises:
        @hookimpl
        def register_steps(self):
            raise RuntimeError("oops")

    with pytest.raises(PluginError, match="failed in register_steps: RuntimeError: oops"):
        registry_with(Raises())


def test_no_global_state():
    a = get_plugin_manager(entry_points=False)
    b = get_plugin_manager(entry_points=False, plugins=[OffsetPlugin()])
    assert "offset" in Registry(b).steps and "offset" not in Registry(a).steps


def test_example_plugin_through_its_entry_point(raw):
    """plugins/destripe, installed by the test command, found via the entry-point group."""
    eps = [ep.name for ep in importlib.metadata.entry_points(group="spherex_reduce")]
    assert "destripe" in eps, "install the example plugin: pip install ./plugins/destripe"
    registry = Registry()
    assert registry.providers["step"]["destripe"] == "destripe"
    pipe = Pipeline({"steps": ["unchop", {"destripe": {"sigma": 3}}]}, registry=registry)
    out = pipe.run(raw)
    # independent expectation: every active row's clipped median is now ~0
    from astropy.stats import sigma_clipped_stats

    active_cols = ~raw.geometry.reference_column_mask()
    _, med, _ = sigma_clipped_stats(out.data.data[..., active_cols], sigma=3.0, axis=-1)
    np.testing.assert_allclose(med, 0.0, atol=1e-3)
    assert out.header["S_DESTRP"] == "COMPLETE"
    assert "DESTRIPE" in out.tables
    with pytest.raises(spherex_reduce.SpherexReduceError, match="run unchop before it"):
        Pipeline({"steps": ["destripe"]}, registry=registry).run(raw)


def test_example_plugin_docstring_examples_run():
    import doctest

    module = pytest.importorskip("spherex_reduce_destripe.plugin")
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_a_plugin_step_with_its_own_constructor_runs_in_a_pipeline(tmp_path):
    # made as plugin authors wrote steps before: __init__(registry, threads); a step
    # with file inputs still reads them with the config's geometry/readout values
    class Scaled(Step):
        name, keyword = "scaled", "S_SCALED"

        def __init__(self, registry=None, threads=None):
            super().__init__(registry, threads)
            self.factor = 2.0

        def run(self, exposure):
            return exposure.replace(data=exposure.data.data * self.factor)

    class ScaledPlugin:
        @hookimpl
        def register_steps(self):
            return [Scaled]

    raw = example_raw_exposure()
    pipe = Pipeline({"readout": {"nframes": raw.schedule.nframes}, "steps": ["scaled"]},
                    registry=registry_with(ScaledPlugin()))
    out = pipe.run(raw)
    np.testing.assert_array_equal(out.data.data, raw.data.data * 2.0)
    assert out.header["S_SCALED"] == "COMPLETE"
