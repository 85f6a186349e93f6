"""Pipeline from YAML, plugin discovery, hooks and provenance."""

import importlib.metadata
import types

import numpy as np
import pytest

import spherex_reduce
from spherex_reduce import ConfigError, Exposure, Pipeline, PluginError, Step, StepSkipped, unchop
from spherex_reduce.examples import example_raw_exposure
from spherex_reduce.hookspecs import hookimpl
from spherex_reduce.parameters import Parameter
from spherex_reduce.plugins import Registry, get_plugin_manager


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=5)


class Offset(Step):
    name, keyword = "offset", "S_OFFSET"
    parameters = (Parameter("value", 0.0, (float,), "added (e)"),
                  Parameter("mode", "add", (str,), "add or skip", choices=("add", "skip")))

    def run(self, exposure, value, mode):
        if mode == "skip":
            raise StepSkipped("asked to skip")
        return exposure.replace(data=exposure.data.data + value)


class OffsetPlugin:
    def __init__(self):
        self.calls = []

    @hookimpl
    def register_steps(self):
        return [Offset]

    @hookimpl
    def before_step(self, step, exposure, params):
        self.calls.append(("before", step.name, dict(params)))

    @hookimpl
    def after_step(self, step, exposure, result, params, status, reason, elapsed):
        self.calls.append(("after", step.name, status))
        return [("QA_" + step.name[:5].upper(), float(elapsed >= 0), "qa")]


def registry_with(*plugins):
    return Registry(get_plugin_manager(entry_points=False, plugins=plugins))


def test_steps_run_in_yaml_order_with_provenance(tmp_path, raw):
    plugin = OffsetPlugin()
    config = tmp_path / "p.yaml"
    config.write_text("steps:\n  - offset: {value: 2}\n  - unchop: {}\n  - offset: {value: 3}\n")
    pipe = Pipeline.from_yaml(config, registry=registry_with(plugin))
    out = pipe.run(raw)
    expected = unchop(raw).data.data + 5.0
    np.testing.assert_allclose(out.data.data, expected, rtol=1e-6)
    assert [c[:2] for c in plugin.calls] == [("before", "offset"), ("after", "offset"),
                                               ("before", "unchop"), ("after", "unchop"),
                                               ("before", "offset"), ("after", "offset")]
    h = out.header
    assert h["S_UNCHOP"] == "COMPLETE" and h["S_OFFSET"] == "COMPLETE"
    assert h["SXR OFFSET VALUE"] == 3.0  # the last run's parameters
    assert h["SXRVERS"] == spherex_reduce.__version__
    assert h["SXRCONF"] == pipe.config_hash and len(pipe.config_hash) == 16
    assert h["QA_OFFSE"] == 1.0
    history = "\n".join(str(v) for v in h["HISTORY"])
    assert '"value": 2.0' in history and '"value": 3.0' in history
    assert raw.header.get("S_UNCHOP") is None  # input untouched


def test_skipped_step_is_recorded(raw):
    pipe = Pipeline({"steps": [{"offset": {"mode": "skip"}}]}, registry=registry_with(
        OffsetPlugin()))
    out = pipe.run(raw)
    assert out.header["S_OFFSET"] == "SKIPPED"
    assert any("asked to skip" in str(v) for v in out.header["HISTORY"])
    np.testing.assert_array_equal(out.data.data, raw.data.data)


def test_effective_config_fills_defaults():
    pipe = Pipeline({"steps": ["unchop", {"offset": {"value": 1}}]},
                    registry=registry_with(OffsetPlugin()))
    assert pipe.config == {"steps": [{"unchop": {}},
                                     {"offset": {"value": 1.0, "mode": "add"}}]}
    assert "value: 1.0" in pipe.to_yaml()
    same = Pipeline({"steps": ["unchop", {"offset": {"value": 1.0, "mode": "add"}}]},
                    registry=registry_with(OffsetPlugin()))
    assert same.config_hash == pipe.config_hash


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"steps": [{"unchop": {}}, {"unchopp": {}}]},
         "steps[1].unchopp: unknown step 'unchopp'; valid: "),
        ({"steps": [{"offset": {"valu": 1}}]},
         "steps[0].offset.valu: unknown parameter; valid: value, mode"),
        ({"steps": [{"offset": {"value": "big"}}]}, "steps[0].offset.value: expected number"),
        ({"steps": [{"offset": {"mode": "sub"}}]}, "steps[0].offset.mode: 'sub' is not one of"),
        ({"steps": [{"unchop": {"x": 1}}]}, "steps[0].unchop.x: unknown parameter; valid: (none"),
        ({"steps": []}, "steps: a non-empty list"),
        ({"stepz": []}, "stepz: unknown top-level key"),
        ({"steps": ["unchop"], "readout": {"skip": "many"}}, "readout.skip: expected integer"),
        ({"steps": ["unchop"], "geometry": {"nrow": 5}}, "geometry.nrow: unknown parameter"),
    ],
)
def test_config_errors_name_the_yaml_path(config, message):
    with pytest.raises(ConfigError) as info:
        Pipeline(config, registry=registry_with(OffsetPlugin()))
    assert message in str(info.value)


def test_bad_yaml_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("steps: [unchop\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        Pipeline.from_yaml(p)
    with pytest.raises(FileNotFoundError, match="shipped: "):
        Pipeline.from_yaml(tmp_path / "missing.yaml")


def test_shipped_config_by_name(raw):
    out = Pipeline.from_yaml("unchop").run(raw)
    assert out.order == "physical"


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


def test_input_exposure_is_not_mutated(raw):
    data = raw.data.data.copy()
    header = raw.header.copy()
    Pipeline({"steps": ["unchop"]}).run(raw)
    np.testing.assert_array_equal(raw.data.data, data)
    assert raw.header == header and isinstance(raw, Exposure)


class FrameSum(Step):
    """Toy accumulating step: the sum of the frames (a stand-in for fit_ramp)."""

    name, keyword = "framesum", "S_FSUM"

    def run(self, exposure):
        total = exposure.data.data.sum(axis=0, dtype=np.float64)
        return Exposure.from_arrays(total, exposure.schedule, order=exposure.order,
                                    header=exposure.header, tables=exposure.tables)

    def accumulator(self, schedule, header):
        return _SumAccumulator()


class _SumAccumulator:
    def __init__(self):
        self.total, self.seen = None, []

    def add(self, index, frame):
        self.seen.append(index)
        self.total = frame.data.data[0].astype(np.float64) + (0 if self.total is None
                                                              else self.total)
        self.schedule, self.order, self.header = frame.schedule, frame.order, frame.header

    def finish(self):
        return Exposure.from_arrays(self.total, self.schedule, order=self.order,
                                    header=self.header)


class PerFrameNote(Step):
    """Toy per-frame step that records a table, like correct_reference does."""

    name, keyword, per_frame = "note", "S_NOTE", True

    def run(self, exposure):
        from astropy.table import Table

        means = np.atleast_1d(exposure.data.data.mean(axis=(-2, -1)))
        return exposure.replace(data=exposure.data.data - 1.0, tables={
            **exposure.tables, "NOTE": Table({"frame": np.arange(means.size), "mean": means})})


class ToyPlugin:
    @hookimpl
    def register_steps(self):
        return [FrameSum, PerFrameNote]


def test_streamed_run_equals_in_memory_run(tmp_path, raw):
    path = write_raw(tmp_path, raw)
    registry = registry_with(ToyPlugin())
    pipe = Pipeline({"steps": ["unchop", "note", "framesum"]}, registry=registry)
    in_memory = pipe.run(raw, stream=False)
    for source in (raw, path):
        streamed = pipe.run(source)
        np.testing.assert_allclose(streamed.data.data, in_memory.data.data, rtol=1e-12)
        assert streamed.order == "physical" and streamed.data.data.ndim == 2
        for key in ("S_UNCHOP", "S_NOTE", "S_FSUM"):
            assert streamed.header[key] == in_memory.header[key] == "COMPLETE"
        note, expected = streamed.tables["NOTE"], in_memory.tables["NOTE"]
        assert note["frame"].tolist() == expected["frame"].tolist() == list(range(4))
        np.testing.assert_allclose(note["mean"], expected["mean"], rtol=1e-12)


def write_raw(tmp_path, raw):
    from spherex_reduce import write

    return write(raw, tmp_path / "raw.fits")


def test_streaming_reads_one_frame_at_a_time(tmp_path, raw, monkeypatch):
    from spherex_reduce.io import frames as fits_format

    path = write_raw(tmp_path, raw)
    asked = []
    original = fits_format.FrameReader.frame

    def spy(self, k):
        asked.append(k)
        return original(self, k)

    monkeypatch.setattr(fits_format.FrameReader, "frame", spy)
    Pipeline({"steps": ["unchop", "framesum"]}, registry=registry_with(ToyPlugin())).run(path)
    assert asked == list(range(raw.schedule.nframes))


class _FailingAccumulator(_SumAccumulator):
    def add(self, index, frame):
        if index == 2:
            raise RuntimeError("accumulator broke on frame 2")
        super().add(index, frame)


class FailingSum(FrameSum):
    name, keyword = "failsum", "S_FAILS"

    def accumulator(self, schedule, header):
        return _FailingAccumulator()


class FailingNote(PerFrameNote):
    name, keyword = "failnote", "S_FAILN"

    def run(self, exposure):
        raise RuntimeError("per-frame step broke")


class FailingPlugin:
    @hookimpl
    def register_steps(self):
        return [FrameSum, FailingSum, FailingNote]


def _accumulating_threads():
    import threading

    return [t for t in threading.enumerate() if t.name == "spherex-reduce-accumulate"]


@pytest.mark.parametrize("steps, message", [
    (["unchop", "failsum"], "accumulator broke on frame 2"),
    (["unchop", "failnote", "framesum"], "per-frame step broke"),
])
def test_streaming_errors_reach_the_caller_and_leave_no_thread(raw, steps, message):
    # the accumulator runs in a thread of its own; its errors and the steps' errors
    # must still stop the run, in the caller, without leaving that thread behind
    pipe = Pipeline({"steps": steps}, registry=registry_with(FailingPlugin()))
    with pytest.raises(PluginError, match=message) as info:  # a plugin's failure, named
        pipe.run(raw)
    assert isinstance(info.value.__cause__, RuntimeError)
    assert _accumulating_threads() == []
