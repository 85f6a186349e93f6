"""One `source_mask` gives the masks of both former copies (power spectrum, median strategy).

The expected masks are computed here with photutils directly, following each
former function's recipe step by step.
"""

import warnings

import numpy as np
import pytest
from astropy.nddata import CCDData
from astropy.stats import SigmaClip
from astropy.utils.exceptions import AstropyUserWarning
from photutils.background import (
    Background2D,
    MedianBackground,
    SExtractorBackground,
    StdBackgroundRMS,
)
from photutils.segmentation import detect_sources

from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.core.source_mask import source_mask

#: the median reference strategy's call (nsigma, npixels, box_size are its parameters)
MEDIAN_STRATEGY = {"nsigma": 3.0, "npixels": 5, "box_size": 64, "dilate": 5,
                   "background": "sextractor", "two_sided": False, "min_boxes": 1}


def _image(dtype, shape=(96, 80)):
    """Noise on a gradient, two extended sources, hot pixels of both signs, NaNs, a bad pixel."""
    rng = np.random.default_rng(11)
    x = np.arange(shape[1])[None, :]
    img = rng.normal(0, 1, shape) + 0.02 * x
    img[20:24, 30:35] += 8.0        # extended, a few sigma
    img[60:63, 10:13] += 40.0
    img[45, 70] = 60.0              # positive hot pixel
    img[75, 40] = -60.0             # negative hot pixel
    img[5, 5] = np.nan
    bad = np.zeros(shape, bool)
    bad[50, 50] = True
    return img.astype(dtype), bad


def _expected(img, bad, *, nsigma, npixels, box, dilate, estimator, two_sided, dtype):
    data = np.asarray(img, dtype)
    bad = bad | ~np.isfinite(data)
    filled = np.where(bad, 0.0, data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AstropyUserWarning)
        bkg = Background2D(filled, box, mask=bad, filter_size=(3, 3),
                           sigma_clip=SigmaClip(sigma=3.0, maxiters=10),
                           bkg_estimator=estimator, bkg_rms_estimator=StdBackgroundRMS())
    resid = filled - bkg.background
    if two_sided:
        resid = np.abs(np.where(bad, 0.0, resid))
    segm = detect_sources(resid, nsigma * bkg.background_rms, n_pixels=npixels, mask=bad)
    return segm.make_source_mask(size=dilate) if dilate > 1 else segm.data > 0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_spectrum_defaults_give_the_former_analysis_mask(dtype):
    img, bad = _image(dtype)
    # box: min(64, max(min(shape) // 4, 4)) = 20; computed in the image's own precision
    want = _expected(img, bad, nsigma=5.0, npixels=1, box=20, dilate=3,
                     estimator=MedianBackground(), two_sided=True, dtype=dtype)
    got = source_mask(np.where(bad, np.nan, img), mask=bad)
    np.testing.assert_array_equal(got, want)
    assert got[45, 70] and got[75, 40] and got[61, 11]     # both signs of hot pixel
    # as power_spectrum passes it, and as a CCDData with its own mask
    np.testing.assert_array_equal(source_mask(CCDData(img, unit="adu", mask=bad)), want)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_median_strategy_call_gives_the_former_reference_mask(dtype):
    img, bad = _image(dtype)
    # the strategy cast its image to float64, boxes of min(box_size, min(shape)) pixels
    want = _expected(img, bad, nsigma=3.0, npixels=5, box=64, dilate=5,
                     estimator=SExtractorBackground(sigma_clip=None), two_sided=False,
                     dtype=np.float64)
    got = source_mask(np.asarray(img, np.float64), bad, **MEDIAN_STRATEGY)
    np.testing.assert_array_equal(got, want)
    assert got[21, 32] and got[61, 11] and not got[75, 40] and not got[45, 70]
    # a small image: the box shrinks to the image
    small, sbad = img[:40, :48], bad[:40, :48]
    want = _expected(small, sbad, nsigma=3.0, npixels=5, box=40, dilate=5,
                     estimator=SExtractorBackground(sigma_clip=None), two_sided=False,
                     dtype=np.float64)
    got = source_mask(np.asarray(small, np.float64), sbad, **MEDIAN_STRATEGY)
    np.testing.assert_array_equal(got, want)


def test_input_is_not_changed_and_bad_input_is_refused():
    img, bad = _image(np.float32)
    before = img.copy()
    source_mask(img, bad)
    np.testing.assert_array_equal(img, before)
    with pytest.raises(SpherexReduceError, match="2-D"):
        source_mask(np.zeros((2, 8, 8)))
    with pytest.raises(SpherexReduceError, match="mask shape"):
        source_mask(img, np.zeros((3, 3), bool))
    with pytest.raises(SpherexReduceError, match="background must be"):
        source_mask(img, background="mode")
