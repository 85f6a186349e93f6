"""Files of each channel layout, read, reduced and written: slopes against numpy.

Each test writes a small ramp (16 x 16, 5 reads) as a lab would store it: a known
slope per pixel, noise, and an offset per read and channel that the channel's
reference pixels carry too.  The expected slopes are computed here: the offset
taken out with the mean of the pixels the test knows are that channel's reference
rows, then ``np.polyfit`` per pixel.
"""

import hashlib

import numpy as np
import pytest
import yaml
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.cli import main
from spherex_reduce.io import FrameReader

N, NREADS, BORDER, TFRAME = 16, 5, 2, 2.0
READOUT = {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0,
           "nframes": NREADS, "frame_time": TFRAME}
GEOMETRY = {
    "columns": {"nchannels": 2},
    "rows": {"nchannels": 2, "channels": "rows"},
    "quadrants": {"nchannels": 4, "channels": "quadrants", "first_corner": "outer",
                  "fast_axis": "rows"},
}


def _channels_by_hand(layout):
    """Channel of every stored pixel, and the stored reference rows of each channel."""
    chan = np.empty((N, N), int)
    rows_of = {}
    b = BORDER
    if layout == "columns":  # stripes of 8 columns; reference rows top and bottom
        chan[:] = np.arange(N) // 8
        ref = [(r, c) for r in [*range(b), *range(N - b, N)] for c in range(N)]
    elif layout == "rows":  # bands of 8 rows; the frame's rows are the stored columns
        chan[:] = (np.arange(N) // 8)[:, None]
        ref = [(r, c) for r in range(N) for c in [*range(b), *range(N - b, N)]]
    else:  # quadrants from the outer corner: the outer rows of each quadrant
        chan[:] = (np.arange(N) // 8)[:, None] * 2 + (np.arange(N) // 8)[None, :]
        ref = [(r, c) for r in [*range(b), *range(N - b, N)] for c in range(N)]
    for r, c in ref:
        rows_of.setdefault(chan[r, c], []).append((r, c))
    return chan, rows_of


def _lab_file(path, layout, seed=3):
    rng = np.random.default_rng(seed)
    t = TFRAME * np.arange(NREADS)
    chan, _ = _channels_by_hand(layout)
    border = np.zeros((N, N), bool)
    border[:BORDER], border[-BORDER:], border[:, :BORDER], border[:, -BORDER:] = (True,) * 4
    offset = rng.normal(0, 50, (NREADS, chan.max() + 1))
    slope = rng.uniform(1, 5, (N, N))
    data = 1000 + slope * t[:, None, None] + rng.normal(0, 1, (NREADS, N, N)) + offset[:, chan]
    data[:, border] = (1000 + offset[:, chan])[:, border]  # reference pixels: offsets alone
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI")]).writeto(path)
    return data, border


def _expected_slopes(data, layout):
    chan, rows_of = _channels_by_hand(layout)
    corrected = data.copy()
    for c, pixels in rows_of.items():
        r, col = np.array(pixels).T
        corrected[:, chan == c] -= data[:, r, col].mean(axis=1)[:, None]
    t = TFRAME * np.arange(NREADS)
    return np.array([[np.polyfit(t, corrected[:, i, j], 1)[0] for j in range(N)]
                     for i in range(N)])


def _config(layout):
    return {"geometry": {"nrows": N, "ncols": N, "pixel_rate": 1e5, "ref_border": BORDER,
                         **GEOMETRY[layout]},
            "readout": READOUT,
            "steps": ["unchop", {"correct_reference": {"strategy": "mean"}}, "fit_ramp"]}


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("layout", list(GEOMETRY))
def test_each_layout_reduces_to_the_numpy_slopes_in_the_stored_orientation(tmp_path, layout):
    raw = tmp_path / "raw.fits"
    data, border = _lab_file(raw, layout)
    before = _digest(raw)
    reduced = sr.Pipeline(_config(layout)).run(raw)
    out = sr.write(reduced, tmp_path / "slopes.fits")
    assert _digest(raw) == before
    got = fits.getdata(out, "SCI")
    assert got.shape == (N, N)
    expected = _expected_slopes(data, layout)
    assert np.allclose(got[~border], expected[~border], rtol=2**-23, atol=1e-9)
    header = fits.getheader(out)
    assert header.get("CHANLAY", "columns") == layout
    again = sr.read(out)  # read back: the readout frame, mapped once more
    assert np.array_equal(again.geometry.layout.to_stored(again.data.data), got)


@pytest.mark.parametrize("layout", ["rows", "quadrants"])
def test_bands_of_the_readout_frame_read_from_the_stored_file(tmp_path, layout):
    raw = tmp_path / "raw.fits"
    data, _ = _lab_file(raw, layout)
    supplied = {k: v for k, v in {**_config(layout)["geometry"], **READOUT}.items()}
    whole = sr.read(raw, **supplied)
    with FrameReader(raw, **supplied) as reader:
        g = reader.schedule.geometry
        assert reader.readable_in_bands()
        for k in (0, NREADS - 1):
            for first, stop in [(0, 3), (3, g.nrows)]:
                assert np.array_equal(reader.reads(k, first, stop),
                                      whole.data.data[k, first:stop])
        assert np.array_equal(g.layout.to_stored(reader.frame(2).data.data[0]), data[2])


@pytest.mark.parametrize("layout", ["rows", "quadrants"])
def test_header_keywords_round_trip_and_old_files_read_as_columns(tmp_path, layout):
    g = DetectorGeometry(N, N, ref_border=BORDER, preset=None, **GEOMETRY[layout])
    s = ReadoutSchedule(g, **READOUT)
    h = s.to_header()
    assert h["CHANLAY"] == layout and not {"GEOPRSET", "FIRSTCRN", "FASTAXIS"} & set(h)
    back = ReadoutSchedule.from_header(h, s.to_table())
    assert back == s and back.geometry.layout == g.layout
    inner = DetectorGeometry(N, N, 4, BORDER, channels="quadrants", first_corner="inner",
                             fast_axis="columns")
    h = ReadoutSchedule(inner, **READOUT).to_header()
    assert (h["FIRSTCRN"], h["FASTAXIS"]) == ("inner", "columns")
    assert ReadoutSchedule.from_header(h).geometry.layout == inner.layout
    wfc3 = ReadoutSchedule(DetectorGeometry.from_preset("WFC3-IR"),
                           **{**READOUT, "frame_time": 2.93})  # handbook 7.7.2
    preset = wfc3.to_header()
    assert (preset["GEOPRSET"], preset["CHANLAY"], preset["NROWS"], preset["REFBORD"]) == (
        "WFC3-IR", "quadrants", 1024, 5)
    old = ReadoutSchedule(DetectorGeometry(N, N, 2, ref_border=BORDER), **READOUT).to_header()
    assert not {"CHANLAY", "FIRSTCRN", "FASTAXIS", "GEOPRSET"} & set(old)
    assert ReadoutSchedule.from_header(old).geometry.layout.identity


def test_preset_in_a_config_overridden_by_the_keys_given(tmp_path):
    config = {"geometry": {"preset": "WFC3-IR", "nrows": N, "ncols": N, "ref_border": BORDER,
                           "pixel_rate": 1e5},  # the preset leaves it to the user
              "readout": READOUT, "steps": ["fit_ramp"]}
    pipeline = sr.Pipeline(config)
    assert pipeline.config["geometry"]["channels"] == "quadrants"
    raw = tmp_path / "raw.fits"
    _lab_file(raw, "quadrants")
    out = sr.write(pipeline.run(raw), tmp_path / "out.fits")
    assert (fits.getheader(out)["GEOPRSET"], fits.getheader(out)["CHANLAY"]) == (
        "WFC3-IR", "quadrants")


@pytest.mark.parametrize(("geometry", "message"), [
    ({"preset": "H5RG"}, "not a known preset"),
    ({"preset": ["H2RG"]}, "not a known preset"),  # was a TypeError, exit 1
    ({"nrows": 15, "ncols": 16, "nchannels": 4, "channels": "quadrants"},
     "even number of rows"),
])
def test_impossible_layout_is_one_line_and_exit_2(tmp_path, capsys, geometry, message):
    raw = tmp_path / "raw.fits"
    _lab_file(raw, "quadrants")
    before = _digest(raw)
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(
        {"geometry": {"nrows": N, "ncols": N, "ref_border": BORDER, "nchannels": 4,
                      "pixel_rate": 1e5, **geometry},
         "readout": READOUT, "steps": ["fit_ramp"]}))
    code = main(["reduce", str(raw), "-c", str(tmp_path / "c.yaml"), "-o",
                 str(tmp_path / "o.fits")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert err.startswith("spherex-reduce reduce: error:")
    assert _digest(raw) == before and not (tmp_path / "o.fits").exists()


def test_chopped_readout_of_a_stored_layout_is_refused(tmp_path):
    raw = tmp_path / "raw.fits"
    _lab_file(raw, "rows")
    supplied = {**_config("rows")["geometry"], **READOUT, "skip": 2}
    with pytest.raises(ValueError, match="read every row once, in order"):
        sr.read(raw, **supplied)


def test_quadrant_side_columns_join_their_own_channels_offsets(tmp_path):
    """Outer-corner quadrants start every channel with reference columns: with
    ``side_columns`` each channel's mean takes its quadrant's border columns too."""
    raw = tmp_path / "raw.fits"
    data, _ = _lab_file(raw, "quadrants")
    config = _config("quadrants")
    config["steps"][1] = {"correct_reference": {"strategy": "mean", "side_columns": True}}
    table = sr.Pipeline(config).run(raw).tables["REFOFFS"]
    rows_by_hand = BORDER * (N // 2)  # the quadrant's outer rows
    columns_by_hand = BORDER * (N // 2 - BORDER)  # its outer columns, active rows only
    assert set(table["n_used"]) == {rows_by_hand + columns_by_hand}
    chan, _ = _channels_by_hand("quadrants")
    for row in table:  # every reference pixel holds 1000 + its read's channel offset
        k, c = int(row["frame"]), int(row["channel"])
        truth = data[k][(chan == c) & (np.abs(np.arange(N) - 7.5) > 7.5 - BORDER)[:, None]]
        assert row["offset"] == pytest.approx(truth.mean(), abs=1e-9)


def test_quadrants_read_along_columns_stream_by_columns_of_the_stored_rows(tmp_path):
    raw = tmp_path / "raw.fits"
    _lab_file(raw, "quadrants")
    supplied = {**_config("quadrants")["geometry"], **READOUT, "fast_axis": "columns"}
    whole = sr.read(raw, **supplied)
    with FrameReader(raw, **supplied) as reader:
        for first, stop in [(0, 2), (5, 8)]:
            assert np.array_equal(reader.reads(1, first, stop), whole.data.data[1, first:stop])


def test_a_dq_of_another_shape_is_one_format_error(tmp_path):
    raw = tmp_path / "raw.fits"
    _lab_file(raw, "rows")
    with fits.open(raw) as hdul:
        hdul.append(fits.ImageHDU(np.zeros((N, N + 2), np.int32), name="DQ"))
        hdul.writeto(tmp_path / "dq.fits")
    with pytest.raises(sr.FormatError, match="DQ: the stored image must be 16 x 16"):
        sr.read(tmp_path / "dq.fits", **{**_config("rows")["geometry"], **READOUT})


@pytest.mark.parametrize(("example", "line"), [
    ("wfc3-ir.yaml", "stored image 1024 x 1024, channels: quadrants read from the outer "
                     "corner along rows; readout frame 512 x 2048"),
    ("nirspec-science.yaml", "stored image 2048 x 2048, channels: rows, read along the "
                             "columns; readout frame 2048 x 2048"),
])
def test_shipped_layout_examples_describe_their_readout(capsys, example, line):
    from _paths import ROOT

    assert main(["readout", "--config", str(ROOT / "data" / "examples" / example)]) == 0
    assert capsys.readouterr().out.splitlines()[1] == line


def test_hst_style_extensions_in_quadrants_reduce_to_numpy_slopes(tmp_path):
    """SCI,i / DQ,i per read, latest first (HST _raw), four quadrants read from their outer
    corners: each quadrant's outer reference rows carry its offsets; a DQ flags one read of
    one pixel, which the fit leaves out."""
    rng = np.random.default_rng(5)
    t = TFRAME * np.arange(NREADS)
    chan, rows_of = _channels_by_hand("quadrants")
    r, _ = np.indices((N, N))
    ref = (r < BORDER) | (r >= N - BORDER)
    offset = rng.normal(0, 40, (NREADS, 4))[:, chan]
    data = np.where(ref, 1000.0, 1000 + rng.uniform(1, 5, (N, N)) * t[:, None, None]
                    + rng.normal(0, 1, (NREADS, N, N))) + offset
    hdus = [fits.PrimaryHDU()]
    for version, k in enumerate(range(NREADS - 1, -1, -1), start=1):
        sci = fits.ImageHDU(data[k], name="SCI", ver=version)
        sci.header["SAMPTIME"] = t[k]
        flags = np.zeros((N, N), np.int16)
        flags[5, 6] = 4 if k == 3 else 0
        hdus += [sci, fits.ImageHDU(flags, name="DQ", ver=version)]
    fits.HDUList(hdus).writeto(tmp_path / "raw.fits")
    config = _config("quadrants")
    config["input"] = {"reads": "extensions"}
    config["readout"] = {k: v for k, v in READOUT.items() if k != "nframes"}
    got = fits.getdata(sr.write(sr.Pipeline(config).run(tmp_path / "raw.fits"),
                                tmp_path / "slopes.fits"), "SCI")
    expected = _expected_slopes(data, "quadrants")
    kept = np.arange(NREADS) != 3
    corrected = data[:, 5, 6] - np.array([data[k][tuple(np.array(rows_of[chan[5, 6]]).T)].mean()
                                          for k in range(NREADS)])
    expected[5, 6] = np.polyfit(t[kept], corrected[kept], 1)[0]
    assert np.allclose(got[~ref], expected[~ref], rtol=2**-23, atol=1e-9)
