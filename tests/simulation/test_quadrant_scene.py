"""A simulated quadrant-layout exposure is stored as a WFC3/IR file is, and reduces back.

The scene has photocurrent only on light-sensitive pixels and no noise but the
engine's own; the file must hold stored images (each quadrant's reference rows
and columns on the array's outer sides, where the definition puts them) and the
reduced slopes must match a straight-line fit of the file's own pixels computed
here with numpy.
"""

import hashlib

import numpy as np
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce.simulation.simulator import simulate_to_fits

N, BORDER, NFRAMES, TFRAME, RATE = 16, 2, 6, 2.0, 50.0
SCENE = {"geometry": {"nrows": N, "ncols": N, "nchannels": 4, "ref_border": BORDER,
                      "channels": "quadrants", "first_corner": "outer", "fast_axis": "rows"},
         "readout": {"skip": 1, "ref_mode": "none", "ref_reads": 0, "nframes": NFRAMES,
                     "phantom_reads": 0, "frame_time": TFRAME},
         "scene": {"photocurrent": RATE}}


def test_quadrant_scene_is_stored_as_the_array_and_reduces_to_numpy_slopes(tmp_path):
    path = simulate_to_fits(SCENE, tmp_path / "q.fits", seed=4, mode="ramps")
    header, sci = fits.getheader(path), fits.getdata(path, "SCI")
    assert (header["CHANLAY"], sci.shape) == ("quadrants", (NFRAMES, N, N))
    border = np.zeros((N, N), bool)  # the outer border of the stored array, every side
    border[:BORDER], border[-BORDER:], border[:, :BORDER], border[:, -BORDER:] = (True,) * 4
    gained = sci[-1] - sci[0]
    per_second = gained / ((NFRAMES - 1) * TFRAME)
    assert np.all(np.abs(per_second[border]) < 5) and np.all(per_second[~border] > 30)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    out = sr.write(sr.Pipeline({"steps": ["fit_ramp"]}).run(path), tmp_path / "slopes.fits")
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before
    got = fits.getdata(out, "SCI")
    t = TFRAME * np.arange(NFRAMES)
    expected = np.polyfit(t, sci.reshape(NFRAMES, -1), 1)[0].reshape(N, N)
    assert np.allclose(got, expected, rtol=1e-6, atol=1e-6)
