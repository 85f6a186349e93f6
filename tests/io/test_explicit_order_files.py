"""A file read in an explicit order: its header says so, its READOUT table lists the rows,
and it reads back (and is written again) without a config."""

import numpy as np
from astropy.io import fits

from spherex_reduce import read, simulate, write
from spherex_reduce.simulation import simulate_to_fits

ORDER = [15, 2, 10, 6, 13, 4, 8, 0, 12, 3, 11, 7, 5, 9, 0, 1]  # rows 0 1 14 15: reference
SCENE = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 2,
                      "ref_border": {"top": 2, "bottom": 2}},
         "readout": {"order": ORDER, "frame_time": 0.5, "nframes": 3},
         "noise": {"components": ["roic"]}, "output": {"mode": "ramps"}}


def test_an_explicit_order_round_trips_through_fits(tmp_path):
    path = simulate_to_fits(SCENE, tmp_path / "ramps.fits", seed=4)
    with fits.open(path) as hdul:
        header, table = hdul[0].header, hdul["READOUT"].data
        assert header["ROWORDER"] == "explicit"
        assert "ROWSKIP" not in header and "REFMODE" not in header
        assert table["row"].tolist() == ORDER
        assert [k.strip() for k in table["kind"]][:8] == ["reference"] + ["active"] * 6 + [
            "reference"]
    exposure = read(path)
    assert exposure.schedule.rows.tolist() == ORDER
    assert exposure.schedule == simulate(SCENE, seed=4).schedule
    again = read(write(exposure, tmp_path / "again.fits"))
    assert again.schedule == exposure.schedule
    assert np.array_equal(again.data.data, exposure.data.data)
