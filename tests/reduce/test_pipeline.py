"""Pipeline from YAML, plugin discovery, hooks and provenance."""

import importlib.metadata
import json
import types

import numpy as np
import pytest
from _one_by_one import one_by_one
from astropy.table import Table

import spherex_reduce
from spherex_reduce import ConfigError, Exposure, Pipeline, PluginError, Step, StepSkipped, unchop
from spherex_reduce.core.parameters import Parameter
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.reduce.hookspecs import hookimpl
from spherex_reduce.reduce.plugins import Registry, get_plugin_manager
from spherex_reduce.reduce.step import Consumer, Kernel, Record


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


class _SumConsumer(Consumer):
    """Toy consumer: the sum of the frames (a stand-in for fit_ramp), band by band."""

    def __init__(self, context):
        self.context = context
        n = (context.schedule.n_reads if context.order == "readout"
             else context.geometry.nrows)
        self.total = np.full((n, context.geometry.ncols), np.nan)
        self.bands = []

    def band(self, block):
        self.bands.append(len(block.index))
        self.total[block.index] = block.data.sum(axis=0, dtype=np.float64)

    def finish(self, reference, header, tables):
        c = self.context
        return Exposure.from_arrays(self.total, c.schedule, order=c.order, header=header,
                                    tables=tables)


class FrameSum(Step):
    name, keyword = "framesum", "S_FSUM"

    def consumer(self, context):
        if not context.ramp:
            raise StepSkipped("not ramps")
        return _SumConsumer(context)


class _NoteKernel(Kernel):
    """Toy kernel: minus each frame's mean reference read; the means in a table."""

    def prepare(self, side):
        return side.data.mean(axis=(1, 2), dtype=np.float64)

    def apply(self, means, block):
        return block.replace(data=block.data - means[:, None, None], owned=True)

    def record(self, means):
        return Record({"NOTE": Table({"frame": np.arange(means.size), "mean": means})})


class PerFrameNote(Step):
    name, keyword = "note", "S_NOTE"

    def kernel(self, context):
        return _NoteKernel(context)


class ToyPlugin:
    @hookimpl
    def register_steps(self):
        return [FrameSum, PerFrameNote]


def write_raw(tmp_path, raw):
    from spherex_reduce import write

    return write(raw, tmp_path / "raw.fits")


def test_a_plugin_kernel_and_consumer_stream_like_the_steps_called_one_by_one(tmp_path, raw):
    path = write_raw(tmp_path, raw)
    registry = registry_with(ToyPlugin())
    pipe = Pipeline({"steps": ["unchop", "note", "framesum"]}, registry=registry)
    s = raw.schedule
    # independently: the reference reads' mean of each frame, off the un-chopped pixels
    means = raw.data.data[:, s.reference_read_indices].mean(axis=(1, 2), dtype=np.float64)
    expected = (unchop(raw).data.data - means[:, None, None]).sum(axis=0)
    by_hand = one_by_one(pipe, raw)
    for source in (raw, path):
        out = pipe.run(source, threads=3)
        np.testing.assert_allclose(out.data.data, expected, rtol=1e-12)
        np.testing.assert_array_equal(out.data.data, by_hand.data.data)
        assert out.order == "physical" and out.data.data.ndim == 2
        for key in ("S_UNCHOP", "S_NOTE", "S_FSUM"):
            assert out.header[key] == by_hand.header[key] == "COMPLETE"
        np.testing.assert_allclose(out.tables["NOTE"]["mean"], means, rtol=1e-12)
        routes = out.tables["PROVENANCE"]["route"].tolist()
        assert all("pass of 3 step(s)" in r for r in routes)


def test_a_file_is_read_once_in_bands_of_reads_never_whole_frames(tmp_path, raw, monkeypatch):
    from spherex_reduce.io import FrameReader
    from spherex_reduce.reduce.executor import FileSource

    path = write_raw(tmp_path, raw)
    asked, frames = [], []
    original = FileSource.read
    monkeypatch.setattr(FileSource, "read", lambda self, lo, hi: (asked.append((lo, hi)),
                                                                  original(self, lo, hi))[1])
    monkeypatch.setattr(FrameReader, "frame", lambda self, k: frames.append(k))
    with patch_band_rows(monkeypatch, 5):
        Pipeline({"steps": ["unchop", "framesum"]}, registry=registry_with(ToyPlugin())).run(
            path, threads=2)
    covered = sorted(r for lo, hi in asked for r in range(lo, hi))
    assert covered == list(range(raw.schedule.n_reads))  # every read once
    assert max(hi - lo for lo, hi in asked) == 5 and frames == []


class patch_band_rows:
    """Bands of ``rows`` rows in the executor (small files would otherwise be one band)."""

    def __init__(self, monkeypatch, rows):
        from spherex_reduce.reduce import executor

        self.monkeypatch, self.executor, self.rows = monkeypatch, executor, rows

    def __enter__(self):
        ncols = 16
        self.monkeypatch.setattr(self.executor, "BAND_PIXELS", self.rows * ncols)
        return self

    def __exit__(self, *exc):
        return False


class _BrokenKernel(_NoteKernel):
    def apply(self, means, block):
        if block.index[0] > 10:
            raise RuntimeError("kernel broke on a band")
        return super().apply(means, block)


class FailingNote(PerFrameNote):
    name, keyword = "failnote", "S_FAILN"

    def kernel(self, context):
        return _BrokenKernel(context)


class FailingPlugin:
    @hookimpl
    def register_steps(self):
        return [FrameSum, FailingNote]


def _band_threads():
    import threading

    return [t for t in threading.enumerate() if t.name.startswith("spherex-reduce-band")]


@pytest.mark.parametrize("threads", [1, 3])
def test_a_kernel_error_in_a_band_reaches_the_caller_and_leaves_no_thread(raw, monkeypatch,
                                                                          threads):
    pipe = Pipeline({"steps": ["unchop", "failnote", "framesum"]},
                    registry=registry_with(FailingPlugin()))
    with patch_band_rows(monkeypatch, 4), pytest.raises(PluginError,
                                                        match="kernel broke") as info:
        pipe.run(raw, threads=threads)
    assert isinstance(info.value.__cause__, RuntimeError)
    assert _band_threads() == []


def test_provenance_rows_survive_a_file_and_grow_with_the_next_reduction(tmp_path, raw):
    from spherex_reduce import fit_ramp, read, write

    first = Pipeline({"steps": ["unchop", "subtract_phantom"]}).run(raw)
    path = write(first, tmp_path / "stage1.fits")
    again = read(path)
    second = Pipeline({"steps": ["correct_reference"]}).run(again)
    rows = second.tables["PROVENANCE"]
    assert rows["step"].tolist() == ["unchop", "subtract_phantom", "correct_reference"]
    assert json.loads(rows["parameters"][2])["strategy"] == "mean"
    assert json.loads(rows["versions"][0]) == {"spherex-reduce": spherex_reduce.__version__}
    assert rows["elapsed"].unit == "s" and (rows["elapsed"] >= 0).all()
    # a function called alone records its step too (stpipe style)
    alone = fit_ramp(second)
    assert alone.header["S_RAMPFT"] == "COMPLETE"
    assert alone.tables["PROVENANCE"]["step"].tolist()[-1] == "fit_ramp"
    assert alone.tables["PROVENANCE"]["route"][-1] == "whole exposure"
