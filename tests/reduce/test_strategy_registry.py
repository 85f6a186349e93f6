"""One registry of strategies: the plugins' own, for the plain functions as for a pipeline."""

import importlib.metadata
import sys

import numpy as np
import pytest

from spherex_reduce import ConfigError, Exposure, Pipeline, correct_reference
from spherex_reduce.io.examples import tiny_schedule
from spherex_reduce.reduce.plugins import (
    BLOCK_ENV,
    Registry,
    default_registry,
    get_plugin_manager,
)


@pytest.fixture
def offsets_exposure():
    """Ramps in readout order: noise plus a different offset per channel and frame."""
    s = tiny_schedule(nframes=3, phantom_reads=0)
    g = s.geometry
    rng = np.random.default_rng(7)
    offsets = rng.uniform(-20, 20, (s.nframes, 1, g.nchannels))
    data = rng.normal(0, 1, (s.nframes, s.n_reads, g.ncols)) + np.repeat(
        offsets, g.channel_width, axis=-1)
    return Exposure.from_arrays(data, s)


def _fourier_installed():
    return any(ep.name == "fourier_filter"
               for ep in importlib.metadata.entry_points(group="spherex_reduce"))


def test_the_fourier_plugin_is_installed():
    # the test command installs it; a missing plugin is a failure, not a skip
    assert _fourier_installed(), "install the plugin: pip install ./plugins/fourier_filter"


def test_plugin_strategy_from_the_plain_function(offsets_exposure):
    e = offsets_exposure
    out = correct_reference(e, "fourier")
    # zeroing the k_y = 0 axis but k = 0 of each frame: minus its column means, plus its mean
    data = e.data.data
    expected = data - data.mean(axis=1, keepdims=True) + data.mean(axis=(1, 2), keepdims=True)
    np.testing.assert_allclose(out.data.data, expected, atol=1e-9)
    assert out.header["REFSTRAT"] == "fourier"
    assert out.header["S_REFCOR"] == "COMPLETE"


@pytest.mark.parametrize("params", [{}, {"width": 1, "keep_mean": False}])
def test_plain_function_and_pipeline_agree_on_a_plugin_strategy(offsets_exposure, params):
    e = offsets_exposure
    alone = correct_reference(e, "fourier", **params)
    piped = Pipeline({"steps": [{"correct_reference": {"strategy": "fourier", **params}}]}).run(e)
    np.testing.assert_array_equal(alone.data.data, piped.data.data)
    for name in ("offset", "n_used", "channel", "frame"):
        np.testing.assert_array_equal(alone.tables["REFOFFS"][name],
                                      piped.tables["REFOFFS"][name])


def test_unknown_strategy_lists_the_plugin_strategies_too(offsets_exposure):
    with pytest.raises(ConfigError, match=r"'nonesuch' is not one of") as info:
        correct_reference(offsets_exposure, "nonesuch")
    for name in ("acn", "fourier", "mean", "median", "wiener"):
        assert f"'{name}'" in str(info.value)


def test_builtin_strategies_are_registered_by_the_builtin_plugin():
    reg = Registry(get_plugin_manager(entry_points=False))
    assert reg.providers["strategy"] == {f"reference/{n}": "builtin.reference"
                                         for n in ("acn", "mean", "median", "wiener")}
    assert default_registry().providers["strategy"]["reference/fourier"] == "fourier_filter"


def test_a_given_registry_is_the_one_used(offsets_exposure):
    without_plugins = Registry(get_plugin_manager(entry_points=False))
    with pytest.raises(ConfigError, match=r"'fourier' is not one of \['acn', 'mean', "
                                          r"'median', 'wiener'\]"):
        correct_reference(offsets_exposure, "fourier", registry=without_plugins)


def test_default_registry_is_made_again_when_the_blocked_plugins_change(
        offsets_exposure, monkeypatch):
    first = default_registry()
    assert default_registry() is first
    monkeypatch.setenv(BLOCK_ENV, "fourier_filter")
    blocked = default_registry()
    assert "fourier" not in blocked.strategies["reference"]
    with pytest.raises(ConfigError, match=r"'fourier' is not one of \['acn', 'mean', "
                                          r"'median', 'wiener'\]"):
        correct_reference(offsets_exposure, "fourier")
    monkeypatch.delenv(BLOCK_ENV)
    assert "fourier" in default_registry().strategies["reference"]
    assert correct_reference(offsets_exposure, "fourier").header["REFSTRAT"] == "fourier"


HALVE = """
from spherex_reduce.plugin import Strategy, hookimpl


class Halve(Strategy):
    kind, name = "reference", "halve"

    def __call__(self, exposure):
        return exposure.replace(data=exposure.data.data / 2)


@hookimpl
def register_strategies():
    return [Halve]
"""


def test_a_plugin_installed_while_the_process_runs_is_found(
        offsets_exposure, tmp_path, monkeypatch):
    site = tmp_path / "site"
    site.mkdir()
    monkeypatch.syspath_prepend(str(site))
    assert "halve" not in default_registry().strategies["reference"]
    # installing adds a distribution's folder to a folder of sys.path already listed
    (site / "halve_plugin.py").write_text(HALVE)
    info = site / "spherex_reduce_halve-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: spherex-reduce-halve\n"
                                   "Version: 0.1.0\n")
    (info / "entry_points.txt").write_text("[spherex_reduce]\nhalve = halve_plugin\n")
    monkeypatch.delitem(sys.modules, "halve_plugin", raising=False)
    out = correct_reference(offsets_exposure, "halve")
    np.testing.assert_array_equal(out.data.data, offsets_exposure.data.data / 2)
    assert default_registry().providers["strategy"]["reference/halve"] == "halve"


def test_the_step_made_alone_knows_the_reference_strategies():
    from spherex_reduce.io.examples import example_raw_exposure
    from spherex_reduce.reduce.steps.reference.step import CorrectReferenceStep

    raw = example_raw_exposure()
    alone = CorrectReferenceStep()(raw, strategy="acn")
    by_function = correct_reference(raw, "acn")
    assert alone.header["S_REFCOR"] == "COMPLETE"
    np.testing.assert_array_equal(alone.data.data, by_function.data.data)
