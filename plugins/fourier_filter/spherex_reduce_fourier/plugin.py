"""The ``fourier`` reference strategy (paper §4.3's Fourier-space alternative).

Channel offsets are constant along the columns of a channel, so all their
power lies on the horizontal axis (``k_y = 0``) of the image's 2-D Fourier
transform (the paper's Fig. 7); so does the even/odd (ACN) offset.  Zeroing
that axis removes both without reference pixels, but also removes every
column-constant structure of the scene.
"""

import numpy as np
from astropy.table import Table

from spherex_reduce import dq
from spherex_reduce.plugin import Parameter, Strategy, hookimpl

__all__ = ["FourierReference", "fourier_filter"]


def fourier_filter(image, width=0, keep_mean=True):
    """What the horizontal-axis filter removes from a 2-D image.

    Parameters
    ----------
    image : array_like
        2-D image ``(rows, columns)``; NaN pixels are replaced by the median
        of the finite ones while filtering.
    width : int
        Remove the Fourier modes with ``|k_y| <= width`` (in FFT bins); 0 is
        the horizontal axis alone.
    keep_mean : bool
        Keep the ``k = 0`` mode (the image's mean level).

    Returns
    -------
    `numpy.ndarray`
        The removed component; ``image - removed`` is the filtered image.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce_fourier import fourier_filter
    >>> img = np.zeros((8, 8)) + np.repeat([1.0, 3.0], 4)   # two channel offsets
    >>> np.round(img - fourier_filter(img), 12).tolist()[0]
    [2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0]
    """
    img = np.array(image, dtype=np.float64)
    bad = ~np.isfinite(img)
    if bad.all():
        return np.zeros_like(img)
    if bad.any():
        img[bad] = np.median(img[~bad])
    spec = np.fft.rfft2(img)
    keep = np.zeros(spec.shape, bool)
    ky = np.fft.fftfreq(img.shape[0]) * img.shape[0]
    keep[np.abs(ky) <= width, :] = True
    if keep_mean:
        keep[0, 0] = False
    removed = np.fft.irfft2(np.where(keep, spec, 0), s=img.shape)
    return removed


class FourierReference(Strategy):
    """Remove channel offsets by zeroing the horizontal axis in Fourier space (paper §4.3).

    Works frame by frame on ramps and on 2-D images.  The ``REFOFFS`` table
    records, per frame and channel, the mean of what was removed (parity -1),
    the pixels used and 0 clipped.
    """

    kind, name = "reference", "fourier"
    parameters = (
        Parameter("width", 0, (int,), "remove Fourier rows |k_y| <= width (bins)", minimum=0),
        Parameter("keep_mean", True, (bool,), "keep the image's mean level (k = 0)"),
    )

    def __call__(self, exposure, width=0, keep_mean=True):
        nd = exposure.data
        data = np.asarray(nd.data)
        frames = data.reshape(-1, *data.shape[-2:])
        mask = None if exposure.dq is None else (exposure.dq != 0).reshape(frames.shape)
        out = np.empty(frames.shape, dtype=np.result_type(data.dtype, np.float32))
        g = exposure.geometry
        nch, w = g.nchannels, g.channel_width
        offsets = np.zeros((frames.shape[0], nch))
        used = np.zeros((frames.shape[0], nch), int)
        for f, frame in enumerate(frames):
            img = np.array(frame, dtype=np.float64)
            if mask is not None:
                img[mask[f]] = np.nan
            removed = fourier_filter(img, width=width, keep_mean=keep_mean)
            out[f] = frame - removed
            fin = np.isfinite(img).reshape(img.shape[0], nch, w)
            r = removed.reshape(img.shape[0], nch, w)
            used[f] = fin.sum(axis=(0, 2))
            offsets[f] = (r * fin).sum(axis=(0, 2)) / np.maximum(used[f], 1)
        cols = {}
        if data.ndim == 3:
            cols["frame"] = np.repeat(np.arange(frames.shape[0]), nch)
        cols["channel"] = np.tile(np.arange(nch), frames.shape[0])
        cols["parity"] = np.full(offsets.size, -1)
        cols["offset"] = offsets.ravel()  # data unit (in the table's BUNIT)
        cols["n_used"] = used.ravel()
        cols["n_clipped"] = np.zeros(offsets.size, int)
        cols["flag"] = np.zeros(offsets.size, np.uint16) | (used.ravel() == 0) * dq.NO_REFERENCE
        tables = dict(exposure.tables)
        tables["REFOFFS"] = Table(cols, meta={"strategy": self.name,
                                              "bunit": str(exposure.unit or "")})
        header = exposure.header.copy()
        header["REFSTRAT"] = (self.name, "reference correction strategy")
        return exposure.replace(data=out.reshape(data.shape), tables=tables, header=header)


@hookimpl
def register_strategies():
    return [FourierReference]
