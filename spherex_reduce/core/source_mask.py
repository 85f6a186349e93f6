"""Sources and hot pixels of an image, found by photutils segmentation.

One function, `source_mask`, used by the spatial power spectrum
(``mask_sources``) and by the ``median`` reference strategy; each passes its
own thresholds.  It depends only on numpy, astropy and photutils.
"""

import warnings

import numpy as np
from astropy import units as u
from astropy.nddata import NDData

from .errors import SpherexReduceError

__all__ = ["image_and_mask", "source_mask"]

#: Background estimators `source_mask` knows, by name.
BACKGROUNDS = ("median", "sextractor")


def image_and_mask(image, mask=None, what="source_mask needs a 2-D image", hint=""):
    """``(data, bad-pixel mask, unit)`` of a 2-D image; non-finite pixels are bad.

    Accepts `~astropy.nddata.CCDData`/`~astropy.nddata.NDData` (its ``mask``
    is used), a `~astropy.units.Quantity`, a `numpy.ma.MaskedArray` or an
    array; ``mask`` (bool or flags, nonzero = bad) is or-ed in.  ``data`` is a
    view when it can be.  ``what`` and ``hint`` make the message for input
    that is not 2-D.
    """
    unit, own = u.one, None
    if isinstance(image, NDData):
        unit, own, data = image.unit or u.one, image.mask, image.data
    elif isinstance(image, u.Quantity):
        unit, data = image.unit, image.value
    elif isinstance(image, np.ma.MaskedArray):
        own, data = np.ma.getmaskarray(image), image.data
    else:
        data = image
    data = np.asarray(data)
    if data.ndim != 2:
        raise SpherexReduceError(f"{what}, got shape {data.shape}{hint}")
    if not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
        raise SpherexReduceError(f"image must be real numbers, got dtype {data.dtype}")
    bad = ~np.isfinite(data)
    for m in (own, mask):
        if m is not None:
            m = np.asarray(m)
            if m.shape != data.shape:
                raise SpherexReduceError(
                    f"mask shape {m.shape} differs from the image shape {data.shape}")
            bad = bad | (m != 0)
    return data, bad, unit


def source_mask(image, mask=None, *, nsigma=5.0, npixels=1, box_size=64, dilate=3,
                background="median", two_sided=True, min_boxes=4):
    """Mask of sources and hot pixels from a photutils segmentation map.

    A background and its RMS are estimated with
    `photutils.background.Background2D` (σ-clipped at 3σ, 10 iterations, in
    boxes of ``box_size`` pixels, median-filtered over 3 × 3 boxes); every
    connected group of at least ``npixels`` pixels deviating from the
    background by more than ``nsigma`` times the RMS is a segment
    (`photutils.segmentation.detect_sources`); segments are dilated by a
    ``dilate × dilate`` box.

    The defaults are those of the spatial power spectrum (single hot pixels
    of either sign count).  The ``median`` reference strategy looks for
    extended positive sources: ``nsigma=3, npixels=5, dilate=5,
    background="sextractor", two_sided=False, min_boxes=1``.

    Parameters
    ----------
    image : `~astropy.nddata.NDData`, `~astropy.units.Quantity`, `numpy.ma.MaskedArray` or array
        2-D image (any unit; the thresholds are relative).  An NDData's
        ``mask`` and non-finite pixels are ignored by the estimate.
        Floating-point images are worked on in their own precision (photutils
        keeps float32 as float32), integer ones in float64.  Not changed.
    mask : array-like of bool, optional
        Pixels already known to be bad (ignored by the estimate).
    nsigma : float
        Detection threshold in background RMS.
    npixels : int
        Minimum connected pixels of a detection (1 catches single hot pixels).
    box_size : int
        Background box size in pixels; reduced for small images (see
        ``min_boxes``).
    dilate : int
        Size of the dilation box; 1 (or 0) for none.
    background : {'median', 'sextractor'}
        Background estimator in each box: `photutils.background.MedianBackground`
        or `photutils.background.SExtractorBackground`.
    two_sided : bool
        Detect deviations of either sign (negative hot pixels of pair
        differences); False detects only pixels above the background.
    min_boxes : int
        The box is reduced to give at least this many boxes along the
        shorter side of the image, but not below 4 pixels, and never exceeds
        that side.

    Returns
    -------
    mask : `numpy.ndarray` of bool
        True for source or hot pixels (not including ``mask``, unless dilated
        into it).

    Raises
    ------
    SpherexReduceError
        An image that is not 2-D real numbers, or a mask of another shape.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.core.source_mask import source_mask
    >>> img = np.random.default_rng(0).normal(0, 1, (128, 128))
    >>> img[40, 50] = 100.0
    >>> m = source_mask(img)
    >>> bool(m[40, 50]), int(m.sum())
    (True, 9)
    >>> img[90:94, 90:94] += 50
    >>> m = source_mask(img, nsigma=3, npixels=5, dilate=5, background="sextractor",
    ...                 two_sided=False, min_boxes=1)
    >>> bool(m[91, 91]), bool(m[40, 50])       # the hot pixel is smaller than 5 pixels
    (True, False)
    """
    from astropy.stats import SigmaClip
    from astropy.utils.exceptions import AstropyUserWarning
    from photutils.background import (
        Background2D,
        MedianBackground,
        SExtractorBackground,
        StdBackgroundRMS,
    )
    from photutils.segmentation import detect_sources
    from photutils.utils.exceptions import NoDetectionsWarning

    if background not in BACKGROUNDS:
        raise SpherexReduceError(
            f"background must be one of {', '.join(BACKGROUNDS)}; got {background!r}")
    data, bad, _ = image_and_mask(image, mask)
    if data.dtype.kind != "f":
        data = data.astype(np.float64)
    side = min(data.shape)
    box = int(min(box_size, max(side // max(int(min_boxes), 1), min(4, side))))
    estimator = MedianBackground() if background == "median" else SExtractorBackground()
    filled = np.where(bad, 0.0, data)
    with warnings.catch_warnings():
        # photutils' notes about boxes with few unmasked pixels (they are excluded)
        warnings.simplefilter("ignore", category=AstropyUserWarning)
        bkg = Background2D(filled, box, mask=bad, sigma_clip=SigmaClip(sigma=3.0, maxiters=10),
                           bkg_estimator=estimator, bkg_rms_estimator=StdBackgroundRMS())
    resid = np.where(bad, 0.0, filled - bkg.background)
    if two_sided:
        resid = np.abs(resid)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", category=NoDetectionsWarning)
        segm = detect_sources(resid, nsigma * bkg.background_rms, n_pixels=int(npixels),
                              mask=bad)
    if segm is None:
        return np.zeros(data.shape, dtype=bool)
    if dilate and int(dilate) > 1:
        return segm.make_source_mask(size=int(dilate))
    return segm.data > 0
