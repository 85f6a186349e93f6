"""Windows of a larger array reduced from a lab-like file (no readout keywords: the
config's ``window:`` says how it was read) with row chopping, reference correction and
``fit_ramp``; slopes against numpy, the read order against one written by hand."""

import hashlib

import numpy as np
import pytest
from astropy.io import fits

import spherex_reduce as sr

FULL = {"full_nrows": 64, "full_ncols": 64, "full_nchannels": 4, "full_scan": "alternate",
        "full_ref_border": 4}
TFRAME, NREADS, SKIP = 0.5, 5, 4


def full_order(skip=SKIP, nrows=64, border=4):
    """The full readout's rows (ref_mode none): top reference rows, active rows chopped
    (k, k+S, ... for k = 0 ... S-1), bottom reference rows."""
    active = list(range(border, nrows - border))
    order = list(range(border))
    for k in range(skip):
        order += active[k::skip]
    return order + list(range(nrows - border, nrows))


@pytest.mark.parametrize(("first_row", "first_column", "shape", "refs"), [
    (0, 0, (16, 16), {"rows": [0, 1, 2, 3], "left": 4}),              # corner in channel 0
    (0, 16, (64, 16), {"rows": [0, 1, 2, 3, 60, 61, 62, 63], "left": 0}),  # output 1
    (2, 16, (32, 32), {"rows": [0, 1], "left": 0}),  # channels 1 and 2 from full row 2
], ids=["corner", "output", "two-channels"])
@pytest.mark.parametrize("strategy", ["mean", "acn"])
def test_window_reduces_to_the_numpy_slopes(tmp_path, first_row, first_column, shape, refs,
                                            strategy):
    rng = np.random.default_rng(7)
    nrows, ncols = shape
    width = 16
    nch = max(ncols // width, 1)
    ref = np.zeros(shape, bool)
    ref[refs["rows"]] = True
    ref[:, :refs["left"]] = True
    rate = np.where(ref, 0.0, rng.uniform(1.0, 5.0, shape))  # ADU/s
    offsets = 500.0 + rng.normal(0, 50.0, (NREADS, nch))     # per read and channel
    t = TFRAME * np.arange(NREADS)
    physical = (np.repeat(offsets, min(width, ncols), axis=1)[:, None, :]
                + rate * t[:, None, None])
    rows = [r - first_row for r in full_order() if first_row <= r < first_row + nrows]
    raw = physical[:, rows, :]  # the file holds the rows in the order they were read
    path = tmp_path / "window.fits"
    sci = fits.ImageHDU(raw.astype(np.float64), name="SCI")
    sci.header["BUNIT"] = "ADU"
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()

    config = {"input": {"unit": "adu"},
              "geometry": {"nrows": nrows, "ncols": ncols, "pixel_rate": 1e5},
              "window": {"first_row": first_row, "first_column": first_column, **FULL},
              "readout": {"skip": SKIP, "ref_mode": "none", "phantom_reads": 0,
                          "nframes": NREADS, "frame_time": TFRAME},
              "steps": ["unchop", {"correct_reference": {"strategy": strategy}}, "fit_ramp"]}
    pipeline = sr.Pipeline(config)
    assert pipeline.read(path).schedule.rows.tolist() == rows
    got = pipeline.run(path).data.data

    # numpy: each channel's reference-row mean subtracted from every read, then a line
    chan = np.arange(ncols) // min(width, ncols)
    corrected = physical.copy()
    for k in range(nch):
        corrected[:, :, chan == k] -= physical[:, refs["rows"]][:, :, chan == k].mean(
            axis=(1, 2))[:, None, None]
    slope = np.polyfit(t, corrected.reshape(NREADS, -1), 1)[0].reshape(shape)
    np.testing.assert_allclose(got[~ref], slope[~ref], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got[~ref], rate[~ref], rtol=1e-9)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest


def test_wiener_refuses_a_window_in_one_line(tmp_path):
    path = tmp_path / "corner.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.zeros((3, 16, 16)), name="SCI")]
                 ).writeto(path)
    config = {"geometry": {"nrows": 16, "ncols": 16, "pixel_rate": 1e5},
              "window": {"first_row": 0, "first_column": 0, **FULL},
              "readout": {"skip": 1, "ref_mode": "none", "phantom_reads": 0, "nframes": 3,
                          "frame_time": TFRAME},
              "steps": [{"correct_reference": {"strategy": "wiener", "noise": "spherex-table2"}}]}
    with pytest.raises(sr.ConfigError, match="wiener does not model a window") as info:
        sr.Pipeline(config).run(path)
    assert "\n" not in str(info.value)
