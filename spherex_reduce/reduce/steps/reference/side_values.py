"""Side reference columns as observations of the drift common to every channel.

The side reference columns of a HxRG (``ref_border``'s ``left`` and ``right``)
belong to the first and last output only, but they are read at every row: their
mean over those outputs samples, at every row read, the drift all channels share
(NGHXRG's correlated pink, a common bias), plus the outer outputs' own drift.  The
``wiener`` strategy adds one such value per read to its estimate of the channels'
mean drift, and so corrects every channel alike.

`side_columns` finds the columns of each channel and parity group; `side_values`
reads them from an exposure (only those columns: a few MB at full size), takes out
each pixel's own level (a raw dark's bias), leaves out pixels and reads far from the
rest, and averages them per read.
"""

import warnings

import numpy as np
from astropy.utils.exceptions import AstropyUserWarning

from .strategies import group_columns, side_column_values
from .telegraph import MAD_TO_SIGMA, nanmedian

__all__ = ["SideValues", "side_columns", "side_values"]

#: A side pixel whose robust scatter is above this many times the median side pixel's
#: is left out (a hot, noisy or flipping pixel that a read-by-read clip would only thin).
_NOISY = 3.0


def side_columns(geometry, acn):
    """The side reference columns of every channel and parity group.

    Parameters
    ----------
    geometry : `~spherex_reduce.DetectorGeometry`
    acn : bool
        Whether the groups are split by the parity of their sample (as
        `~spherex_reduce.reduce.steps.reference.strategies.group_columns`).

    Returns
    -------
    list of list of (int, `numpy.ndarray`)
        For each group, ``(channel, columns)`` of the channels with side columns in it.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.reduce.steps.reference.side_values import side_columns
    >>> g = DetectorGeometry(16, 16, 4, ref_border=2, scan="alternate")
    >>> [(ch, c.tolist()) for ch, c in side_columns(g, acn=False)[0]]
    [(0, [0, 1]), (3, [14, 15])]
    """
    mask = geometry.reference_column_mask()
    groups = group_columns(geometry, acn)
    out = []
    for p in range(groups.shape[1]):
        part = []
        for ch in range(groups.shape[0]):
            cols = groups[ch, p][groups[ch, p] >= 0]
            cols = np.sort(cols[mask[cols]])
            if cols.size:
                part.append((ch, cols))
        out.append(part)
    return out


class SideValues:
    """The side values of one exposure: ``values[p]`` ``(L, r)`` for group ``p`` at the
    reads ``reads`` (``r``), each the mean over channels of their usable side pixels'
    mean; ``left_out`` pixels never used (noisy), ``clipped`` pixel reads left out."""

    def __init__(self, values, reads, left_out, clipped):
        self.values, self.reads = values, reads
        self.left_out, self.clipped = left_out, clipped


def _deviations(v):
    """Each pixel's departure from the median of the channel's other side pixels of its
    read (``v (L, r, n)``; 0 without another pixel): the read's shared drift taken out,
    and a departure with the noise of a pixel and its peers whatever ``n`` (from the
    median of all ``n``, one of an odd number of pixels would depart by 0, and the
    others' robust scatter would clip a few percent of good reads)."""
    dev = np.empty_like(v)
    for j in range(v.shape[2]):
        others = np.delete(v, j, axis=2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # no other usable pixel
            med = (nanmedian(others, 2) if others.shape[2]
                   else np.full(v.shape[:2], np.nan))
        dev[..., j] = np.where(np.isfinite(med), v[..., j] - med, v[..., j] * 0.0)
    return dev


def _scatter(dev):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN pixel
        return MAD_TO_SIGMA * np.nanmedian(np.abs(dev), axis=(0, 1))


def _channel_means(v, sigma):
    """``v (L, r, n)`` of one channel's side pixels: the per-read mean of the usable
    ones after each pixel's level is taken out, and the pixels and reads left out.
    With ``L = 1`` (an image, or one frame) the level is the column's: the bias of a
    single raw frame stays in its side values."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN pixel
        # each pixel's own level (a raw frame's bias): its median over the frames (the same
        # pattern taken from every frame: no change to a slope); an image, its column's
        v = v - (nanmedian(v, 0) if v.shape[0] > 1 else np.nanmedian(v, axis=(0, 1)))
        # a noisy pixel: its scatter about the median of all, the read's shared drift out
        scatter = _scatter(v - nanmedian(v, 2)[..., None])
    typical = np.nanmedian(scatter) if np.isfinite(scatter).any() else np.nan
    with np.errstate(invalid="ignore"):
        noisy = ~(scatter <= _NOISY * typical) if typical > 0 else ~np.isfinite(scatter)
    # the reads' clip against the other pixels kept (a noisy pixel left out is left out of
    # the others' medians too, as a flagged one)
    dev = _deviations(np.where(noisy, np.nan, v))
    scatter = _scatter(dev)
    with np.errstate(invalid="ignore"):
        far = np.abs(dev) > sigma * np.where(scatter > 0, scatter, np.inf)
    keep = np.isfinite(v) & ~noisy & ~far
    n = keep.sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, np.where(keep, v, 0.0).sum(axis=2) / np.maximum(n, 1), np.nan)
    return mean, int(noisy.sum()), int((np.isfinite(v) & ~noisy & far).sum())


def side_values(exposure, groups, sigma):
    """The side values of an exposure, as `SideValues`.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps or an image, in readout or physical order.
    groups : list of list of (int, `numpy.ndarray`)
        `side_columns` of its geometry.
    sigma : float
        A pixel's read beyond this many of its robust deviations from the
        channel's other side pixels of that read is left out.

    Returns
    -------
    `SideValues`
        Each channel's mean less its median over the frame's reads, averaged over
        the channels that have a usable pixel in the read; a read where none has
        takes its neighbours' values (linear interpolation over reads), and a frame
        without any usable side pixel is warned of (its side values are 0: the
        estimate then has the reference rows alone, with weights solved for side
        values too).
    """
    s = exposure.schedule
    vals, _, cols = side_column_values(exposure)  # (L, r, side columns), NaN: unusable
    reads = (s.active_read_indices if exposure.order == "readout"
             else s.read_of_row()[s.geometry.active_rows])
    order = np.argsort(reads, kind="stable")
    reads, block = np.asarray(reads)[order], vals[:, order]
    values, left_out, clipped = [], 0, 0
    for part in groups:
        means = []
        for _, c in part:
            mean, noisy, far = _channel_means(block[..., np.searchsorted(cols, c)], sigma)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a frame without pixels
                # each channel's offset in the frame out, so that a read one channel misses
                # does not take the others' offset (the side constant absorbs the rest)
                means.append(mean - np.nanmedian(mean, axis=1, keepdims=True))
            left_out, clipped = left_out + noisy, clipped + far
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a read without pixels
            v = np.nanmean(np.stack(means), axis=0)  # (L, r)
        values.append(_fill(v, reads))
    return SideValues(values, reads, left_out, clipped)


def _fill(v, reads):
    """Reads without a value: linear interpolation over the frame's reads (flat beyond)."""
    bad = ~np.isfinite(v)
    if not bad.any():
        return v
    v = v.copy()
    empty = 0
    for f in np.flatnonzero(bad.any(axis=1)):
        ok = ~bad[f]
        v[f] = np.interp(reads, reads[ok], v[f, ok]) if ok.any() else 0.0
        empty += not ok.any()
    if empty:
        warnings.warn(f"correct_reference (wiener): {empty} frame(s) without a usable side "
                      "reference pixel: their drift comes from the reference rows alone",
                      AstropyUserWarning, stacklevel=3)
    return v
