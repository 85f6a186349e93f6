"""A reference border per side: reference pixels where declared, and only there.

The corner of an array (issue 13: a 40 x 40 corner of an H4RG) has reference rows
on one side and reference columns on one side only.  ``ref_border`` takes one
width (every side) or ``{top, bottom, left, right}``; ``top`` is the rows from
row 0, ``left`` the columns from column 0.
"""

import logging
import warnings

import numpy as np
import pytest
import yaml
from astropy.io import fits
from astropy.table import Table

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    Pipeline,
    ReadoutSchedule,
    RefBorder,
    correct_reference,
    read,
    simulate,
    unchop,
    write,
)
from spherex_reduce.analysis.timestreams import reference_timestream
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError, FormatError
from spherex_reduce.io.config import load_yaml, schedule_from_config
from spherex_reduce.reduce.steps.reference.strategies import UnequalReferenceWarning

CORNER = {"top": 4, "left": 4}
SIDE_KEYWORDS = ("REFBTOP", "REFBBOT", "REFBLEFT", "REFBRIGH")
SIDE_LABELS = ("top", "bottom", "left", "right")


def corner_schedule(border=CORNER, **readout):
    """40 x 40, two channels of 20 columns, reference rows on top and columns on the left."""
    params = {"skip": 3, "ref_reads": 8, "ref_mode": "distributed", "phantom_reads": 0,
              "nframes": 3, **readout}
    return ReadoutSchedule(DetectorGeometry(40, 40, 2, ref_border=border), **params)


def corner_ramps(s, seed=0):
    """Physical frames ``(3, 40, 40)``: per-frame, per-channel offsets plus noise; the last four
    rows (light-sensitive in the corner) sit 760 ADU low, as in the issue's H4RG corner."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0, 50, (s.nframes, 2))
    phys = np.repeat(offsets, 20, axis=1)[:, None, :] + rng.normal(0, 2, (s.nframes, 40, 40))
    phys[:, 36:, 4:] -= 760.0
    return phys


# -- the done-when of issue 13: offsets from exactly the declared reference pixels -------------
@pytest.mark.parametrize("order", ["readout", "physical"])
def test_one_sided_border_offsets_are_the_mean_of_exactly_the_declared_pixels(order):
    s = corner_schedule()
    phys = corner_ramps(s)
    raw = Exposure.from_arrays(phys[:, s.rows, :], s)  # the reads as the schedule takes them
    e = raw if order == "readout" else unchop(raw)
    ref_rows = s.rows[s.is_reference]  # rows of the 8 reference reads: each top row twice
    assert sorted(set(ref_rows.tolist())) == [0, 1, 2, 3]
    for side_columns in (False, True):
        with warnings.catch_warnings():  # the left side's channel only: said once, in one line
            warnings.simplefilter("ignore", UnequalReferenceWarning)
            t = correct_reference(e, "mean", sigma=1e6,
                                  side_columns=side_columns).tables["REFOFFS"]
        for k in range(s.nframes):
            for ch in range(2):
                cols = slice(20 * ch, 20 * ch + 20)
                pixels = [phys[k][ref_rows][:, cols].ravel()]
                if side_columns and ch == 0:  # the left columns of every active row (4 ... 39)
                    pixels.append(phys[k, 4:40, 0:4].ravel())
                expected = np.concatenate(pixels)
                row = t[(t["frame"] == k) & (t["channel"] == ch)]
                assert row["offset"].value[0] == pytest.approx(expected.mean(), rel=1e-12)
                assert row["n_used"][0] == expected.size
                # the old reading of ref_border=4: rows 36-39 and the right columns too
                every_side = np.concatenate([phys[k][[0, 1, 2, 3, 36, 37, 38, 39]][:, cols]
                                             .ravel(), *pixels[1:]])
                assert abs(row["offset"].value[0] - every_side.mean()) > 100


def test_reference_rows_and_columns_are_where_declared():
    g = DetectorGeometry(40, 40, 2, ref_border={"top": 4, "right": 2})
    assert g.ref_border == RefBorder(top=4, right=2) and g.border == g.ref_border
    assert g.reference_rows.tolist() == [0, 1, 2, 3]
    assert g.active_rows.tolist() == list(range(4, 40)) and g.n_active_rows == 36
    assert np.flatnonzero(g.reference_column_mask()).tolist() == [38, 39]
    bottom = DetectorGeometry(40, 40, 2, ref_border=RefBorder(bottom=3))
    assert bottom.reference_rows.tolist() == [37, 38, 39]
    assert not bottom.reference_column_mask().any()
    # one number is every side, as before; equal sides are that number
    assert DetectorGeometry(40, 40, 2, ref_border=dict.fromkeys(SIDE_LABELS, 4)) == \
        DetectorGeometry(40, 40, 2, ref_border=4)
    assert DetectorGeometry(40, 40, 2, ref_border=4).ref_border == 4


@pytest.mark.parametrize("mode", ["none", "repeated", "distributed"])
def test_schedule_reads_reference_rows_of_the_declared_sides_only(mode):
    top = corner_schedule(ref_mode=mode, ref_reads=6)
    assert set(top.rows[top.is_reference].tolist()) == {0, 1, 2, 3}
    assert sorted(top.rows[~top.is_reference].tolist()) == list(range(4, 40))
    assert top.is_reference.sum() == (4 if mode == "none" else 6)
    bottom = corner_schedule({"bottom": 2}, ref_mode=mode, ref_reads=5)
    assert set(bottom.rows[bottom.is_reference].tolist()) == {38, 39}
    if mode == "repeated":  # every re-read at the one end that has reference rows
        assert bottom.rows[-5:].tolist() == [38, 39, 38, 39, 38]


def test_a_border_without_rows_cannot_have_reference_reads():
    with pytest.raises(ValueError, match=r"ref_border is \{top: 0, bottom: 0, left: 4"):
        corner_schedule({"left": 4}, ref_reads=4)
    assert corner_schedule({"left": 4}, ref_reads=0).is_reference.sum() == 0


@pytest.mark.parametrize(("border", "message"), [
    ({"top": -1}, "ref_border.top must be >= 0, got -1"),
    ({"up": 4}, "ref_border has no side 'up'"),
    ({"top": 1.5}, "ref_border.top must be an integer"),
    ({"top": True}, "ref_border.top must be an integer"),
    ({"top": 20, "bottom": 20}, "leaves no active row or column"),
    ({"left": 40}, "leaves no active row or column"),
])
def test_invalid_sides_are_named(border, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        DetectorGeometry(40, 40, 2, ref_border=border)


# -- FITS --------------------------------------------------------------------------------------
def test_fits_round_trip_of_both_keyword_forms(tmp_path):
    for border, keys in ((CORNER, SIDE_KEYWORDS), (4, ("REFBORD",))):
        s = corner_schedule(border)
        path = tmp_path / f"raw{len(keys)}.fits"
        write(Exposure.from_arrays(corner_ramps(s)[:, s.rows], s), path)
        header = fits.getheader(path)
        assert [k for k in ("REFBORD", *SIDE_KEYWORDS) if k in header] == list(keys)
        if border == CORNER:
            assert [header[k] for k in keys] == [4, 0, 4, 0]
        again = read(path)
        assert again.schedule == s and again.geometry.border == RefBorder.of(border)


def test_a_header_written_over_another_keeps_one_form():
    sides = corner_schedule().to_header()
    h = corner_schedule(4).to_header(sides)
    assert h["REFBORD"] == 4 and not any(k in h for k in SIDE_KEYWORDS)
    back = corner_schedule().to_header(h)
    assert "REFBORD" not in back
    assert [back[k] for k in SIDE_KEYWORDS] == [4, 0, 4, 0]


def test_old_single_refbord_header_reads_unchanged():
    s = corner_schedule(4)
    h = fits.Header([(k, v) for k, v in s.to_header().items()])
    assert "REFBORD" in h and not any(k in h for k in SIDE_KEYWORDS)
    again = ReadoutSchedule.from_header(h, s.to_table())
    assert again == s and again.geometry.ref_border == 4
    assert again.to_header() == s.to_header()


def test_side_keywords_left_out_are_zero_and_agreeing_forms_are_read():
    h = corner_schedule().to_header()
    del h["REFBBOT"], h["REFBRIGH"]
    assert ReadoutSchedule.from_header(h).geometry.border == RefBorder(top=4, left=4)
    h = corner_schedule(4).to_header()
    h["REFBTOP"] = 4  # both forms, agreeing
    assert ReadoutSchedule.from_header(h).geometry.ref_border == 4


@pytest.mark.parametrize(("cards", "names"), [
    ({"REFBORD": 4, "REFBBOT": 0}, ("REFBORD=4", "REFBBOT=0")),
    ({"REFBORD": 2, "REFBTOP": 4, "REFBLEFT": 4}, ("REFBORD=2", "REFBTOP=4")),
])
def test_conflicting_forms_are_refused_naming_both(cards, names, tmp_path):
    s = corner_schedule(4)
    path = tmp_path / "raw.fits"
    write(Exposure.from_arrays(corner_ramps(s)[:, s.rows], s), path)
    with fits.open(path) as hdul:
        for key, value in cards.items():
            hdul[0].header[key] = value
        for hdu in hdul:
            hdu.header.remove("CHECKSUM", ignore_missing=True)
            hdu.header.remove("DATASUM", ignore_missing=True)
        hdul.writeto(tmp_path / "both.fits")
    with pytest.raises(FormatError) as info:
        read(tmp_path / "both.fits")
    message = str(info.value)
    assert "\n" not in message and all(n in message for n in names) and "disagree" in message


def test_a_side_keyword_below_zero_is_refused_by_name():
    h = corner_schedule().to_header()
    h["REFBLEFT"] = -2
    with pytest.raises(FormatError, match="keyword REFBLEFT must be >= 0"):
        ReadoutSchedule.from_header(h)


def test_reference_layout_assumed_from_the_default_is_a_warning(caplog):
    s = corner_schedule(4)
    h = s.to_header()
    del h["REFBORD"]
    with caplog.at_level(logging.WARNING, logger="spherex_reduce"):
        again = ReadoutSchedule.from_header(h)
    assert again.geometry.ref_border == 4
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "REFBORD" in warned[0].getMessage()
    assert warned[0].name.startswith("spherex_reduce")
    caplog.clear()
    del h["TFRAME"]  # FRMOVH gives the frame time of the other read count
    with caplog.at_level(logging.WARNING, logger="spherex_reduce"):  # supplied: no warning
        assert ReadoutSchedule.from_header(h, ref_border=CORNER).geometry.border == \
            RefBorder(**CORNER)
        ReadoutSchedule.from_header(s.to_header())  # in the file: no warning
    assert not caplog.records


def test_pipeline_config_supplies_the_per_side_border_of_a_bare_file(tmp_path):
    s = corner_schedule()
    path = tmp_path / "raw.fits"
    write(Exposure.from_arrays(corner_ramps(s)[:, s.rows], s), path)
    with fits.open(path) as hdul:
        for key in SIDE_KEYWORDS:
            del hdul[0].header[key]
        for hdu in hdul:
            hdu.header.remove("CHECKSUM", ignore_missing=True)
            hdu.header.remove("DATASUM", ignore_missing=True)
        hdul.writeto(tmp_path / "bare.fits")
    pipe = Pipeline({"geometry": {"ref_border": CORNER}, "steps": ["fit_ramp"]})
    assert pipe.read(tmp_path / "bare.fits").schedule == s


# -- YAML and the command line -----------------------------------------------------------------
def test_yaml_mapping_and_number_forms():
    text = ("geometry: {nrows: 40, ncols: 40, nchannels: 2, ref_border: {top: 4, left: 4}}\n"
            "readout: {skip: 3, ref_reads: 8, phantom_reads: 0, nframes: 3}\n")
    config, _ = load_yaml(text, "scene")
    s = schedule_from_config(config["geometry"], config["readout"])
    assert s == corner_schedule()
    assert s.geometry.to_dict()["ref_border"] == {"top": 4, "bottom": 0, "left": 4, "right": 0}
    dumped = yaml.safe_dump({"geometry": s.geometry.to_dict(), "readout": s.to_dict()})
    again, _ = load_yaml(dumped, "scene")
    assert schedule_from_config(again["geometry"], again["readout"]) == s
    number, _ = load_yaml(text.replace("{top: 4, left: 4}", "4"), "scene")
    assert schedule_from_config(number["geometry"], number["readout"]) == corner_schedule(4)
    assert yaml.safe_dump(corner_schedule(4).geometry.to_dict()).count("ref_border: 4") == 1


@pytest.mark.parametrize(("value", "message"), [
    ("{top: -1}", "ref_border.top must be >= 0, got -1"),
    ("{up: 4}", "ref_border has no side 'up'"),
    ("{top: 40}", "leaves no active row"),
    ("[4, 4]", "geometry.ref_border: expected integer or mapping"),
    ("true", "geometry.ref_border: expected integer or mapping"),
])
def test_yaml_refuses_bad_sides_by_name(value, message):
    config, _ = load_yaml(f"geometry: {{nrows: 40, ncols: 40, nchannels: 2, ref_border: {value}}}",
                          "scene")
    with pytest.raises(ConfigError, match=message):
        schedule_from_config(config["geometry"], {"ref_reads": 0})


def test_readout_command_takes_sides(tmp_path, capsys):
    out = tmp_path / "s.ecsv"
    assert main(["readout", "--nrows", "40", "--ncols", "40", "--nchannels", "2",
                 "--ref-border", "top=4,left=4", "--skip", "3", "--ref-reads", "8",
                 "-o", str(out)]) == 0
    t = Table.read(out, format="ascii.ecsv")
    assert set(t["row"][t["kind"] == "reference"]) == {0, 1, 2, 3}
    capsys.readouterr()
    for bad in ("top=4,up=1", "top=x", "top=4,top=2", "top=-1"):
        assert main(["readout", "--ref-border", bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "argument --ref-border" in err
    assert not list(tmp_path.glob(".*tmp"))


# -- the simulator -----------------------------------------------------------------------------
def test_simulator_puts_reference_pixels_where_declared():
    scene = {"geometry": {"nrows": 12, "ncols": 12, "nchannels": 2,
                          "ref_border": {"top": 2, "left": 3}},
             "readout": {"nframes": 3, "skip": 1, "ref_reads": 4, "row_overhead": 10},
             "noise": {"components": []},
             "scene": {"photocurrent": 5.0, "poisson": False}, "output": {"mode": "ramps"}}
    e = unchop(simulate(scene, seed=1))
    signal = e.data.data[-1] - e.data.data[0]
    expected = np.ones((12, 12), bool)
    expected[:2], expected[:, :3] = False, False  # reference pixels see no light
    assert (signal[expected] > 0.1).all()
    np.testing.assert_array_equal(signal[~expected], 0.0)


def test_border_column_stream_uses_the_declared_side_columns_only():
    s = corner_schedule({"top": 2, "left": 3, "right": 1}, ref_reads=0, ref_mode="none",
                        nframes=4)
    rng = np.random.default_rng(5)
    raw = rng.normal(0, 1, (4, s.n_reads, 40))
    stream = reference_timestream(Exposure.from_arrays(raw, s), "columns")
    assert stream.values.shape == (2, 4, s.n_reads) and stream.nbox == 1
    for values, column in zip(stream.values, (0, 39), strict=True):  # one column each side
        v = raw[:, :, column]
        t = np.arange(4) - 1.5
        fit = v.mean(axis=0) + t[:, None] * (t @ v / (t @ t))
        np.testing.assert_allclose(values, (v - fit) * np.sqrt(2), atol=1e-12)
    left = corner_schedule({"top": 2, "left": 3}, ref_reads=0, ref_mode="none", nframes=4)
    one = reference_timestream(Exposure.from_arrays(raw, left), "columns")
    assert one.values.shape == (1, 4, left.n_reads) and one.nbox == 3
