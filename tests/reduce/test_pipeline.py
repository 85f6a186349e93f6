"""Pipeline from YAML: step order, hooks, skipped steps, config errors, passes and provenance."""

import json

import numpy as np
import pytest
from _toy_steps import OffsetPlugin, registry_with
from astropy import units as u

import spherex_reduce
from spherex_reduce import (
    ConfigError,
    Exposure,
    Pipeline,
    correct_reference,
    fit_ramp,
    read,
    subtract_phantom,
    unchop,
    write,
)
from spherex_reduce.io.examples import example_raw_exposure, tiny_schedule


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=5)


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


@pytest.mark.parametrize("second", ["skip", "add"])
def test_a_step_listed_twice_records_that_it_ran(raw, second):
    """The docs allow a step listed more than once.  When its first run completes and a later
    one is skipped, the status keyword says the data went through it (COMPLETE; it said
    SKIPPED); each run's own status is in HISTORY and PROVENANCE, in order."""
    pipe = Pipeline({"steps": [{"offset": {"value": 2}}, "unchop",
                               {"offset": {"value": 3, "mode": second}}]},
                    registry=registry_with(OffsetPlugin()))
    out = pipe.run(raw)
    added = 2.0 + (3.0 if second == "add" else 0.0)
    np.testing.assert_allclose(out.data.data, unchop(raw).data.data + added, rtol=1e-6)
    assert out.header["S_OFFSET"] == "COMPLETE" and out.header["S_UNCHOP"] == "COMPLETE"
    last = "COMPLETE" if second == "add" else "SKIPPED"
    assert out.tables["PROVENANCE"]["status"].tolist() == ["COMPLETE", "COMPLETE", last]
    history = [str(v) for v in out.header["HISTORY"]]
    assert [h.split(" in ")[0] for h in history if h.startswith("offset ")] == [
        "offset complete", f"offset {last.lower()}"] + (
        ["offset skipped: asked to skip"] if second == "skip" else [])
    alone = Pipeline({"steps": [{"offset": {"mode": "skip"}}, {"offset": {"mode": "skip"}}]},
                     registry=registry_with(OffsetPlugin())).run(raw)
    assert alone.header["S_OFFSET"] == "SKIPPED"  # no run completed


def test_a_repeated_step_is_reported_run_by_run(tmp_path, raw, capsys):
    """``reduce`` prints every run's status in order (it printed the keyword's, SKIPPED, for
    both runs of fit_ramp), and the file says fit_ramp ran."""
    from astropy.io import fits

    from spherex_reduce.cli import main

    write(raw, tmp_path / "raw.fits")
    (tmp_path / "twice.yaml").write_text("steps: [unchop, fit_ramp, unchop, fit_ramp]\n")
    out = tmp_path / "out.fits"
    assert main(["reduce", str(tmp_path / "raw.fits"), "-c", str(tmp_path / "twice.yaml"),
                 "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == (
        f"wrote {out} (unchop=COMPLETE, fit_ramp=COMPLETE, unchop=SKIPPED, fit_ramp=SKIPPED)")
    header = fits.getheader(out)
    assert header["S_RAMPFT"] == "COMPLETE" and header["S_UNCHOP"] == "COMPLETE"


def test_effective_config_fills_defaults():
    pipe = Pipeline({"steps": ["unchop", {"offset": {"value": 1}}]},
                    registry=registry_with(OffsetPlugin()))
    assert pipe.config == {"steps": [{"unchop": {}},
                                     {"offset": {"value": 1.0, "mode": "add"}}]}
    assert "value: 1.0" in pipe.to_yaml()
    same = Pipeline({"steps": ["unchop", {"offset": {"value": 1.0, "mode": "add"}}]},
                    registry=registry_with(OffsetPlugin()))
    assert same.config_hash == pipe.config_hash


def test_maps_given_as_arrays_hash_by_their_values():
    # str() of a large array abbreviates it: two maps that differ inside must not hash alike
    a = np.full((64, 64), 10.0)
    b = a.copy()
    b[30, 30] = 11.0
    assert "..." in str(a)
    hashes = {Pipeline({"steps": [{"detect_jumps": {"read_noise": v}}]}).config_hash
              for v in (a, b, 10.0)}
    assert len(hashes) == 3
    assert Pipeline({"steps": [{"detect_jumps": {"read_noise": a.copy()}}]}).config_hash in hashes
    # a Quantity's unit is part of it: 10 e and 10 ADU of read noise are not one map
    q = [Pipeline({"steps": [{"detect_jumps": {"read_noise": a * unit}}]}).config_hash
         for unit in (u.electron, u.adu)]
    assert q[0] != q[1] and not set(q) & hashes


def test_a_quiet_parameter_given_as_an_array_is_hashed_by_its_values():
    # a parameter left out of the hash at its default is compared without numpy's ==
    a = np.full((64, 64), 0.01)
    b = a.copy()
    b[3, 3] = 0.02
    hashes = [Pipeline({"steps": [{"detect_jumps": {"read_noise": 10.0, "expected_rate": v}}]})
              .config_hash for v in (a, b, a.copy())]
    assert hashes[0] != hashes[1] and hashes[0] == hashes[2]


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


def test_input_exposure_is_not_mutated(raw):
    data = raw.data.data.copy()
    header = raw.header.copy()
    Pipeline({"steps": ["unchop"]}).run(raw)
    np.testing.assert_array_equal(raw.data.data, data)
    assert raw.header == header and isinstance(raw, Exposure)


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


def test_source_masking_runs_in_a_pass_staged_at_its_estimate(tmp_path):
    """The median strategy estimates from every pixel (and masks sources on the last minus
    the first frame): first of a pass over a file it runs whole; after ``unchop`` the pass
    is staged at its estimate (the unchopped exposure made first, then corrected and
    fitted in place), the numbers those of the steps run one by one."""
    raw = example_raw_exposure(tiny_schedule(nframes=3), seed=2)
    path = write(raw, tmp_path / "raw.fits")

    def routes(steps):
        out = Pipeline({"steps": steps}).run(path)
        return [(row["step"], row["route"]) for row in out.tables["PROVENANCE"]]

    median = {"correct_reference": {"strategy": "median", "mask_sources": True}}
    masked = routes(["unchop", median, "fit_ramp"])
    assert all("pass of 3 step(s)" in route and "from a file" in route
               and route.endswith("in 2 stages (an exposure made for a whole-exposure "
                                  "estimate)") for _, route in masked)
    assert routes([median]) == [("correct_reference", "whole exposure")]
    one_by_one = fit_ramp(correct_reference(unchop(raw), "median", mask_sources=True))
    staged = Pipeline({"steps": ["unchop", median, "fit_ramp"]}).run(path)
    np.testing.assert_array_equal(staged.data.data, one_by_one.data.data)
    mean = routes(["unchop", {"correct_reference": {"strategy": "mean"}}, "fit_ramp"])
    assert all("pass of 3 step(s)" in route and "from a file" in route
               and "stages" not in route for _, route in mean)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_a_staged_pass_that_unchops_after_the_estimate_equals_the_steps_one_by_one(
        monkeypatch, dtype):
    """``unchop`` after a whole-exposure estimate writes readout rows to physical ones: the
    second stage must not write them into the first stage's arrays, whose other rows are
    still to be read (bands of 8 rows here, several on two threads)."""
    from spherex_reduce.reduce import executor

    raw = example_raw_exposure(seed=3)
    flags = np.zeros(raw.data.data.shape, np.uint32)
    flags[:, 5::17, 3::11] = spherex_reduce.dq.DO_NOT_USE
    e = Exposure.from_arrays(np.asarray(raw.data.data, dtype), raw.schedule, mask=flags,
                             phantom=raw.phantom, header=raw.header)
    before = np.array(e.data.data)
    monkeypatch.setattr(executor, "BAND_PIXELS", 8 * e.data.data.shape[-1])
    steps = ["subtract_phantom", {"correct_reference": {"strategy": "median"}}, "unchop"]
    staged = Pipeline({"steps": steps}).run(e, threads=2)
    assert "in 2 stages" in staged.tables["PROVENANCE"]["route"][1]
    one_by_one = unchop(correct_reference(subtract_phantom(e), "median"))
    np.testing.assert_array_equal(staged.data.data, one_by_one.data.data)
    np.testing.assert_array_equal(staged.dq, one_by_one.dq)
    np.testing.assert_array_equal(e.data.data, before)  # the input is not written


def test_streamed_file_keeps_its_tables(tmp_path):
    from astropy.table import Table

    s = tiny_schedule(nframes=3)
    raw = example_raw_exposure(s, seed=1).replace(tables={"NOTES": Table({"x": [1, 2]})})
    path = write(raw, tmp_path / "raw.fits")
    out = Pipeline({"steps": ["unchop", "fit_ramp"]}).run(path)
    assert "NOTES" in out.tables and out.tables["NOTES"]["x"].tolist() == [1, 2]
    assert read(path).tables["NOTES"]["x"].tolist() == [1, 2]
