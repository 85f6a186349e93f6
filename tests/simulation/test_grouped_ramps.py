"""Ramps of groups: every read simulated, each group's reads averaged, the others discarded."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import ConfigError, simulate
from spherex_reduce.io import read
from spherex_reduce.simulation import simulate_to_fits

GROUPS = [[1], [2, 3], [5, 6, 7]]  # read 0 and read 4 are read and discarded
SCENE = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 2, "ref_border": 2},
         "readout": {"skip": 4, "ref_reads": 4, "phantom_reads": 2, "frame_time": 0.5,
                     "nframes": 3, "groups": GROUPS},
         "output": {"mode": "ramps"}}


def _with(readout=None, **sections):
    return {**SCENE, "readout": {**SCENE["readout"], **(readout or {})}, **sections}


def test_noiseless_groups_are_the_mean_charge_of_their_reads():
    rate = 10.0  # e/s
    e = simulate(_with(noise={"components": []}, scene={"photocurrent": rate,
                                                        "poisson": False}), seed=1)
    s = e.schedule
    g = s.geometry
    active = (~s.is_reference)[:, None] & (~g.reference_column_mask())[None, :]
    tau = s.pixel_times().to_value(u.s)  # within the frame
    for k, reads in enumerate(GROUPS):
        expected = rate * (np.mean(np.array(reads) * 0.5) + tau)
        np.testing.assert_allclose(e.data.data[k][active], expected[active], rtol=1e-6)
        assert not e.data.data[k][~active].any()


def test_noisy_groups_average_the_reads_simulated_one_by_one(tmp_path):
    """The same scene and seed with every read stored: averaging its reads by hand gives
    the grouped ramps (pixels and phantom values), streamed to FITS or in memory."""
    scene = _with(noise={"components": ["roic", "video8"]}, scene={"photocurrent": 3.0})
    grouped = simulate(scene, seed=7)
    every = simulate(_with({"groups": None, "nframes": 8}, noise=scene["noise"],
                           scene=scene["scene"]), seed=7)
    for k, reads in enumerate(GROUPS):
        for got, reads_of in ((grouped.data.data, every.data.data),
                              (grouped.phantom, every.phantom)):
            mean = reads_of[reads].astype(np.float64).mean(axis=0)
            np.testing.assert_allclose(got[k], mean, rtol=1e-6, atol=1e-4)
    streamed = read(simulate_to_fits(scene, tmp_path / "g.fits", seed=7))
    assert streamed.schedule == grouped.schedule
    assert np.array_equal(streamed.data.data, grouped.data.data)


def test_slopes_of_groups_are_refused_in_one_line():
    with pytest.raises(ConfigError) as info:
        simulate(_with(output={"mode": "slopes"}), seed=1)
    assert str(info.value) == ("output.mode: slopes are simulated for one read per frame; a "
                               "readout with groups or gaps needs output.mode: ramps")


def test_reads_at_given_times_are_refused_in_one_line():
    """A readout with ``read_times`` (reads at uneven times) is never simulated as if the
    reads were every frame time."""
    times = [0.0, 0.5, 2.0]
    scene = {**SCENE, "readout": {**{k: v for k, v in SCENE["readout"].items() if k != "groups"},
                                  "read_times": times}}
    with pytest.raises(ConfigError, match=r"^readout\.read_times: the simulator reads the array "
                                          "every frame_time"):
        simulate(scene, seed=1)
