"""Simulating and reducing a readout with an explicit read order (``readout.order``)."""

import numpy as np
import pytest

import spherex_reduce as sr
from spherex_reduce import simulate
from spherex_reduce.simulation import simulate_to_fits

#: 16 rows, reference rows 0 1 (top) and 14 15 (bottom); the active rows in an order no
#: skip gives, reference rows read five times, in between.
ACTIVE = [2, 10, 6, 13, 4, 8, 12, 3, 11, 7, 5, 9]
ORDER = [0, *ACTIVE[:6], 15, 1, *ACTIVE[6:], 14, 0]
NFRAMES, TFRAME = 4, 0.5
SCENE = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 2,
                      "ref_border": {"top": 2, "bottom": 2}},
         "readout": {"order": ORDER, "phantom_reads": 2, "frame_time": TFRAME,
                     "nframes": NFRAMES},
         "noise": {"components": ["roic", "video8"]}, "scene": {"photocurrent": 3.0},
         "output": {"mode": "ramps"}}


def test_reduced_ramps_are_numpy_slopes_of_the_reads_put_back_by_hand(tmp_path):
    """unchop, a plain mean of each channel's reference reads, fit_ramp: against the
    simulated reads corrected, placed in physical rows and fitted by numpy."""
    exposure = simulate(SCENE, seed=3)
    path = simulate_to_fits(SCENE, tmp_path / "ramps.fits", seed=3)
    pipeline = sr.Pipeline({"steps": [  # no readout: the file says how it was read
        "unchop", {"correct_reference": {"strategy": "mean", "sigma": 1e6,
                                         "telegraph": "keep"}}, "fit_ramp"]})
    got = pipeline.run(path).data.data

    raw = exposure.data.data.astype(np.float64)  # (frames, reads, columns), in read order
    assert raw.shape == (NFRAMES, len(ORDER), 16)
    is_ref = np.isin(ORDER, [0, 1, 14, 15])
    corrected = raw.copy()
    for k in range(2):
        cols = slice(8 * k, 8 * k + 8)
        corrected[:, :, cols] -= raw[:, is_ref, cols].mean(axis=(1, 2))[:, None, None]
    physical = np.zeros((NFRAMES, 16, 16))
    for i, row in enumerate(ORDER):
        if not is_ref[i]:
            physical[:, row] = corrected[:, i]
    t = TFRAME * np.arange(NFRAMES)
    slope = np.polyfit(t, physical.reshape(NFRAMES, -1), 1)[0].reshape(16, 16)
    np.testing.assert_allclose(got[2:14], slope[2:14], rtol=1e-5, atol=1e-4)
    assert np.abs(slope[2:14]).mean() > 1.0  # a real signal, not zeros


@pytest.mark.parametrize("mode", ["slopes", "ramps"])
def test_an_explicit_order_equal_to_a_skip_order_simulates_the_same(mode):
    chopped = {**SCENE, "readout": {"skip": 4, "ref_reads": 4, "phantom_reads": 2,
                                    "frame_time": TFRAME, "nframes": NFRAMES},
               "output": {"mode": mode}}
    a = simulate(chopped, seed=11)
    explicit = {**chopped, "readout": {**{k: v for k, v in chopped["readout"].items()
                                          if k not in ("skip", "ref_reads")},
                                       "order": a.schedule.rows.tolist()}}
    b = simulate(explicit, seed=11)
    assert b.schedule.order is not None and a.schedule.order is None
    assert np.array_equal(a.data.data, b.data.data)
