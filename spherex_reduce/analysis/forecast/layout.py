"""Which cell of the readout frame's Fourier plane holds each cell of the stored image's.

The forecast's engine (`spherex_reduce.analysis.forecast.rows`) computes
``E|FFT|²`` of the light-sensitive rectangle in the readout frame, where the
reads run; the spectrum is measured on the stored image
(`~spherex_reduce.analysis.light.light_sensitive_image`).  With channels as
columns the two are the same image.  With channels as rows
(`~spherex_reduce.core.channel_layout`) the stored image is the frame's
transpose, so its ``FFT`` is the frame's transposed: the stored cell
``(k_y, k_x)`` is the frame's ``(k_x, k_y)``, and where that falls outside the
frame's rfft half, the frame's ``(-k_x, -k_y)`` (``E|FFT|²`` of a real image
is even in ``k``).  The rows layout has no flips; a flip would map ``k`` to
``-k`` along one axis, the same ``|k|`` and the ``k_y = 0`` row to itself, so
it would not change binned power.  Quadrants (four flipped, side-by-side
blocks) are not a transpose and are refused by the forecast.
"""

import numpy as np

__all__ = ["frame_cells", "transposed"]


def transposed(geometry):
    """True when the stored image is the transpose of the readout frame (``channels:
    rows``), False when it is the frame (``columns``).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.analysis.forecast.layout import transposed
    >>> transposed(DetectorGeometry(8, 8, 2, ref_border=0, channels="rows"))
    True
    """
    return geometry.layout.channels == "rows"


def frame_cells(ky, kx, frame_shape, is_transposed):
    """The readout frame's rfft cells holding the stored image's cells ``(ky, kx)``.

    Parameters
    ----------
    ky, kx : array_like of int
        Cells of the stored light-sensitive image's rfft2 plane (``0 <= ky <
        ny``, ``0 <= kx <= nx // 2``), any matching shapes.
    frame_shape : tuple of int
        ``(rows, columns)`` of the light-sensitive rectangle in the readout
        frame.
    is_transposed : bool
        Whether the stored image is the frame's transpose (`transposed`).

    Returns
    -------
    tuple of `numpy.ndarray`
        ``(ky, kx)`` of the frame's rfft2 plane (``kx <= columns // 2``) whose
        ``E|FFT|²`` is that of the stored cells.

    Examples
    --------
    A 4 x 6 frame is a 6 x 4 stored image: stored ``(5, 1)`` is frame ``(1, 5)``,
    outside the frame's rfft half, so frame ``(-1, -5) = (3, 1)``.

    >>> from spherex_reduce.analysis.forecast.layout import frame_cells
    >>> [a.tolist() for a in frame_cells([5, 2], [1, 2], (4, 6), True)]
    [[3, 2], [1, 2]]
    """
    ky, kx = np.asarray(ky), np.asarray(kx)
    if not is_transposed:
        return ky, kx
    ny, nx = frame_shape
    fy, fx = kx, ky
    mirror = fx > nx // 2
    return np.where(mirror, (-fy) % ny, fy), np.where(mirror, nx - fx, fx)
