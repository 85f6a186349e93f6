"""`run_case`: the one simulate -> reduce -> measure route of demo, figures and sweeps."""

import numpy as np
import pytest

from spherex_reduce.analysis import (
    SpectrumMeasure,
    as_pipeline,
    band_power,
    power_spectrum,
    run_case,
)
from spherex_reduce.analysis.sweep import load_sweep, run_cell
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.simulation import simulate

SCENE = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2, "ref_border": 4},
         "readout": {"skip": 4, "ref_reads": 8, "nframes": 5, "phantom_reads": 2}}
RAW = {"name": "raw", "steps": [{"unchop": {}}]}


def test_one_case_is_simulate_then_reduce_then_measure():
    """Each step done by hand, with the public functions, gives the same numbers."""
    res = run_case(SCENE, {"raw": RAW, "corrected": "spherex-default"},
                   {"bins": 6, "exclude_horizontal": True}, seed=4, keep=True)
    raw = simulate(SCENE, seed=4)
    for label, pipe in (("raw", RAW), ("corrected", "spherex-default")):
        image = as_pipeline(pipe).run(raw).to_ccddata()
        np.testing.assert_array_equal(res.reduced[label].to_ccddata().data, image.data)
        m = res.measured[label]
        edges = np.geomspace(2 * np.pi / 64, np.pi, 7)
        spec = power_spectrum(image, bins=edges, exclude_horizontal=True)
        np.testing.assert_array_equal(np.asarray(m["spectrum"]["power"]),
                                      np.asarray(spec["power"]))
        assert m["band_power"] == band_power(image, exclude_horizontal=True)
        assert m["std"] == float(np.std(np.asarray(image.data, float)))
        assert m["k"].shape == (6,)  # every bin, empty ones NaN
    assert set(res.seconds) == {"simulate", "raw", "corrected"}
    # the pipelines saw one exposure: the corrected one differs, the simulation does not
    assert res.measured["raw"]["band_power"] != res.measured["corrected"]["band_power"]


def test_streamed_from_a_file_equals_in_memory(tmp_path):
    scene = {**SCENE, "output": {"mode": "ramps"}}
    mem = run_case(scene, "spherex-default", SpectrumMeasure(), seed=3, keep=True)
    disk = run_case(scene, "spherex-default", SpectrumMeasure(), seed=3, keep=True,
                    raw_path=tmp_path / "raw.fits")
    assert disk.raw == tmp_path / "raw.fits" and disk.raw.is_file()
    np.testing.assert_array_equal(mem.reduced["spherex-default"].to_ccddata().data,
                                  disk.reduced["spherex-default"].to_ccddata().data)
    assert mem.measurement["band_power"] == disk.measurement["band_power"]


def test_a_measure_needs_an_image():
    scene = {**SCENE, "output": {"mode": "ramps"}}
    with pytest.raises(SpherexReduceError, match="left ramps"):
        run_case(scene, RAW, lambda image: image, seed=1)
    res = run_case(scene, RAW, seed=1, keep=True)  # no measure: ramps are fine
    assert res.reduced["raw"].is_ramp and res.measured == {}
    with pytest.raises(SpherexReduceError, match="0 measurements"):
        _ = res.measurement


def test_a_sweep_cell_is_a_case():
    sw = load_sweep({"scene": SCENE, "grid": {"skip": [4]}, "seed": 9,
                     "measure": {"bins": 5}})
    cell = sw.cells()[0]
    task = sw.task(cell)
    row = run_cell(task)
    seed = int(np.random.SeedSequence(task["entropy"]).generate_state(1, np.uint64)[0])
    m = run_case(task["scene"], "spherex-default", {"bins": 5}, seed=seed,
                 mode="slopes").measurement
    assert row["band_power"] == m["band_power"].value
    np.testing.assert_array_equal(row["power"], m["power"])
