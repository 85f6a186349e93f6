"""A reference strategy that streams: the median of each channel's reference pixels.

A complete plugin module (see "Write a streaming strategy" in the plugin guide).
Register it through the ``spherex_reduce`` entry-point group of your package::

    [project.entry-points.spherex_reduce]
    refmedian = "my_package.reference_median"

and select it with ``correct_reference: {strategy: refmedian}``.
"""

import warnings

import numpy as np

from spherex_reduce.plugin import (
    ALL,
    Parameter,
    ReferenceOffsets,
    Strategy,
    hookimpl,
    reference_pixels,
)

__all__ = ["ReferenceMedian"]


class ReferenceMedian(Strategy):
    """One offset per frame and channel: the median of its usable reference pixels.

    It estimates from the reference reads alone (the side block), so the
    ``correct_reference`` step's kernel applies its offsets band by band while
    the file is read once, as for the built-in ``mean``.
    """

    kind, name = "reference", "refmedian"
    parameters = (
        Parameter("min_pixels", 8, (int,), "fewest usable reference pixels for an offset",
                  minimum=1),
    )

    def __init__(self, min_pixels=8):
        self.min_pixels = min_pixels

    def estimate(self, side, context, exposure=None):
        pixels = reference_pixels(side, context.schedule)  # (frames, reads, columns); NaN: unusable
        g = context.geometry
        frames, reads, _ = pixels.shape
        per_channel = (pixels.reshape(frames, reads, g.nchannels, g.channel_width)
                       .transpose(0, 2, 1, 3).reshape(frames, g.nchannels, -1))
        n_used = np.isfinite(per_channel).sum(axis=-1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN channels: NaN
            offsets = np.nanmedian(per_channel, axis=-1)
        offsets[n_used < self.min_pixels] = np.nan  # left uncorrected and flagged
        # shape (frames, channels, 1): one group of columns per channel
        return ReferenceOffsets(offsets[..., None], n_used[..., None],
                                np.zeros_like(n_used)[..., None], [ALL])


@hookimpl
def register_strategies():
    return [ReferenceMedian]
