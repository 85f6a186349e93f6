"""Sweeps: the same results serially and on a 2-process dask LocalCluster; failures; resume."""

import numpy as np
import pytest
from astropy.table import Table

from spherex_reduce.analysis.sweep import load_sweep, plot_sweep, run_sweep
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError

SWEEP = {
    "scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
              "readout": {"nframes": 10, "phantom_reads": 2, "ref_reads": 8}},
    "grid": {"skip": [1, 4], "ref_mode": ["repeated", "distributed"]},
    "realizations": 2,
    "seed": 11,
    "measure": {"kmin": 0.1, "kmax": 1.0, "bins": 8},
}


@pytest.fixture(scope="module")
def serial():
    return run_sweep(SWEEP, scheduler="serial")


def test_serial_sweep_table(serial):
    t = serial.table
    assert serial.computed == 8 and not serial.failed and len(t) == 8
    assert t.colnames[:4] == ["skip", "ref_mode", "pipeline", "realization"]
    assert np.all(t["band_power"] > 0) and np.all(t["band_power_err"] > 0)
    assert t["power"].shape == (8, 8)
    # realisations differ; the same cell and seed repeat exactly
    assert t["band_power"][0] != t["band_power"][1]
    again = run_sweep(SWEEP, scheduler="serial")
    assert np.array_equal(again.table["band_power"], t["band_power"])


@pytest.mark.slow
def test_local_cluster_two_processes_matches_serial(serial):
    par = run_sweep(SWEEP, workers=2)  # embedded LocalCluster, processes=True
    assert par.computed == 8 and not par.failed
    for col in ("skip", "ref_mode", "realization", "seed", "band_power", "band_power_err",
                "std"):
        assert list(par.table[col]) == list(serial.table[col]), col
    assert np.array_equal(par.table["power"], serial.table["power"], equal_nan=True)


def test_failed_cell_is_reported_and_others_finish(tmp_path):
    bad = dict(SWEEP, grid={"skip": [4, 0]}, realizations=1)  # skip 0 is invalid
    out = tmp_path / "r.ecsv"
    res = run_sweep(bad, out, scheduler="serial")
    assert res.computed == 1 and len(res.failed) == 1
    assert res.failed[0]["cell"]["skip"] == 0 and "skip" in res.failed[0]["error"]
    t = Table.read(out)
    assert list(t["skip"]) == [4]
    assert t.meta["failed"][0]["cell"]["skip"] == 0
    # a re-run skips the finished cell and tries the failed one again
    res2 = run_sweep(bad, out, scheduler="serial")
    assert res2.skipped == 1 and res2.computed == 0 and len(res2.failed) == 1


def test_rerun_skips_cells_already_in_results(tmp_path):
    out = tmp_path / "r.ecsv"
    small = dict(SWEEP, grid={"skip": [1, 4]}, realizations=1)
    first = run_sweep(small, out, scheduler="serial")
    assert first.computed == 2
    bigger = dict(small, realizations=2)
    second = run_sweep(bigger, out, scheduler="serial")
    assert second.skipped == 2 and second.computed == 2
    t = Table.read(out)
    assert len(t) == 4
    # every column says what it holds, also in a table merged from two runs
    assert all(t[c].description for c in t.colnames if c != "skip"), \
        [c for c in t.colnames if not t[c].description]
    # the resumed rows equal a fresh run's
    fresh = run_sweep(bigger, scheduler="serial").table
    assert np.array_equal(np.asarray(t["band_power"]), np.asarray(fresh["band_power"]))
    fig = plot_sweep(t)
    assert fig.axes[0].get_xlabel() == "skip"
    # the sweep's own band (not the paper's) is named by its k range
    assert fig.axes[0].get_title() == ("band power 0.1 ≤ k ≤ 1 rad/pixel "
                                       "(mean ± s.e. over realisations)")
    # a different scene would not match the rows already there
    other = dict(bigger, seed=99)
    with pytest.raises(ConfigError, match="different scene, seed"):
        run_sweep(other, out, scheduler="serial")
    assert run_sweep(other, out, scheduler="serial", overwrite=True).computed == 4


def test_sweep_validation():
    with pytest.raises(ConfigError, match=r"grid\.colour"):
        load_sweep({"grid": {"colour": [1]}})
    with pytest.raises(ConfigError, match="realizations"):
        load_sweep({"realizations": -1})
    # 0: no Monte Carlo cells, a forecast only (run_sweep refuses it without the forecast)
    assert load_sweep({"realizations": 0}).cells() == []
    with pytest.raises(ConfigError, match="sweep: grids: unknown parameter; valid: scene"):
        load_sweep({"grids": {}})


def test_sweep_cli_serial(tmp_path, capsys):
    import yaml

    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(dict(SWEEP, grid={"skip": [1, 4]}, realizations=1)))
    out = tmp_path / "res.ecsv"
    assert main(["-q", "sweep", str(path), "-o", str(out), "--scheduler", "serial",
                 "--plot"]) == 0
    assert "2 computed" in capsys.readouterr().out
    assert (tmp_path / "res.png").exists() and len(Table.read(out)) == 2
    assert main(["-q", "sweep", str(path), "-o", str(out), "--scheduler", "serial"]) == 0
    assert "0 computed, 2 already" in capsys.readouterr().out


def test_scheduler_that_is_not_dask_is_an_input_error_named_fast():
    """A loopback server that answers garbage (not a dask scheduler): one error, no hang."""
    import socket
    import threading
    import time

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]

    def answer_garbage():  # every connection (the reachability check's, then dask's)
        while True:
            try:
                conn, _ = server.accept()
            except OSError:  # closed at the end of the test
                return
            conn.sendall(b"\xff" * 64)  # read by dask as an absurd message length
            threading.Timer(2, conn.close).start()

    threading.Thread(target=answer_garbage, daemon=True).start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(ConfigError, match=f"scheduler tcp://127.0.0.1:{port}"):
            run_sweep(SWEEP, scheduler=f"tcp://127.0.0.1:{port}")
    finally:
        server.close()
    assert time.perf_counter() - t0 < 15


@pytest.mark.parametrize("workers", [0, -1, 2.5])
def test_workers_outside_one_to_many_are_refused(workers):
    from spherex_reduce.core.errors import ResourceError

    with pytest.raises(ResourceError, match="workers must be a whole number"):
        run_sweep(SWEEP, workers=workers)


def test_scheduler_that_accepts_and_stays_silent_is_refused_within_the_timeout():
    """dask's own client waits for ever on such a server (even with its timeout)."""
    import socket
    import time

    from spherex_reduce.reduce.scheduler import check_scheduler

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)  # the kernel completes the connection; nobody answers
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        t0 = time.perf_counter()
        with pytest.raises(ConfigError, match="no dask scheduler answered within 2 s"):
            check_scheduler(address, timeout=2)
        assert time.perf_counter() - t0 < 10


def test_every_column_of_a_row_is_its_cells_case_measured_alone(serial):
    """A row of the table holds what its cell gives when simulated, reduced and measured
    by hand (`run_case` with the cell's readout values and seed), column by column."""
    import json

    from spherex_reduce.analysis.case import run_case

    sw = load_sweep(SWEEP)
    t = serial.table
    i = 5
    cell = {"skip": int(t["skip"][i]), "ref_mode": str(t["ref_mode"][i]),
            "pipeline": str(t["pipeline"][i]), "realization": int(t["realization"][i])}
    entropy = sw.cell_seed(cell).entropy
    seed = int(np.random.SeedSequence(entropy).generate_state(1, np.uint64)[0])
    scene = {**SWEEP["scene"], "readout": {**SWEEP["scene"]["readout"], "skip": cell["skip"],
                                           "ref_mode": cell["ref_mode"]}}
    m = run_case(scene, "spherex-default", SWEEP["measure"], seed=seed,
                 mode="slopes").measurement
    assert t["seed"][i] == json.dumps(entropy)
    assert t["band_power"][i] == m["band_power"].value
    assert t["band_power_err"][i] == m["band_power_err"].value
    assert t["std"][i] == m["std"] and t["masked_fraction"][i] == m["masked_fraction"]
    np.testing.assert_array_equal(t["k"][i], m["k"])
    np.testing.assert_array_equal(t["power"][i], m["power"])
    assert t["band_power"].unit == m["band_power"].unit and 0 < t["seconds"][i] < 600
