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


def test_a_reduced_window_without_reference_rows_reads_back(tmp_path):
    """A window in the middle of the array has no reference row: its reduced file holds an
    empty REFPIX, which every reader used to fail on (a traceback, exit 1)."""
    from astropy.io import fits

    from spherex_reduce import Pipeline

    t = 2.0 * np.arange(3)
    rate = np.random.default_rng(1).uniform(1, 2, (8, 8))
    sci = fits.ImageHDU((100 + rate * t[:, None, None]).astype(np.float32), name="SCI")
    sci.header["BUNIT"] = "adu"
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(tmp_path / "mid.fits")
    p = Pipeline({"geometry": {"nrows": 8, "ncols": 8, "pixel_rate": 1e5},
                  "window": {"first_row": 20, "first_column": 16, "full_nrows": 64,
                             "full_ncols": 64, "full_nchannels": 4},
                  "readout": {"skip": 1, "ref_mode": "none", "phantom_reads": 0,
                              "nframes": 3, "frame_time": 2.0},
                  "steps": [{"unchop": {}}, {"fit_ramp": {}}]})
    write(p.run(tmp_path / "mid.fits"), tmp_path / "slopes.fits")
    back = sr.read(tmp_path / "slopes.fits")
    assert back.geometry.border.rows == 0
    np.testing.assert_allclose(back.data.data, rate, rtol=1e-5)
