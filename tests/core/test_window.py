"""A window of a larger array: pixel times against a schedule written out by hand,
reference border, refusals in one line, FITS and YAML round trips."""

import numpy as np
import pytest
import yaml
from astropy import units as u

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError, FormatError
from spherex_reduce.core.window import Window
from spherex_reduce.io.config import schedule_from_config


def hand_schedule(full_rows, ncols, nchannels, scan, border, skip, c, overhead):
    """The full readout written from its definition: ``{row: start sample of its first
    pixel}`` and ``{column: offset in its channel}``, by plain loops.

    Rows: the top reference rows, then the active rows chopped with ``skip`` (rows
    k, k+S, ... for k = 0 ... S-1), then the bottom ones (``ref_mode: none``).  Every row
    read lasts c + channel width + overhead samples, its pixels starting after c.
    """
    top, bottom = border
    active = list(range(top, full_rows - bottom))
    order = list(range(top))
    for k in range(skip):
        order += active[k::skip]
    order += list(range(full_rows - bottom, full_rows))
    width = ncols // nchannels
    length = c + width + overhead
    start = {row: i * length + c for i, row in enumerate(order)}
    offset = {}
    for col in range(ncols):
        channel, j = divmod(col, width)
        reverse = scan == "alternate" and channel % 2 == 1
        offset[col] = width - 1 - j if reverse else j
    return start, offset


def check_times(sched, first_row, first_column, hand):
    start, offset = hand
    g = sched.geometry
    expected = np.empty((sched.n_reads, g.ncols))
    for i, row in enumerate(sched.rows):
        for col in range(g.ncols):
            expected[i, col] = start[first_row + row] + offset[first_column + col]
    assert sched.pixel_samples().tolist() == expected.tolist()
    np.testing.assert_allclose(sched.pixel_times().to_value(u.s), expected / g.pixel_rate,
                               rtol=1e-15)
    assert sorted(sched.rows.tolist()) == list(range(g.nrows))  # every row once


def window_schedule(first_row, first_column, nrows, ncols, full, **readout):
    g = Window(first_row, first_column, full).geometry(nrows, ncols)
    return ReadoutSchedule(g, **{"ref_mode": "none", "nframes": 3, **readout})


def test_corner_inside_channel_0_reads_as_the_full_array_does():
    full = DetectorGeometry(64, 64, 4, ref_border=4, scan="alternate", pixel_rate=1e5)
    s = window_schedule(0, 0, 12, 10, full, skip=3, phantom_reads=2, row_overhead=3,
                        frame_time=0.02)
    check_times(s, 0, 0, hand_schedule(64, 64, 4, "alternate", (4, 4), 3, 2, 3))
    g = s.geometry
    assert (g.nchannels, g.channel_width, g.border.sides()) == (
        1, 10, {"top": 4, "bottom": 0, "left": 4, "right": 0})
    assert s.row_samples == 2 + 16 + 3  # the full channel's row read
    assert s.rows[:4].tolist() == [0, 1, 2, 3] and s.is_reference.sum() == 4


def test_one_output_in_the_middle_of_an_alternate_scan_array():
    full = DetectorGeometry(64, 64, 4, ref_border=4, scan="alternate", pixel_rate=1e5)
    s = window_schedule(0, 16, 64, 16, full, skip=4, phantom_reads=1, row_overhead=2,
                        frame_time=0.02)
    check_times(s, 0, 16, hand_schedule(64, 64, 4, "alternate", (4, 4), 4, 1, 2))
    g = s.geometry
    assert g.scan_directions.tolist() == [-1] and g.column_offsets()[0] == 15
    assert g.border.sides() == {"top": 4, "bottom": 4, "left": 0, "right": 0}
    assert g.reference_pixel_mask().sum() == 8 * 16


def test_a_window_of_two_whole_channels_keeps_both():
    full = DetectorGeometry(32, 64, 4, ref_border=2, scan="alternate", pixel_rate=1e5)
    s = window_schedule(5, 16, 20, 32, full, skip=2, phantom_reads=3, row_overhead=1,
                        frame_time=0.02)
    check_times(s, 5, 16, hand_schedule(32, 64, 4, "alternate", (2, 2), 2, 3, 1))
    g = s.geometry
    assert (g.nchannels, g.scan_directions.tolist(), g.border.rows) == (2, [-1, 1], 0)


def test_frame_time_is_taken_as_given_and_checked_against_the_last_window_read():
    full = DetectorGeometry(64, 64, 4, ref_border=4, pixel_rate=1e5)
    # rows 0-15 read in physical order: the 16th ends 16 x (0 + 16 + 0) = 256 samples in
    s = window_schedule(0, 0, 16, 16, full, skip=1, phantom_reads=0, row_overhead=0,
                        frame_time=256e-5)
    assert s.frame_samples == 256 and s.frame_overhead == 0
    with pytest.raises(ValueError, match=r"frame_time must be >= 0.00256 s, the time to read 16 "
                       r"rows of 16 samples \(phantom_reads \+ pixels \+ row_overhead\)"):
        window_schedule(0, 0, 16, 16, full, skip=1, phantom_reads=0, row_overhead=0,
                        frame_time=255e-5)
    with pytest.raises(ValueError, match=r"a window needs readout\.frame_time"):
        window_schedule(0, 0, 16, 16, full, skip=1)


def test_a_prime_like_output_takes_its_real_frame_time():
    """One 4096 x 128 output of a 4096 x 4096 H4RG with 32 outputs at 200 kHz: the
    frame time is not re-derived from the output alone."""
    full = DetectorGeometry(4096, 4096, 32, ref_border=4, scan="alternate", pixel_rate=2e5)
    s = window_schedule(0, 128 * 5, 4096, 128, full, skip=1, phantom_reads=0,
                        row_overhead=0, nframes=2, frame_time=2.7)
    assert s.frame_time == 2.7 * u.s and s.frame_samples == 540000
    assert s.geometry.scan_directions.tolist() == [-1]
    assert s.pixel_samples()[1, 0] == 128 + 127  # row 1, column 0 read last in its row


def test_frame_overhead_instead_of_frame_time_is_refused_for_a_window():
    """A 64-row window of a 512-row array given ``frame_overhead`` (not the ``frame_time`` the
    docs require) was timed by its own 64 rows: 0.0205 s where the full readout takes
    0.164 s.  Refused, naming frame_time; with ``frame_time`` the frame is the one given,
    at least the full readout to the window's last row; a window schedule's ``to_dict``,
    ``replace`` and FITS keywords carry its frame time (so they never rebuild it from an
    overhead)."""
    full = DetectorGeometry(512, 512, 8, ref_border=4, pixel_rate=1e5)
    readout = {"skip": 1, "phantom_reads": 4, "row_overhead": 4}
    # the full readout by hand: 512 rows of 4 + 64 + 4 samples, then 2000 samples of reset
    tframe = (512 * (4 + 64 + 4) + 2000) / 1e5
    assert np.isclose(tframe, 0.38864)
    message = (r"a window needs readout\.frame_time \(TFRAME\), the full readout's frame time: "
               r"it is taken as given, not derived; frame_overhead=2000 alone would time a "
               r"frame by the window's own rows")
    with pytest.raises(ValueError, match=message):
        window_schedule(0, 0, 64, 64, full, frame_overhead=2000, **readout)
    with pytest.raises(ConfigError, match=r"^geometry/readout: " + message):
        schedule_from_config({"nrows": 64, "ncols": 64, "pixel_rate": 1e5},
                             {**readout, "ref_mode": "none", "frame_overhead": 2000},
                             {"first_row": 0, "first_column": 0, "full_nrows": 512,
                              "full_ncols": 512, "full_nchannels": 8})
    s = window_schedule(0, 0, 64, 64, full, frame_time=tframe, **readout)
    assert s.frame_time == tframe * u.s and s.frame_samples == 38864
    assert s.frame_overhead == 38864 - 64 * 72  # what is left after the window's last row
    assert s.to_dict()["frame_time"] == tframe and "frame_overhead" not in s.to_dict()
    longer = s.replace(nframes=5, row_overhead=0)
    assert longer.frame_time == tframe * u.s and longer.frame_samples == 38864
    h = s.to_header()
    assert ReadoutSchedule.from_header(h, s.to_table()) == s
    del h["TFRAME"]  # FRMOVH alone: the remainder after the window's rows, not a frame time
    with pytest.raises(FormatError, match=r"a window needs readout\.frame_time \(TFRAME\)"):
        ReadoutSchedule.from_header(h)


@pytest.mark.parametrize(("where", "size", "message"), [
    ((0, 60), (16, 16), r"16 x 16 window at row 0, column 60 of the 64 x 64 full array "
                        r"does not fit in it \(rows 0-15, columns 60-75\)"),
    ((60, 0), (16, 16), r"does not fit in it \(rows 60-75"),
    ((0, 8), (16, 16), r"cuts a readout channel: columns 8-23 span full channels 0-1, "
                       r"whose boundaries are every 16 columns \(0, 16, 32, ...\)"),
])
def test_refusals_name_the_window_and_the_channel_boundaries(where, size, message):
    full = DetectorGeometry(64, 64, 4, pixel_rate=1e5)
    with pytest.raises(ValueError, match=message) as info:
        Window(*where, full).geometry(*size)
    assert "\n" not in str(info.value)


def test_header_round_trip_and_the_readout_table():
    full = DetectorGeometry(64, 64, 4, ref_border={"top": 4, "left": 2}, scan="alternate",
                            pixel_rate=1e5)
    s = window_schedule(0, 16, 64, 16, full, skip=4, phantom_reads=1, frame_time=0.02)
    h, table = s.to_header(), s.to_table()
    assert [h[k] for k in ("WINROW", "WINCOL", "FULLROWS", "FULLCOLS", "FULLCHAN",
                           "FULLSCAN", "FULLBTOP", "FULLBLFT", "NCHAN", "SCANDIR")] == [
        0, 16, 64, 64, 4, "alternate", 4, 2, 1, "-"]
    again = ReadoutSchedule.from_header(h, table)
    assert again == s and again.geometry.window == s.geometry.window
    assert again.pixel_samples().tolist() == s.pixel_samples().tolist()
    table["start"][3] += 1
    with pytest.raises(FormatError, match="READOUT column 'start' disagrees"):
        ReadoutSchedule.from_header(h, table)
    h["NCHAN"] = 4  # the full array's, not the window's
    with pytest.raises(FormatError, match="NCHAN/nchannels is 4 but the window gives 1"):
        ReadoutSchedule.from_header(h)
    assert "WINROW" not in ReadoutSchedule().to_header()  # no window: no card


def test_yaml_window_section_and_the_readout_command(tmp_path, capsys):
    config = {"geometry": {"nrows": 16, "ncols": 16, "pixel_rate": 1e5},
              "window": {"first_row": 0, "first_column": 16, "full_nrows": 64,
                         "full_ncols": 64, "full_nchannels": 4, "full_scan": "alternate"},
              "readout": {"frame_time": 0.02, "skip": 4, "ref_mode": "none"}}
    s = schedule_from_config(config["geometry"], config["readout"], config["window"])
    full = DetectorGeometry(64, 64, 4, scan="alternate", pixel_rate=1e5)
    assert s == window_schedule(0, 16, 16, 16, full, skip=4, nframes=74, frame_time=0.02)
    path = tmp_path / "w.yaml"
    path.write_text(yaml.safe_dump(config))
    assert main(["readout", "--config", str(path)]) == 0
    assert ("window 16x16 at row 0, column 16 of a 64x64 array (4 channels of 16 columns, "
            "scan alternate, reference border 4): inside full channel 1") in capsys.readouterr().out
    with pytest.raises(ConfigError, match=r"a window needs readout\.frame_time"):
        schedule_from_config(config["geometry"], {}, config["window"])
    config["window"]["first_column"] = 8
    path.write_text(yaml.safe_dump(config))
    assert main(["readout", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("spherex-reduce readout: error: ") and err.count("\n") == 1
    assert "cuts a readout channel" in err


def test_a_bad_full_array_is_named_as_such():
    values = {"first_row": 0, "first_column": 0, "full_nrows": 64, "full_ncols": 64,
              "full_nchannels": 5}
    with pytest.raises(ValueError, match=r"^the full array \(full_nrows ... full_ref_border\): "
                       "nchannels x channel width must equal ncols"):
        Window.from_fields(values, 1e5)
    with pytest.raises(ValueError, match="a window needs full_ncols"):
        Window.from_fields({k: v for k, v in values.items() if k != "full_ncols"}, 1e5)


def test_the_window_transcript_of_the_readout_docs(capsys):
    from _paths import ROOT

    lines = (ROOT / "docs" / "cli.rst").read_text(encoding="utf-8").splitlines()
    (at,) = [i for i, line in enumerate(lines) if "$ spherex-reduce readout" in line
             and "--first-row" in line]
    argv = lines[at].split("$ spherex-reduce ", 1)[1].split()
    assert main(argv) == 0
    assert capsys.readouterr().out.splitlines() == [x.strip() for x in lines[at + 1:at + 3]]


def test_a_preset_names_the_full_array_a_window_lies_in(tmp_path):
    """``geometry: {preset: H4RG-10}`` with a ``window:``: the preset is the 4096² array of
    32 alternate-scan outputs the window lies in (it used to be ignored by the schedule
    and, in a pipeline, refused as disagreeing with the window's one channel)."""
    geometry = {"preset": "H4RG-10", "nrows": 16, "ncols": 16, "pixel_rate": 2e5}
    window = {"first_row": 0, "first_column": 128 + 100}  # inside output 1, read leftward
    readout = {"frame_time": 3.04, "skip": 1, "ref_mode": "none", "phantom_reads": 0,
               "row_overhead": 0, "nframes": 3}
    s = schedule_from_config(geometry, readout, window)
    check_times(s, 0, 228, hand_schedule(4096, 4096, 32, "alternate", (4, 4), 1, 0, 0))
    assert s.geometry.border.sides() == {"top": 4, "bottom": 0, "left": 0, "right": 0}
    config = {"geometry": geometry, "window": window, "readout": readout,
              "steps": [{"unchop": {}}, {"fit_ramp": {}}]}
    from spherex_reduce import Pipeline
    p = Pipeline(config)
    assert p.supplied()["full_nchannels"] == 32 and "nchannels" not in p.supplied()
    with pytest.raises(ConfigError, match="not a known preset"):
        schedule_from_config({**geometry, "preset": "H5RG"}, readout, window)


def test_a_window_with_another_layout_is_refused_by_every_command(capsys):
    """``readout`` built a window's geometry from five fields and dropped ``channels``
    (and a preset's layout), printing a schedule ``reduce`` refuses; one builder now."""
    readout = {"frame_time": 3.04, "skip": 1, "ref_mode": "none", "nframes": 3}
    window = {"first_row": 0, "first_column": 0, "full_nrows": 64, "full_ncols": 64,
              "full_nchannels": 4}
    for geometry in ({"nrows": 8, "ncols": 8, "pixel_rate": 1e5, "channels": "quadrants"},
                     {"preset": "SIDECAR-science", "nrows": 8, "ncols": 8}):
        with pytest.raises(ConfigError, match="with a window"):
            schedule_from_config(geometry, readout, window)
    argv = ["readout", "--nrows", "8", "--ncols", "8", "--pixel-rate", "1e5", "--skip", "1",
            "--ref-mode", "none", "--nframes", "3", "--frame-time", "3.04", "--first-row", "0",
            "--first-column", "0", "--full-nrows", "64", "--full-ncols", "64",
            "--full-nchannels", "4", "--channels", "quadrants"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "with a window" in err


def test_a_window_without_its_pixel_rate_names_pixrate_and_how_to_give_it(tmp_path, capsys):
    """A window's header without PIXRATE (nor NCHAN, SCANDIR, REFBORD, which its full array
    decides): the error asked for NCHAN and PIXRATE.  Now it names PIXRATE alone and its
    YAML key; given it (from_header's supplied values), the schedule reads back.  The
    command line: one line, exit 2."""
    full = DetectorGeometry(64, 64, 4, scan="alternate", pixel_rate=1e5)
    s = window_schedule(0, 16, 64, 16, full, skip=4, phantom_reads=1, frame_time=0.02)
    h = s.to_header()
    for key in ("PIXRATE", "NCHAN", "SCANDIR", "REFBORD", "REFBTOP", "REFBBOT", "REFBLEFT",
                "REFBRIGH"):
        h.remove(key, ignore_missing=True)
    want = ("missing readout keyword(s) PIXRATE: the file does not say how it was read; "
            "supply them in the pipeline config's geometry:/readout: sections: "
            "geometry.pixel_rate; the window's NCHAN, SCANDIR and REFBORD come from its full "
            "array")
    with pytest.raises(FormatError) as exc:
        ReadoutSchedule.from_header(h)
    assert str(exc.value) == want
    assert ReadoutSchedule.from_header(h, pixel_rate=1e5) == s
    from astropy.io import fits

    fits.HDUList([fits.PrimaryHDU(header=h), fits.ImageHDU(
        np.zeros((3, s.n_reads, 16), np.float32), name="SCI")]).writeto(tmp_path / "w.fits")
    (tmp_path / "c.yaml").write_text("steps: [fit_ramp]\n")
    capsys.readouterr()
    assert main(["reduce", str(tmp_path / "w.fits"), "-c", str(tmp_path / "c.yaml"), "-o",
                 str(tmp_path / "o.fits")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"spherex-reduce reduce: error: {want}"]
    assert not (tmp_path / "o.fits").exists()
