"""The expected 2-D FFT of a reduced slope image near the origin (paper Fig. 7), no random numbers.

`~spherex_reduce.analysis.forecast` bins ``E|FFT|²`` of every cell of the
Fourier plane into P(k); `forecast_fft_magnitude` returns the cells
themselves, as `~spherex_reduce.analysis.fft_magnitude` returns them for one
image: ``sqrt(E|FFT|² / (ny · nx))`` of the light-sensitive pixels, centred
and cropped to the origin.  The image's mean is subtracted (the ``k = 0``
cell is zero), as `~spherex_reduce.analysis.fft_magnitude` does.
"""

import numpy as np
from astropy import units as u

from ..spectrum import FFTImage
from .engine import add_white_parts, prepare_forecast, stored_planes
from .rows import NODES

__all__ = ["forecast_fft_magnitude"]


def forecast_fft_magnitude(scene, pipeline=None, size=129, *, nodes=NODES):
    """``sqrt(E|FFT|²)`` of a scene's reduced slope image, centred and cropped (Fig. 7).

    The expectation of what `~spherex_reduce.analysis.fft_magnitude` gives
    for ``simulate(scene)`` reduced by ``pipeline`` (its light-sensitive
    pixels), squared: ``magnitude²`` is the expected power of each Fourier
    cell, in (e/s)² pix².

    Parameters
    ----------
    scene, pipeline
        As `~spherex_reduce.analysis.forecast` (the same scenes and steps).
    size : int
        Cells kept along each axis around ``k = 0`` (odd; clipped to the image).
    nodes : int
        As `~spherex_reduce.analysis.forecast`.

    Returns
    -------
    `~spherex_reduce.analysis.FFTImage`
        ``magnitude`` (e/s · pixel), ``kx``, ``ky`` (rad/pixel).

    Raises
    ------
    SpherexReduceError, ConfigError
        As `~spherex_reduce.analysis.forecast`.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.fft import forecast_fft_magnitude
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0},
    ...          "noise": {"components": [{"name": "w", "alpha": 2e-3}]}}
    >>> f = forecast_fft_magnitude(scene, size=5)
    >>> (f.magnitude.value**2).round(1)[2]   # white: the pixel variance, 0 at k = 0
    array([1861.9, 1861.9,    0. , 1861.9, 1861.9])
    """
    sc, red, rows, cols, comps = prepare_forecast(scene, pipeline)
    parts, (ny, nx) = stored_planes(sc, red, rows, cols, comps, nodes)
    add_white_parts(sc, red, parts, (ny, nx))  # Poisson noise, pixel populations, a clip's
    half = np.zeros((ny, nx // 2 + 1))
    for part in parts.values():
        half += part
    plane = np.empty((ny, nx))  # a real image: E|Y(-k)|² = E|Y(k)|²
    plane[:, :nx // 2 + 1] = half
    j = np.arange(nx // 2 + 1, nx)
    plane[:, j] = half[(-np.arange(ny)) % ny][:, nx - j]
    plane[0, 0] = 0.0  # the mean is subtracted
    return FFTImage.around_origin(np.sqrt(np.maximum(plane, 0.0) / (ny * nx)), size,
                                  u.electron / u.s)
