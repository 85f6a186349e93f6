"""The light-sensitive pixels of an image: the rectangle inside the reference pixels."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
from spherex_reduce.analysis import light_sensitive, light_sensitive_image
from spherex_reduce.core.errors import SpherexReduceError

WIDTHS = [({"top": 4, "bottom": 4, "left": 4, "right": 4}, (slice(4, 20), slice(4, 20))),
          ({"top": 4, "left": 4}, (slice(4, 24), slice(4, 24))),
          ({"bottom": 2, "right": 3}, (slice(0, 22), slice(0, 21)))]


@pytest.mark.parametrize(("widths", "box"), WIDTHS)
def test_the_rectangle_inside_each_side(widths, box):
    assert light_sensitive(DetectorGeometry(24, 24, 2, ref_border=widths)) == box


@pytest.mark.parametrize(("widths", "box"), WIDTHS)
@pytest.mark.parametrize("order", ["physical", "readout"])
def test_the_image_of_the_light_sensitive_pixels(widths, box, order):
    s = ReadoutSchedule(DetectorGeometry(24, 24, 2, ref_border=widths), skip=5, ref_reads=2,
                        phantom_reads=0, nframes=3)
    img = np.full((24, 24), 1e6)
    img[box] = np.arange(img[box].size, dtype=float).reshape(img[box].shape)
    mask = np.zeros((24, 24), bool)
    mask[10, 10] = True
    values, flags = (img, mask) if order == "physical" else (img[s.rows], mask[s.rows])
    exposure = Exposure.from_arrays(values, s, order=order, mask=flags, unit=u.electron / u.s)
    cut = light_sensitive_image(exposure)
    np.testing.assert_array_equal(cut.data, img[box])
    np.testing.assert_array_equal(cut.mask, mask[box])
    assert cut.unit == u.electron / u.s
    assert values.max() == 1e6  # the input is not changed


def test_ramps_are_refused():
    s = ReadoutSchedule(DetectorGeometry(8, 8, 1, ref_border=2), ref_mode="none",
                        phantom_reads=0, nframes=2)
    with pytest.raises(SpherexReduceError, match="fit them first"):
        light_sensitive_image(Exposure.from_arrays(np.zeros((2, 8, 8)), s))


@pytest.mark.parametrize(("layout", "border"), [
    ({"channels": "quadrants"}, {"top": 2, "bottom": 2, "left": 3, "right": 3}),
    ({"channels": "quadrants", "first_corner": "inner", "fast_axis": "columns"}, 2),
    ({"channels": "rows", "scan": "alternate"}, {"top": 1, "left": 2, "right": 2})])
def test_a_reduced_layout_file_is_measured_as_it_is_stored(tmp_path, layout, border):
    """``spectrum``'s image (``read_image(light=True)``) of a reduced file whose channels
    are quadrants or rows is the file's SCI, as stored, cut inside its border by hand: not
    the readout frame (quadrants side by side, bands transposed) every step works in."""
    from astropy.io import fits

    from spherex_reduce import Pipeline, write
    from spherex_reduce.analysis.io import read_image

    sides = border if isinstance(border, dict) else dict.fromkeys(
        ("top", "bottom", "left", "right"), border)
    stored = np.random.default_rng(3).normal(0, 1, (4, 16, 20)).cumsum(axis=0)
    sci = fits.ImageHDU(stored.astype(np.float32), name="SCI")
    sci.header["BUNIT"] = "adu"
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(tmp_path / "raw.fits")
    p = Pipeline({"geometry": {"nrows": 16, "ncols": 20, "nchannels": 4, "ref_border": border,
                               "pixel_rate": 1e5,
                               **layout},
                  "readout": {"skip": 1, "ref_mode": "none", "phantom_reads": 0,
                              "nframes": 4, "frame_time": 2.0},
                  "steps": [{"unchop": {}}, {"fit_ramp": {}}]})
    write(p.run(tmp_path / "raw.fits"), tmp_path / "slopes.fits")
    written = fits.getdata(tmp_path / "slopes.fits", "SCI")
    image = read_image(tmp_path / "slopes.fits", light=True)
    cut = written[sides.get("top", 0):16 - sides.get("bottom", 0),
                  sides.get("left", 0):20 - sides.get("right", 0)]
    assert image.shape == cut.shape
    np.testing.assert_array_equal(image.data, cut)
    t = 2.0 * np.arange(4)  # and the file holds numpy's slopes where they were stored
    np.testing.assert_allclose(written, np.polyfit(t, stored.reshape(4, -1), 1)[0].reshape(16, 20),
                               rtol=1e-5, atol=1e-5)
