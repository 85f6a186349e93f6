"""Regressions found in review: flags of re-read rows, streamed summaries, CLI input checks."""

import warnings

import numpy as np
import pytest
from _one_by_one import one_by_one

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    Pipeline,
    ReadoutSchedule,
    correct_reference,
    dq,
    read,
    unchop,
    write,
)
from spherex_reduce.cli import main
from spherex_reduce.io.examples import example_raw_exposure, tiny_schedule


def test_rereads_average_only_usable_reads():
    g = DetectorGeometry(8, 4, 1, ref_border=1)
    s = ReadoutSchedule(g, skip=1, ref_reads=4, ref_mode="repeated", phantom_reads=0,
                        nframes=1)
    data = np.ones((s.n_reads, 4))
    flags = np.zeros(data.shape, np.uint16)
    reads_of_row0 = np.flatnonzero(s.rows == 0)
    assert reads_of_row0.size == 2
    data[reads_of_row0[0]] = [np.nan, 1e4, 3.0, 3.0]
    flags[reads_of_row0[0], 1] = dq.SATURATED
    flags[reads_of_row0, 2:] = dq.DO_NOT_USE  # both reads flagged: the row is flagged there
    out = unchop(Exposure.from_arrays(data, s, mask=flags))
    # column 0: the NaN read is not usable, column 1: the flagged read is not
    np.testing.assert_array_equal(out.data.data[0, :2], [1.0, 1.0])
    assert np.isnan(out.data.data[0, 2:]).all()
    assert out.dq[0].tolist() == [0, 0, dq.DO_NOT_USE, dq.DO_NOT_USE]
    pos = out.reference.reads.tolist().index(reads_of_row0[0])
    np.testing.assert_array_equal(out.reference.dq[pos], flags[reads_of_row0[0]])


def test_flagged_reference_pixels_stay_unused_after_unchop():
    g = DetectorGeometry(16, 8, 2, ref_border=2)
    s = ReadoutSchedule(g, skip=3, ref_reads=4, phantom_reads=0, nframes=1)
    data = np.zeros((s.n_reads, 8))
    flags = np.zeros(data.shape, np.uint16)
    bad = s.reference_read_indices[0]
    data[bad, 1] = 50.0
    flags[bad, 1] = dq.DO_NOT_USE
    e = Exposure.from_arrays(data, s, mask=flags)
    readout = correct_reference(e, "mean", sigma=100.0)
    physical = correct_reference(unchop(e), "mean", sigma=100.0)
    np.testing.assert_allclose(readout.tables["REFOFFS"]["offset"], 0.0)
    np.testing.assert_allclose(physical.tables["REFOFFS"]["offset"], 0.0)


def test_streamed_summary_keywords_cover_every_frame():
    s = tiny_schedule(nframes=4)
    raw = example_raw_exposure(s, seed=3)
    flags = np.zeros(raw.shape, np.uint16)
    for f in (0, 1):
        flags[f][np.ix_(s.reference_read_indices, np.arange(16))] = dq.DO_NOT_USE
    raw = raw.replace(dq=flags)
    cfg = {"steps": ["unchop", "subtract_phantom", "correct_reference", "fit_ramp"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no usable reference pixels", tested elsewhere
        streamed = Pipeline(cfg).run(raw)
        in_memory = one_by_one(cfg, raw)
    assert streamed.header["NNOREF"] == in_memory.header["NNOREF"] == 2


def test_source_masking_runs_on_the_whole_exposure(tmp_path):
    """The median strategy estimates from every pixel (and masks sources on the last minus
    the first frame): it cannot run in a streamed pass; the reference strategies can."""
    raw = example_raw_exposure(tiny_schedule(nframes=3), seed=2)
    path = write(raw, tmp_path / "raw.fits")

    def routes(steps):
        out = Pipeline({"steps": steps}).run(path)
        return [(row["step"], row["route"]) for row in out.tables["PROVENANCE"]]

    masked = routes(["unchop", {"correct_reference": {"strategy": "median",
                                                      "mask_sources": True}}, "fit_ramp"])
    assert "from a file" in masked[0][1] and "1 step" in masked[0][1]
    assert all("from memory" in route for _, route in masked[1:])
    mean = routes(["unchop", {"correct_reference": {"strategy": "mean"}}, "fit_ramp"])
    assert all("pass of 3 step(s)" in route and "from a file" in route for _, route in mean)


def test_streamed_file_keeps_its_tables(tmp_path):
    from astropy.table import Table

    s = tiny_schedule(nframes=3)
    raw = example_raw_exposure(s, seed=1).replace(tables={"NOTES": Table({"x": [1, 2]})})
    path = write(raw, tmp_path / "raw.fits")
    out = Pipeline({"steps": ["unchop", "fit_ramp"]}).run(path)
    assert "NOTES" in out.tables and out.tables["NOTES"]["x"].tolist() == [1, 2]
    assert read(path).tables["NOTES"]["x"].tolist() == [1, 2]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "{scene}", "--seed", "-1", "-o", "a.fits"], "non-negative"),
        (["demo", "-o", "d", "--size", "64", "--nframes", "1"], "--nframes must be >= 2"),
        (["spectrum", "{image}", "-o", "s.ecsv", "--pixel-scale", "0"], "--pixel-scale"),
        (["spectrum", "{image}", "-o", "s.ecsv", "--integration-time", "0"],
         "--integration-time"),
        (["spectrum", "{image}", "-o", "s.ecsv", "--photocurrent", "-1"], "--photocurrent"),
    ],
)
def test_cli_rejects_bad_numbers(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    scene = tmp_path / "scene.txt"  # not .yaml: read as a file all the same
    scene.write_text("geometry: {nrows: 64, ncols: 64, nchannels: 1}\nreadout: {nframes: 3}\n")
    image = tmp_path / "img.fits"
    if "{image}" in args:
        assert main(["-q", "simulate", str(scene), "-o", str(image)]) == 0
    argv = [a.format(scene=scene, image=image) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_pair_difference_reads_a_foreign_second_file_with_the_config_sections(tmp_path):
    # both files of the pair lack the read-order keywords; the config's geometry:/readout:
    # sections must serve the second one too (it failed with "supply them in the config")
    from astropy.io import fits

    from spherex_reduce import (
        DetectorGeometry,
        Pipeline,
        ReadoutSchedule,
        fit_ramp,
        pair_difference,
        subtract_phantom,
        unchop,
    )
    from spherex_reduce.io.examples import example_raw_exposure

    s = ReadoutSchedule(DetectorGeometry(32, 16, 2, ref_border=2), skip=5, ref_reads=6,
                        ref_mode="distributed", phantom_reads=3, row_overhead=2,
                        frame_overhead=50, nframes=4)
    raws = [example_raw_exposure(s, seed=seed) for seed in (1, 2)]
    paths = []
    for k, raw in enumerate(raws):
        paths.append(tmp_path / f"foreign{k}.fits")
        fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.asarray(raw.data.data), name="SCI"),
                      fits.ImageHDU(raw.phantom, name="PHANTOM")]).writeto(paths[-1])
    config = {
        "geometry": {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 2,
                     "pixel_rate": 100000},
        "readout": {"skip": 5, "ref_reads": 6, "ref_mode": "distributed", "phantom_reads": 3,
                    "row_overhead": 2, "frame_overhead": 50, "nframes": 4},
        "steps": [{"unchop": {}}, {"subtract_phantom": {}}, {"fit_ramp": {}},
                  {"pair_difference": {"other": str(paths[1])}}],
    }
    out = Pipeline(config).run(paths[0])
    expected = pair_difference(*[fit_ramp(subtract_phantom(unchop(r))) for r in raws])
    np.testing.assert_allclose(out.data.data, expected.data.data, rtol=1e-5, atol=1e-3)
    # and when the second file is already at the same stage (read, not reduced)
    config["steps"][-1]["pair_difference"]["reduce_other"] = False
    config["steps"] = config["steps"][-1:]
    out = Pipeline(config).run(paths[0])
    assert out.header["S_PAIRDF"] == "COMPLETE"
