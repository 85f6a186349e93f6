"""The light-sensitive pixels of an image: what every statistic of a reduced image is taken on.

Which pixels are reference pixels is the geometry's
(`DetectorGeometry.reference_pixel_mask <spherex_reduce.DetectorGeometry.reference_pixel_mask>`):
`light_sensitive` is the smallest rectangle holding every other pixel, and
`light_sensitive_image` cuts a reduced image to it, masking any reference
pixel left inside.  The spatial power spectrum of a reduced image
(``spherex-reduce spectrum``, `~spherex_reduce.analysis.run_case`) and the
injected sky of ``compare-strategies`` work on them.
"""

import numpy as np
from astropy.nddata import CCDData

from ..core.errors import SpherexReduceError
from ..reduce.steps import unchop

__all__ = ["light_sensitive", "light_sensitive_image", "stored_image"]


def light_sensitive(geometry):
    """The rectangle of the light-sensitive pixels, as two slices.

    The smallest rectangle that holds every pixel that is not a reference
    pixel (`DetectorGeometry.reference_pixel_mask
    <spherex_reduce.DetectorGeometry.reference_pixel_mask>`): with reference
    rows and columns along the sides (any width per side), exactly the
    light-sensitive pixels.

    Parameters
    ----------
    geometry : `~spherex_reduce.DetectorGeometry`

    Returns
    -------
    tuple of slice
        ``(rows, columns)``, to index a physical-order image.

    Raises
    ------
    SpherexReduceError
        Every pixel is a reference pixel.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.analysis import light_sensitive
    >>> light_sensitive(DetectorGeometry(64, 64, 4, ref_border=4))
    (slice(4, 60, None), slice(4, 60, None))
    >>> light_sensitive(DetectorGeometry(24, 24, 2, ref_border={"top": 4, "left": 4}))
    (slice(4, 24, None), slice(4, 24, None))
    """
    light = ~geometry.reference_pixel_mask()
    rows, cols = np.flatnonzero(light.any(axis=1)), np.flatnonzero(light.any(axis=0))
    if rows.size == 0:
        raise SpherexReduceError("the geometry has no light-sensitive pixel (its reference "
                                 "border covers the array)")
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)


def light_sensitive_image(exposure):
    """The light-sensitive pixels of a reduced image, as `~astropy.nddata.CCDData`.

    The image in physical row order (un-chopped first if in readout order)
    and in the stored orientation (`stored_image`), cut to `light_sensitive`
    of the stored image's geometry; its mask is the image's (pixels that must not be
    used) and any reference pixel inside the rectangle.  A statistic of the
    result never sees a reference pixel.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A 2-D image (any unit); not changed.

    Returns
    -------
    `~astropy.nddata.CCDData`
        Values, unit, uncertainty and mask of the rectangle; the header as
        ``meta``.

    Raises
    ------
    SpherexReduceError
        The exposure holds ramps, or no light-sensitive pixel.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce.analysis.light import light_sensitive_image
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border={"top": 2, "right": 1}),
    ...                     ref_mode="none", phantom_reads=0, nframes=2)
    >>> img = np.full((8, 8), 1e6)
    >>> img[2:, :7] = 1.0  # the light-sensitive pixels
    >>> cut = light_sensitive_image(Exposure.from_arrays(img, s, order="physical"))
    >>> cut.shape, float(cut.data.max())
    ((6, 7), 1.0)
    """
    if exposure.is_ramp:
        raise SpherexReduceError(f"the light-sensitive pixels of an image: got ramps "
                                 f"{exposure.shape}; fit them first (fit_ramp)")
    if exposure.order == "readout":
        exposure = unchop(exposure)
    geometry = exposure.geometry.stored_geometry
    box = light_sensitive(geometry)
    ccd = stored_image(exposure)[box]
    reference = geometry.reference_pixel_mask()[box]
    ccd.mask = reference if ccd.mask is None else np.asarray(ccd.mask, bool) | reference
    return ccd


def stored_image(exposure):
    """A reduced image as `~astropy.nddata.CCDData` in the stored orientation: as its file
    holds it, whatever the channel layout (`~spherex_reduce.core.channel_layout`).

    An exposure in memory is in the readout frame, where every computation
    runs; for channels as rows or quadrants that is not the image users see
    (quadrants side by side, bands transposed).  Spatial statistics are taken
    on the stored image.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A 2-D image in physical row order; not changed.

    Returns
    -------
    `~astropy.nddata.CCDData`
        Values, unit, uncertainty and mask mapped to the stored orientation;
        the header as ``meta``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce.analysis.light import stored_image
    >>> g = DetectorGeometry(4, 6, 4, ref_border=0, channels="quadrants")
    >>> s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, nframes=2)
    >>> stored = np.arange(24.0).reshape(4, 6)
    >>> e = Exposure.from_arrays(g.layout.to_readout(stored), s, order="physical")
    >>> e.shape, stored_image(e).shape, bool((stored_image(e).data == stored).all())
    ((2, 12), (4, 6), True)
    """
    ccd = exposure.to_ccddata()
    layout = exposure.geometry.layout
    if layout.identity:
        return ccd
    unc = ccd.uncertainty
    return CCDData(layout.to_stored(ccd.data), unit=ccd.unit, meta=ccd.meta,
                   uncertainty=None if unc is None else type(unc)(layout.to_stored(unc.array)),
                   mask=None if ccd.mask is None else layout.to_stored(np.asarray(ccd.mask)))
