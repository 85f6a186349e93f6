"""``reduce A.fits B.fits ... -o OUTDIR``: each file reduced on dask exactly as alone, a summary."""


from dataclasses import replace

import numpy as np
import pytest
from _cli_helpers import digest, one_line_error, run
from astropy.stats import mad_std
from astropy.table import Table

from spherex_reduce import read, write
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.reduce import batch


@pytest.fixture
def raws(tmp_path, small_schedule):
    """Two raw ramps and a truncated one (its second half cut off)."""
    d = tmp_path / "raw"
    d.mkdir()
    for seed, name in enumerate(("a", "b", "broken")):
        write(example_raw_exposure(small_schedule, seed=seed), d / f"{name}.fits")
    data = (d / "broken.fits").read_bytes()
    (d / "broken.fits").write_bytes(data[:len(data) // 2])
    return [d / "a.fits", d / "b.fits", d / "broken.fits"]


def good_pixels(exposure):
    """Finite, unflagged light-sensitive pixels: the reference border cut off by hand."""
    b = exposure.geometry.border
    rows, cols = exposure.data.data.shape
    values = exposure.data.data[b.top:rows - b.bottom, b.left:cols - b.right]
    flags = exposure.dq[b.top:rows - b.bottom, b.left:cols - b.right]
    return values[np.isfinite(values) & (flags == 0)]


@pytest.mark.slow
def test_two_workers_give_each_file_its_single_reduce(tmp_path, raws, capsys):
    before = {p: digest(p) for p in raws}
    out = tmp_path / "out"  # created
    assert run("-q", "reduce", *raws, "-c", "spherex-default", "-o", out, "--workers", 2) == 2
    one_line_error(capsys, "broken.fits is truncated")
    for raw in raws[:2]:  # the same file reduced alone, as the command always did
        alone = tmp_path / f"alone-{raw.name}"
        assert run("-q", "reduce", raw, "-c", "spherex-default", "-o", alone) == 0
        ref, got = read(alone), read(out / f"{raw.stem}_reduced.fits")
        assert np.array_equal(got.data.data, ref.data.data, equal_nan=True)
        assert np.array_equal(got.data.uncertainty.array, ref.data.uncertainty.array,
                              equal_nan=True)
        assert np.array_equal(got.dq, ref.dq)
        assert got.header["SXRCONF"] == ref.header["SXRCONF"]
    assert {p: digest(p) for p in raws} == before  # inputs never written
    assert sorted(p.name for p in out.iterdir()) == ["a_reduced.fits", "b_reduced.fits",
                                                     "summary.ecsv"]
    t = Table.read(out / "summary.ecsv")
    assert list(t["status"]) == ["done", "done", "failed"]
    assert list(t["input"]) == [str(p) for p in raws]
    assert t["output"][0] == str(out / "a_reduced.fits")
    assert "truncated" in t["error"][2] and np.ma.is_masked(t["error"][0])  # "" in the file
    for i, raw in enumerate(raws[:2]):  # against the output's pixels, computed here
        good = good_pixels(read(out / f"{raw.stem}_reduced.fits")).astype(np.float64)
        assert t["median"][i] == pytest.approx(np.median(good), rel=1e-12)
        assert t["robust_std"][i] == pytest.approx(mad_std(good), rel=1e-12)
    assert str(t["median"].unit) == "electron / s" and str(t["seconds"].unit) == "s"
    assert np.all(t["seconds"][:2] > 0) and np.isnan(t["median"][2])

    # a re-run skips what is done (the outputs untouched) and tries the broken file again
    done = {p: (digest(p), p.stat().st_mtime_ns) for p in out.glob("*.fits")}
    assert run("-q", "reduce", *raws, "-c", "spherex-default", "-o", out,
               "--scheduler", "serial") == 2
    captured = capsys.readouterr()
    assert "0 reduced, 2 already done, 1 failed" in captured.out
    assert len(captured.err.strip().splitlines()) == 1
    assert {p: (digest(p), p.stat().st_mtime_ns) for p in out.glob("*.fits")} == done
    again = Table.read(out / "summary.ecsv")
    assert list(again["status"]) == ["skipped", "skipped", "failed"]
    assert np.array_equal(again["median"][:2], t["median"][:2])
    # --overwrite reduces them again, to the same numbers
    assert run("-q", "reduce", *raws[:2], "-c", "spherex-default", "-o", out,
               "--scheduler", "serial", "--overwrite") == 0
    assert list(Table.read(out / "summary.ecsv")["status"]) == ["done", "done"]
    assert {p: digest(p) for p in raws} == before


def test_an_output_of_another_config_is_refused_before_any_work(tmp_path, raws, capsys):
    out = tmp_path / "out"
    cfg = tmp_path / "unchop.yaml"
    cfg.write_text("steps:\n  - unchop: {}\n")
    assert run("-q", "reduce", *raws[:2], "-c", cfg, "-o", out, "--scheduler", "serial") == 0
    capsys.readouterr()
    first = {p.name: digest(p) for p in out.iterdir()}
    # the same directory with another config: refused, nothing reduced or rewritten
    assert run("-q", "reduce", *raws[:2], "-c", "spherex-default", "-o", out,
               "--scheduler", "serial") == 2
    one_line_error(capsys, "a_reduced.fits exists and was made with another pipeline config",
                   "--overwrite")
    assert {p.name: digest(p) for p in out.iterdir()} == first
    # a 3-D output (no fit_ramp) is summarised too: its unit is the ramps'
    t = Table.read(out / "summary.ecsv")
    assert list(t["status"]) == ["done", "done"] and str(t["median"].unit) == "electron"


def test_an_unexpected_failure_is_status_1_and_the_others_finish(tmp_path, raws, capsys,
                                                                monkeypatch):
    real = batch.write

    def fail_b(result, path, overwrite=False, images=None):
        if "b_reduced" in str(path):
            raise RuntimeError("a bug")
        return real(result, path, overwrite=overwrite, images=images)

    monkeypatch.setattr(batch, "write", fail_b)
    out = tmp_path / "out"
    assert run("-q", "reduce", *raws[:2], "-c", "spherex-default", "-o", out,
               "--scheduler", "serial") == 1
    one_line_error(capsys, "b.fits: RuntimeError: a bug")
    t = Table.read(out / "summary.ecsv")
    assert list(t["status"]) == ["done", "failed"] and t["error"][1] == "RuntimeError: a bug"
    assert sorted(p.name for p in out.iterdir()) == ["a_reduced.fits", "summary.ecsv"]


@pytest.mark.parametrize(("inputs", "options", "message"), [
    ([], ["--workers", "0"], "argument --workers: must be a whole number from 1 to"),
    ([], ["--workers", "2", "--scheduler", "serial"], "not allowed with argument"),
    ([], ["--scheduler", "not a url"], "--scheduler 'not a url': not a dask scheduler address"),
    ([], ["-o", "{file}"], "is a file: with several inputs, -o names a directory"),
    ([], ["-o", "{missing}/out"], "does not exist"),
    (["{twin}"], [], "would both be reduced to"),
    (["{raw}/a_reduced.fits"], [], "is the input"),
    (["{raw}/nosuch.fits"], [], "no such file"),
    (["{dir}"], [], "is a directory; give the files in it"),
    ([], ["-o", "{taken}"], "a_reduced.fits names a directory; it is the output of"),
])
def test_bad_arguments_exit_2_with_one_line_and_write_nothing(tmp_path, raws, capsys, inputs,
                                                              options, message):
    (tmp_path / "twin").mkdir()
    (tmp_path / "twin" / "a.fits").write_bytes(raws[0].read_bytes())
    (raws[0].parent / "a_reduced.fits").write_bytes(raws[0].read_bytes())
    (tmp_path / "file").write_text("not a directory")
    (tmp_path / "taken" / "a_reduced.fits").mkdir(parents=True)
    names = {"file": tmp_path / "file", "missing": tmp_path / "missing",
             "taken": tmp_path / "taken", "twin": tmp_path / "twin" / "a.fits",
             "dir": tmp_path / "twin", "raw": raws[0].parent}
    inputs = [*raws[:2], *(i.format(**names) for i in inputs)]
    options = [o.format(**names) for o in options]
    out = [] if "-o" in options else ["-o", raws[0].parent]
    before = sorted(p for p in tmp_path.rglob("*"))
    digests = {p: digest(p) for p in before if p.is_file()}
    assert run("-q", "reduce", *inputs, "-c", "spherex-default", *out, *options) == 2
    one_line_error(capsys, message)
    assert sorted(p for p in tmp_path.rglob("*")) == before
    assert {p: digest(p) for p in before if p.is_file()} == digests


def test_output_names():
    names = batch.output_paths(["d/x.fits", "e/y.FITS.gz", "z.fit", "w"], "o")
    assert [p.name for p in names] == ["x_reduced.fits", "y_reduced.fits", "z_reduced.fits",
                                       "w_reduced.fits"]


def test_a_worker_follows_the_checksum_policy_it_is_given(tmp_path, raws):
    """The policy travels with the task (a worker process does not share this one's)."""
    from astropy.io import fits

    damaged = tmp_path / "damaged.fits"
    data = bytearray(raws[0].read_bytes())
    with fits.open(raws[0]) as hdul:
        offset = hdul["SCI"]._data_offset
    data[offset:offset + 4] = np.float32(12345.0).tobytes()[::-1]  # big-endian, another value
    damaged.write_bytes(bytes(data))
    task = batch.BatchTask(str(damaged), str(tmp_path / "out.fits"),
                           {"steps": [{"unchop": {}}]}, "unchop")
    failed = batch.reduce_file(task)
    assert failed.status == "failed" and "checksum" in failed.error
    assert failed.kind == "input" and not (tmp_path / "out.fits").exists()
    done = batch.reduce_file(replace(task, verify_checksum=False))
    assert done.status == "done", done.error
    assert "SCI" in read(tmp_path / "out.fits").header["SXRCKBAD"]
    assert any("checksum" in note for note in done.notes)  # the warning, for the log


def test_warnings_while_reducing_a_file_are_logged_naming_it(tmp_path, raws, monkeypatch,
                                                             caplog):
    import warnings

    real = batch.write

    def warn(result, path, overwrite=False, images=None):
        warnings.warn("something odd", UserWarning, stacklevel=2)
        return real(result, path, overwrite=overwrite, images=images)

    monkeypatch.setattr(batch, "write", warn)
    res = batch.run_batch("unchop", raws[:1], tmp_path / "out", scheduler="serial")
    assert res.count("done") == 1
    assert [r.getMessage() for r in caplog.records] == [f"{raws[0]}: something odd"]


def test_a_worker_follows_the_dq_bits_it_is_given(tmp_path, small_schedule):
    """``--dq-bits`` travels with the task too: a foreign DQ bit 2 masks only when asked."""
    from astropy.io import fits

    raw = example_raw_exposure(small_schedule, seed=3)
    path = write(raw, tmp_path / "ours.fits")
    foreign = tmp_path / "foreign.fits"
    with fits.open(path) as hdul:  # no READOUT table: a file of other software
        hdus = [h.copy() for h in hdul if h.name != "READOUT"]
        g = small_schedule.geometry
        flags = np.zeros((g.nrows, g.ncols), np.uint16)
        flags[10, 3] = 4  # bit 2 only
        hdus.append(fits.ImageHDU(flags, name="DQ"))
        fits.HDUList(hdus).writeto(foreign)
    task = batch.BatchTask(str(foreign), "", {"steps": ["unchop", "fit_ramp"]}, "test")
    plain = batch.reduce_file(replace(task, output=str(tmp_path / "a.fits"), dq_bits=1))
    masked = batch.reduce_file(replace(task, output=str(tmp_path / "b.fits"), dq_bits=4))
    assert plain.status == masked.status == "done", (plain.error, masked.error)
    assert np.isfinite(read(tmp_path / "a.fits").data.data[10, 3])
    assert np.isnan(read(tmp_path / "b.fits").data.data[10, 3])


def test_the_summary_leaves_reference_pixels_out(tmp_path, small_schedule):
    """Reference pixels are not sky: with extreme values there, the summary's median and
    robust sigma are those of the light-sensitive pixels alone (they included the border)."""
    from astropy import units as u

    from spherex_reduce import Exposure

    g = small_schedule.geometry
    rng = np.random.default_rng(3)
    image = rng.normal(5.0, 1.0, (g.nrows, g.ncols))
    b = g.border
    light = np.zeros(image.shape, bool)
    light[b.top:g.nrows - b.bottom, b.left:g.ncols - b.right] = True
    image[~light] = 1e6  # extreme reference pixels
    reduced = Exposure.from_arrays(image, small_schedule, unit=u.electron / u.s,
                                   order="physical")
    median, sigma = batch.image_statistics(reduced)
    assert median.value == pytest.approx(np.median(image[light]), rel=1e-12)
    assert sigma.value == pytest.approx(mad_std(image[light]), rel=1e-12)
    # an image left in readout order (a pipeline without unchop): each read is its row's
    rows = small_schedule.rows
    readout = Exposure.from_arrays(image[rows], small_schedule, unit=u.electron / u.s)
    median, sigma = batch.image_statistics(readout)
    assert median.value == pytest.approx(np.median(image[rows][light[rows]]), rel=1e-12)
    assert sigma.value == pytest.approx(mad_std(image[rows][light[rows]]), rel=1e-12)
