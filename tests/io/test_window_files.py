"""A window's exposure written to FITS and read back without any config: the window
keywords and the READOUT table give the same schedule and pixel times."""

import hashlib

import numpy as np

import spherex_reduce as sr
from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.core.window import Window
from spherex_reduce.io.fits_write import write


def test_a_written_window_reads_back_with_its_full_readout(tmp_path):
    full = DetectorGeometry(64, 64, 4, ref_border=4, scan="alternate", pixel_rate=1e5)
    g = Window(0, 16, full).geometry(64, 16)  # output 1, read right to left
    s = ReadoutSchedule(g, skip=4, ref_mode="none", phantom_reads=0, row_overhead=2,
                        nframes=3, frame_time=0.05)
    cube = np.arange(3 * 64 * 16, dtype=np.float32).reshape(3, 64, 16)
    path = tmp_path / "window.fits"
    write(sr.Exposure.from_arrays(cube, s), path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    again = sr.read(path)
    assert again.schedule == s and again.schedule.geometry.window == g.window
    # full channel 1 reversed: column 0 of the window is sampled last in its row read
    assert again.schedule.pixel_samples()[0].tolist() == list(range(15, -1, -1))
    assert again.schedule.starts[1] == 18  # the 2nd read of the full readout: 16 + 2 later
    np.testing.assert_array_equal(again.data.data, cube)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest
