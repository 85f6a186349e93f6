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
