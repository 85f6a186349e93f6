"""The batch summary: rows merged by output, never a valid output reported as failed."""

import math

import pytest
from astropy.table import Table

from spherex_reduce.reduce.batch_summary import SummaryFile, SummaryRow, read_rows
from spherex_reduce.reduce.pipeline import as_pipeline


def row(out, name, status, median=1.0):
    return SummaryRow(f"raw/{name}.fits", str(out / f"{name}_reduced.fits"), status,
                      median=median, robust_std=0.5,
                      unit="" if status == "failed" else "electron / s", seconds=1.0,
                      error="broken" if status == "failed" else "")


@pytest.fixture
def out(tmp_path):
    for name in ("a", "b", "c"):
        (tmp_path / f"{name}_reduced.fits").write_bytes(b"")
    return tmp_path


def statuses(path):
    t = Table.read(path, format="ascii.ecsv")
    return [(str(i), str(s)) for i, s in zip(t["input"], t["status"], strict=True)]


def test_a_batch_keeps_the_valid_rows_of_another(out):
    pipeline = as_pipeline("spherex-default")
    first, second = (SummaryFile(out / "summary.ecsv", pipeline) for _ in range(2))
    first.record([row(out, "a", "done"), row(out, "b", "done"), row(out, "x", "failed")])
    # the other batch: c done, a failed (a valid output: not reported so), b done again
    second.record([row(out, "c", "done"), row(out, "a", "failed"),
                   row(out, "b", "skipped", 2.0)])
    assert statuses(out / "summary.ecsv") == [
        ("raw/c.fits", "done"), ("raw/a.fits", "done"), ("raw/b.fits", "skipped")]
    # the first batch records again: its failed x stays, c (valid, another's) too
    first.record([row(out, "a", "done"), row(out, "b", "done"), row(out, "x", "failed")])
    assert statuses(out / "summary.ecsv") == [
        ("raw/a.fits", "done"), ("raw/b.fits", "done"), ("raw/x.fits", "failed"),
        ("raw/c.fits", "done")]


def test_rows_of_outputs_since_removed_or_of_another_config_are_dropped(out):
    SummaryFile(out / "summary.ecsv", as_pipeline("spherex-default")).record(
        [row(out, "a", "done"), row(out, "b", "done"), row(out, "x", "failed")])
    (out / "b_reduced.fits").unlink()
    SummaryFile(out / "summary.ecsv", as_pipeline("spherex-default")).record(
        [row(out, "c", "done")])
    assert statuses(out / "summary.ecsv") == [("raw/c.fits", "done"), ("raw/a.fits", "done")]
    other = as_pipeline({"steps": [{"fit_ramp": {}}]})
    SummaryFile(out / "summary.ecsv", other).record([row(out, "b", "failed")])
    assert statuses(out / "summary.ecsv") == [("raw/b.fits", "failed")]


def test_rows_read_back_as_written(out):
    pipeline = as_pipeline("spherex-default")
    SummaryFile(out / "summary.ecsv", pipeline).record(
        [row(out, "a", "done", 3.25), row(out, "x", "failed")])
    got = read_rows(out / "summary.ecsv", pipeline.config_hash)
    assert [r.status for r in got] == ["done", "failed"]
    assert got[0].median == 3.25 and got[0].unit == "electron / s"
    assert got[1].error == "broken" and math.isnan(got[1].median) is False
    assert got[0] == row(out, "a", "done", 3.25)  # every column as written
    assert read_rows(out / "summary.ecsv", "another hash") == []
    (out / "summary.ecsv").write_text("not a table\n")
    assert read_rows(out / "summary.ecsv", pipeline.config_hash) == []
