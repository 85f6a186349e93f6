"""Roman WFI level-1 files (ASDF, ``ScienceRawModel``) read through the one entry point.

The files are built with ``roman_datamodels`` itself (``create_fake_data``, the
metadata set as a level-1 file has them, ``save``), with an uneven read pattern
counted from 1 as Roman's; slopes are checked against numpy's least squares on
the resultant times written here: the mean read of each resultant times the
frame time.
"""

import sys

import numpy as np
import pytest

import spherex_reduce as sr
from spherex_reduce.cli import main
from spherex_reduce.core.errors import FormatError

rdm = pytest.importorskip("roman_datamodels.datamodels")

PATTERN = [[1], [2, 3], [4, 5, 6, 7], [8]]
FRAME_TIME = 3.04
N, NROWS, NCOLS = len(PATTERN), 32, 64
#: the resultant times: mean read number (from 1) times the frame time
TIMES = np.array([np.mean(reads) for reads in PATTERN]) * FRAME_TIME
FLAGGED = (9, 17, 2)  # (resultant, row, column) flagged in resultantdq


def _resultants(seed=5):
    rng = np.random.default_rng(seed)
    rate = rng.uniform(5, 60, (NROWS, NCOLS))
    values = 2000 + rate * TIMES[:, None, None] + rng.normal(0, 4, (N, NROWS, NCOLS))
    return np.round(values).astype(np.uint16)


def _save(path, detector="WFI01", data=None, flags=None, **exposure):
    """A level-1 file as roman_datamodels writes it; ``exposure`` overrides meta.exposure."""
    data = _resultants() if data is None else data
    model = rdm.ScienceRawModel.create_fake_data(shape=data.shape)
    model.data = data
    model.amp33 = np.zeros((data.shape[0], data.shape[1], 128), np.uint16)
    values = {"read_pattern": PATTERN, "nresultants": data.shape[0],
              "frame_time": FRAME_TIME, **exposure}
    for key, value in values.items():
        model.meta.exposure[key] = value
    model.meta.instrument.detector = detector
    if flags is not None:
        model.resultantdq = flags
    model.save(path)
    return data


def _numpy_slopes(data, times=TIMES):
    """Ordinary least squares of every pixel's resultants on ``times`` (numpy alone)."""
    design = np.vstack([times, np.ones_like(times)]).T
    flat = data.reshape(data.shape[0], -1).astype(np.float64)
    return np.linalg.lstsq(design, flat, rcond=None)[0][0].reshape(data.shape[1:])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("roman")
    out = {}
    for detector in ("WFI01", "WFI03"):
        out[detector] = (d / f"{detector}_uncal.asdf", _save(d / f"{detector}_uncal.asdf",
                                                           detector))
    flags = np.zeros((N, NROWS, NCOLS), np.uint8)
    flags[FLAGGED[0] % N, FLAGGED[1], FLAGGED[2]] = 4  # Roman's JUMP_DET
    out["dq"] = (d / "dq_uncal.asdf", _save(d / "dq_uncal.asdf", flags=flags))
    return out


@pytest.mark.parametrize("detector", ["WFI01", "WFI03"])
def test_read_pattern_geometry_and_timing_come_from_the_file(files, detector):
    path, data = files[detector]
    e = sr.read(path)
    s = e.schedule
    assert [list(g) for g in s.groups] == PATTERN  # Roman's read numbers kept
    np.testing.assert_allclose(s.frame_starts.to_value("s"), TIMES, rtol=1e-12)
    assert s.frame_time.to_value("s") == FRAME_TIME
    g = s.geometry
    assert (g.nrows, g.ncols, g.nchannels, g.ref_border) == (NROWS, NCOLS, 32, 4)
    assert g.scan_directions.tolist() == [1, -1] * 16
    # science orientation: WFI03's columns are reversed (rows read from row 0), the
    # others' rows (read from the last row: romancal's frame_read_times)
    first = 0 if detector == "WFI03" else NROWS - 1
    assert int(s.rows[0]) == first and sorted(s.rows.tolist()) == list(range(NROWS))
    assert e.order == "physical" and str(e.unit) == "adu"
    np.testing.assert_array_equal(e.data.data, data.astype(np.float32))  # not flipped
    assert e.header["DETECTOR"] == detector and e.header["TELESCOP"] == "ROMAN"


@pytest.mark.parametrize("detector", ["WFI01", "WFI03"])
def test_slopes_match_numpy_least_squares(files, detector):
    path, data = files[detector]
    reduced = sr.Pipeline({"steps": [{"fit_ramp": {"weighting": "uniform"}}]}).run(path)
    assert str(reduced.unit) == "adu / s"
    np.testing.assert_allclose(reduced.data.data, _numpy_slopes(data), rtol=1e-6, atol=0)


def test_input_section_gain_and_first_resultant_dropped(files):
    path, data = files["WFI01"]
    config = {"input": {"gain": 2.0, "drop_first_reads": 1}, "steps": ["fit_ramp"]}
    reduced = sr.Pipeline(config).run(path)
    assert str(reduced.unit) == "electron / s" and reduced.header["NDROPRD"] == 1
    np.testing.assert_allclose(reduced.data.data, 2 * _numpy_slopes(data[1:], TIMES[1:]),
                               rtol=1e-6, atol=0)


def test_resultantdq_masks_as_a_foreign_dq(files):
    path, _ = files["dq"]
    e = sr.read(path)
    k, row, col = FLAGGED[0] % N, FLAGGED[1], FLAGGED[2]
    assert np.flatnonzero(e.dq).tolist() == [np.ravel_multi_index((k, row, col), e.dq.shape)]
    assert e.header["SXRDQBIT"] == 0xFFFFFFFF
    assert not sr.read(path, dq_bits=1).dq.any()  # bit 2 (JUMP_DET) only, not chosen


def test_cli_reduces_a_roman_file_with_a_steps_only_config(files, tmp_path):
    path, data = files["WFI01"]
    config = tmp_path / "steps.yaml"
    config.write_text("steps:\n  - fit_ramp: {weighting: uniform}\n")
    out = tmp_path / "slopes.fits"
    assert main(["-q", "reduce", str(path), "-c", str(config), "-o", str(out)]) == 0
    np.testing.assert_allclose(sr.read(out).data.data, _numpy_slopes(data), rtol=1e-6, atol=0)


@pytest.mark.parametrize("change, message", [
    ({"read_pattern": [[1], [2, 3], [4]]}, r"read_pattern lists 3 resultants but data holds 4"),
    ({"nresultants": 5}, r"nresultants is 5 but data holds 4"),
    ({"frame_time": -999999.0}, r"frame_time is -999999.0, not a time > 0"),
    ({"read_pattern": [[1], [3, 2], [4], [5]]}, r"strictly increasing"),
    ({"read_pattern": [[1], [2, 3], [3, 4], [5]]}, r"must not overlap"),
])
def test_inconsistent_metadata_refused_in_one_line(tmp_path, change, message):
    path = tmp_path / "bad_uncal.asdf"
    _save(path, **change)
    with pytest.raises(FormatError, match=message):
        sr.read(path)


def test_reads_extensions_and_a_width_not_of_32_outputs_refused(tmp_path):
    path = tmp_path / "det_uncal.asdf"
    _save(path)
    with pytest.raises(FormatError, match=r"input.reads is extensions"):
        sr.read(path, input={"reads": "extensions"})
    _save(path, data=_resultants()[:, :, :48])  # 48 columns: not 32 outputs
    with pytest.raises(FormatError, match=r"48 columns, not a multiple of the 32 outputs"):
        sr.read(path)


def test_config_values_are_compared_with_the_file(files):
    path, _ = files["WFI01"]
    with pytest.raises(FormatError, match=r"PIXRATE .* pixel_rate is 200000"):
        sr.Pipeline({"geometry": {"pixel_rate": 2e5}, "steps": ["fit_ramp"]}).run(path)
    e = sr.read(path, nrows=NROWS, frame_time=FRAME_TIME)  # agreeing values are fine
    assert e.schedule.frame_time.to_value("s") == FRAME_TIME


def test_not_a_level_1_file_refused(tmp_path):
    import asdf

    path = tmp_path / "other.asdf"
    asdf.AsdfFile({"x": np.arange(3)}).write_to(path)
    with pytest.raises(FormatError, match=r"roman_datamodels cannot open"):
        sr.read(path)


def test_without_roman_datamodels_one_line_naming_the_extra(files, monkeypatch, capsys,
                                                            tmp_path):
    path, _ = files["WFI03"]
    monkeypatch.setitem(sys.modules, "roman_datamodels", None)  # import fails
    with pytest.raises(FormatError, match=r"pip install 'spherex_reduce\[roman\]'"):
        sr.read(path)
    config = tmp_path / "steps.yaml"
    config.write_text("steps: [fit_ramp]\n")
    out = tmp_path / "slopes.fits"
    assert main(["reduce", str(path), "-c", str(config), "-o", str(out)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "spherex_reduce[roman]" in err[0] and not out.exists()


@pytest.mark.parametrize("pattern, frame_time, detector, message", [
    ([["1"], [2]], 3.04, "WFI03", r"read_pattern must be a list of lists of read numbers"),
    ([[1], [2.0]], 3.04, "WFI03", r"read_pattern must be a list of lists"),
    ([[True], [2]], 3.04, "WFI03", r"read_pattern must be a list of lists"),
    (5, 3.04, "WFI03", r"read_pattern must be a list of lists"),
    ([[1], []], 3.04, "WFI03", r"read_pattern must be a list of lists"),
    ([[1], [2]], float("nan"), "WFI03", r"frame_time is nan"),
    ([[1], [2]], "3.04", "WFI03", r"frame_time is '3.04'"),
    ([[1], [2]], 1e30, "WFI03", r"more than the .* a schedule can count"),
    ([[1], [2]], 3.04, "WFI19", r"detector is 'WFI19', not one of WFI01 \.\.\. WFI18"),
    ([[1], [2]], 3.04, None, r"detector is None"),
])
def test_metadata_of_the_wrong_kind_refused(pattern, frame_time, detector, message):
    from spherex_reduce.io.readers.roman_l1 import roman_schedule

    with pytest.raises(FormatError, match=message):
        roman_schedule((2, 16, 64), pattern, frame_time, detector, "x_uncal.asdf")
