"""The fused streaming path gives the numbers of the steps run one after another, bit for bit."""

import warnings

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, Pipeline, ReadoutSchedule, write
from spherex_reduce.examples import example_raw_exposure
from spherex_reduce.steps.reference import NoReferenceWarning

FIT = {"fit_ramp": {}}


def schedule(ref_mode="distributed", nframes=11, skip=5, phantom_reads=3):
    # 11 frames: the fit's buffers of 4 frames fill twice and are summed partly full once
    return ReadoutSchedule(DetectorGeometry(32, 16, 2, ref_border=2), skip=skip, ref_reads=6,
                           ref_mode=ref_mode, phantom_reads=phantom_reads, row_overhead=2,
                           frame_overhead=50, nframes=nframes)


def fused_and_not(config, source):
    """The fused run, and the steps run one by one: on the whole ramp if the fused
    run fitted it band by band, else frame by frame."""
    pipe = Pipeline(config)
    with warnings.catch_warnings(record=True) as w_fused:
        warnings.simplefilter("always")
        fused = pipe.run(source)
    with warnings.catch_warnings(record=True) as w_plain:
        warnings.simplefilter("always")
        if was_banded(fused):
            plain = pipe.run(source, stream=False)
        else:
            plain = pipe.run(source, fuse=False)
    return fused, plain, w_fused, w_plain


def was_fused(exposure):
    return any("fused into fit_ramp" in str(h) for h in exposure.header["HISTORY"])


def was_banded(exposure):
    return any("a band of rows at a time" in str(h) for h in exposure.header["HISTORY"])


def assert_identical(fused, plain):
    np.testing.assert_array_equal(fused.data.data, plain.data.data)
    np.testing.assert_array_equal(fused.data.uncertainty.array, plain.data.uncertainty.array)
    np.testing.assert_array_equal(fused.dq, plain.dq)
    np.testing.assert_array_equal(fused.reference.data, plain.reference.data)
    assert sorted(fused.tables) == sorted(plain.tables)
    for name in fused.tables:
        a, b = fused.tables[name], plain.tables[name]
        assert a.colnames == b.colnames
        for col in a.colnames:
            np.testing.assert_array_equal(np.asarray(a[col]), np.asarray(b[col]), err_msg=name)
    skip = {"HISTORY"}
    keys = [k for k in plain.header if k not in skip]
    # the whole-ramp run records each step's keywords as it goes, the streamed
    # ones after the frames: the same keywords in another order
    assert sorted(k for k in fused.header if k not in skip) == sorted(keys)
    for key in keys:
        assert fused.header[key] == plain.header[key], key


STEPS = {
    "mean": [{"unchop": {}}, {"subtract_phantom": {}},
             {"correct_reference": {"strategy": "mean"}}, FIT],
    "acn": [{"unchop": {}}, {"subtract_phantom": {}},
            {"correct_reference": {"strategy": "acn", "sigma": 2.5, "maxiters": 3}}, FIT],
    "phantom only": [{"unchop": {}}, {"subtract_phantom": {}}, FIT],
    "read noise": [{"unchop": {}}, {"subtract_phantom": {}},
                   {"correct_reference": {"strategy": "mean"}},
                   {"fit_ramp": {"read_noise": 10.0}}],
}


@pytest.mark.parametrize("name", sorted(STEPS))
@pytest.mark.parametrize("ref_mode", ["distributed", "repeated"])
def test_fused_equals_the_steps_on_a_file_and_in_memory(tmp_path, name, ref_mode):
    raw = example_raw_exposure(schedule(ref_mode), seed=4)
    path = write(raw, tmp_path / "raw.fits")
    for source in (path, raw):
        fused, plain, _, _ = fused_and_not({"steps": STEPS[name]}, source)
        assert was_banded(fused) and not was_fused(plain)
        assert_identical(fused, plain)


def test_fused_with_unusable_reads_and_a_channel_without_reference(tmp_path):
    s = schedule()
    raw = example_raw_exposure(s, seed=5)
    data = raw.data.data.copy()
    data[3, 10, 5] = np.nan  # one unusable read of an active pixel
    data[:9, 20, 9] = np.nan  # a pixel without a usable read in the fit's first buffer
    ref = s.reference_read_indices
    data[np.ix_([2, 6], ref, np.arange(8, 16))] = np.nan  # channel 1: no reference, 2 frames
    data[4, ref[0], 3] = np.nan  # one reference pixel
    raw = raw.replace(data=data)
    path = write(raw, tmp_path / "raw.fits")
    fused, plain, w_fused, w_plain = fused_and_not({"steps": STEPS["acn"]}, path)
    assert was_fused(fused)
    assert_identical(fused, plain)
    assert fused.header["NNOREF"] == 4  # two frames x (even, odd) of channel 1
    noref = [w for w in w_fused if issubclass(w.category, NoReferenceWarning)]
    assert len(noref) == len([w for w in w_plain if issubclass(w.category, NoReferenceWarning)])
    assert len(noref) == 2


@pytest.mark.parametrize("steps", [
    [{"unchop": {}}, FIT],
    [{"unchop": {}}, {"correct_reference": {"strategy": "acn"}}, FIT],
])
def test_fused_without_phantom_reads(tmp_path, steps):
    raw = example_raw_exposure(schedule(phantom_reads=0), seed=12)
    path = write(raw, tmp_path / "raw.fits")
    fused, plain, _, _ = fused_and_not({"steps": steps}, path)
    assert was_fused(fused)
    assert_identical(fused, plain)


def test_integer_phantom_values_in_a_file_are_not_fused(tmp_path):
    # the steps work in float64 with integer phantom values: not the fused path's precision
    raw = example_raw_exposure(schedule(), seed=13)
    raw = raw.replace(phantom=np.round(raw.phantom).astype(np.int16))
    path = write(raw, tmp_path / "raw.fits")
    fused, plain, _, _ = fused_and_not({"steps": STEPS["mean"]}, path)
    assert not was_fused(fused)
    assert_identical(fused, plain)


def test_fused_on_float64_input_in_memory():
    raw = example_raw_exposure(schedule(), seed=6)
    raw = raw.replace(data=raw.data.data.astype(np.float64), phantom=raw.phantom.astype(np.float64))
    fused, plain, _, _ = fused_and_not({"steps": STEPS["mean"]}, raw)
    assert was_fused(fused)
    assert_identical(fused, plain)


@pytest.mark.parametrize("steps", [
    [{"unchop": {}}, {"subtract_phantom": {}}, {"correct_reference": {"strategy": "median"}},
     FIT],
    [{"unchop": {}}, {"subtract_phantom": {}},
     {"correct_reference": {"strategy": "mean", "side_columns": True}}, FIT],
    [{"unchop": {}}, {"subtract_phantom": {}}, {"fit_ramp": {"saturation": 1e5}}],
    [{"unchop": {}}, {"subtract_phantom": {}},
     {"fit_ramp": {"weighting": "optimal", "read_noise": 10.0}}],
    [{"unchop": {}}, {"correct_reference": {"strategy": "mean"}}, FIT],  # phantom kept
])
def test_other_step_lists_are_not_fused(steps):
    raw = example_raw_exposure(schedule(nframes=4), seed=7)
    out = Pipeline({"steps": steps}).run(raw)
    assert not was_fused(out)


def test_skipped_step_on_the_first_frame_stops_fusing():
    # no phantom reads: subtract_phantom is skipped on the first frame, so the later
    # frames go through the steps too (and it is reported skipped)
    raw = example_raw_exposure(schedule(phantom_reads=0, nframes=4), seed=8)
    out = Pipeline({"steps": STEPS["mean"]}).run(raw)
    assert out.header["S_PHANTM"] == "SKIPPED" and not was_fused(out)


def test_cli_no_fuse_gives_the_same_file_contents(tmp_path):
    from spherex_reduce import read
    from spherex_reduce.cli import main

    path = write(example_raw_exposure(schedule(), seed=9), tmp_path / "raw.fits")
    outs = {}
    for flag in ([], ["--no-fuse"]):
        out = tmp_path / f"out{len(flag)}.fits"
        assert main(["-q", "reduce", str(path), "-c", "spherex-default", "-o", str(out),
                     *flag]) == 0
        outs[len(flag)] = read(out)
    assert was_banded(outs[0]) and not was_fused(outs[1])
    # fitted at once vs frame by frame: the same fit up to float32 rounding
    err = outs[1].data.uncertainty.array
    assert np.abs(outs[0].data.data - outs[1].data.data).max() < 1e-4 * np.nanmin(err)
    np.testing.assert_array_equal(outs[0].dq, outs[1].dq)


def test_bands_on_threads_equal_the_steps_on_the_whole_ramp(tmp_path, monkeypatch):
    from spherex_reduce.steps import ramp

    monkeypatch.setattr(ramp, "_BAND_PIXELS", 48)  # 3 rows of 16 columns: 11 bands
    monkeypatch.setattr(ramp, "_PARALLEL_SIZE", 0)  # on two threads however small
    monkeypatch.setattr(ramp, "_THREADS", 2)
    s = schedule()
    raw = example_raw_exposure(s, seed=14)
    data = raw.data.data.copy()
    data[3, 10, 5] = np.nan  # unusable reads: refitted on the usable ones, no flag
    data[:, 12, 7] = np.nan
    data[4, s.reference_read_indices[0], 3] = np.nan  # one reference pixel
    path = write(raw.replace(data=data), tmp_path / "raw.fits")
    for name in ("mean", "acn"):
        fused, plain, w_fused, w_plain = fused_and_not({"steps": STEPS[name]}, path)
        assert was_banded(fused)
        assert_identical(fused, plain)
        assert len(w_fused) == len(w_plain)
    assert fused.header["NFEWRDS"] >= 1


def test_bright_pixels_refitted_in_bands_equal_the_whole_ramp(tmp_path, monkeypatch):
    # pixels refitted in float64 (here: bright ramps) are fitted in batches that differ
    # between bands (rows in read order) and whole-cube blocks (rows in order): a
    # pixel's numbers must not depend on its batch
    from spherex_reduce.steps import ramp

    monkeypatch.setattr(ramp, "_BAND_PIXELS", 48)
    monkeypatch.setattr(ramp, "_PARALLEL_SIZE", 0)
    monkeypatch.setattr(ramp, "_THREADS", 2)
    s = schedule()
    first = s.read_of_row()
    raw = example_raw_exposure(s, seed=14)
    data = raw.data.data.copy()
    for row, col in [(10, 3), (11, 4), (12, 5), (20, 9)]:  # a source over a few rows
        data[:, first[row], col] += (2e4 * np.arange(s.nframes)).astype(np.float32)
    path = write(raw.replace(data=data), tmp_path / "raw.fits")
    for name in ("mean", "read noise"):
        fused, plain, _, _ = fused_and_not({"steps": STEPS[name]}, path)
        assert was_banded(fused)
        assert_identical(fused, plain)


def test_flags_fit_frame_by_frame_as_the_steps_do(tmp_path):
    s = schedule()
    raw = example_raw_exposure(s, seed=15)
    data = raw.data.data.copy()
    data[np.ix_([2], s.reference_read_indices, np.arange(8, 16))] = np.nan  # NO_REFERENCE
    path = write(raw.replace(data=data), tmp_path / "raw.fits")
    fused, plain, _, _ = fused_and_not({"steps": STEPS["mean"]}, path)
    assert was_fused(fused) and not was_banded(fused)
    assert_identical(fused, plain)


def test_fused_equals_the_steps_with_background_sums(monkeypatch):
    from spherex_reduce import fused as fused_module
    from spherex_reduce.steps import ramp

    monkeypatch.setattr(ramp, "_ASYNC_PIXELS", 0)  # the full-size path, on a small image
    # frame by frame, as when something is flagged
    monkeypatch.setattr(fused_module.FusedFrames, "bandable", lambda self, first, parts: False)
    raw = example_raw_exposure(schedule(nframes=20), seed=10)
    fused, plain, _, _ = fused_and_not({"steps": STEPS["acn"]}, raw)
    assert was_fused(fused) and not was_banded(fused)
    assert_identical(fused, plain)


def test_an_error_in_a_band_reaches_the_caller_and_stops_the_others(tmp_path, monkeypatch):
    import threading

    from spherex_reduce import fused
    from spherex_reduce.steps import ramp

    monkeypatch.setattr(ramp, "_BAND_PIXELS", 16)  # one row per band: 32 bands
    monkeypatch.setattr(ramp, "_PARALLEL_SIZE", 0)
    monkeypatch.setattr(ramp, "_THREADS", 2)
    path = write(example_raw_exposure(schedule(), seed=16), tmp_path / "raw.fits")
    original = fused.FusedFrame.rows
    failed = threading.Event()
    after = []

    def broken(self, src, rereads, out, raw=None, first=0):
        if failed.is_set():
            after.append(1)
        elif src.max() > 15:  # a band in the middle, while the other thread works
            failed.set()
            raise RuntimeError("a band broke")
        return original(self, src, rereads, out, raw, first)

    monkeypatch.setattr(fused.FusedFrame, "rows", broken)
    with pytest.raises(RuntimeError, match="a band broke"):
        Pipeline({"steps": STEPS["mean"]}).run(path)
    assert not [t for t in threading.enumerate() if t.name.startswith("spherex-reduce")]
    # the other thread finishes at most the band it was copying (10 frames), not all
    # of its remaining ~8 bands
    assert len(after) <= 10


def test_an_error_while_fusing_reaches_the_caller(tmp_path, monkeypatch):
    import threading

    from spherex_reduce import fused
    from spherex_reduce.steps import ramp

    path = write(example_raw_exposure(schedule(), seed=11), tmp_path / "raw.fits")
    original = fused.FusedFrame.fill
    calls = []

    def broken(self, out):
        calls.append(1)
        if len(calls) == 9:  # two buffers of frames are being summed or were
            raise RuntimeError("fused frame 9 broke")
        return original(self, out)

    monkeypatch.setattr(fused.FusedFrame, "fill", broken)
    monkeypatch.setattr(fused.FusedFrames, "bandable", lambda self, first, parts: False)
    monkeypatch.setattr(ramp, "_ASYNC_PIXELS", 0)  # with the fit's summing thread
    with pytest.raises(RuntimeError, match="fused frame 9 broke"):
        Pipeline({"steps": STEPS["mean"]}).run(path)
    assert not [t for t in threading.enumerate() if t.name.startswith("spherex-reduce")]
