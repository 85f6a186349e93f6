"""Phantom-pixel correction (paper §2.5)."""

import numpy as np

from ...core.errors import StepSkipped
from ..hookspecs import hookimpl
from ..noise_effect import NoiseEffect
from ..step import Kernel, Step

__all__ = ["subtract_phantom"]


def subtract_phantom(exposure):
    """Subtract from every row read the phantom value of its channel (paper §2.5).

    Each row read of each channel is preceded by ``c`` samples of the Video8
    reference voltage, averaged into one phantom value; it tracks the
    amplifier's drift, leakage and 1/f noise, and is subtracted from the 64
    (channel width) pixels of that row read.  Works on ramps and on slopes
    (`fit_ramp` fits the phantom values too), in readout or physical order;
    the reference reads kept aside by `unchop` are corrected too.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        With phantom values (``exposure.phantom``, same unit as the pixels).

    Returns
    -------
    `~spherex_reduce.Exposure`
        A new exposure; its phantom values are consumed (``phantom`` is None),
        so the correction cannot be applied twice.  Uncertainty and mask are
        unchanged (the phantom noise is small, paper §4.1).

    Notes
    -----
    When the exposure has no phantom values (``c = 0``, or already
    subtracted) the step is skipped, stpipe style: the input comes back
    unchanged, with the status keyword set to ``SKIPPED`` and the reason in
    HISTORY and ``PROVENANCE``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, subtract_phantom
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 2, ref_border=1), skip=1, ref_mode="none",
    ...                     phantom_reads=2, nframes=1)
    >>> e = Exposure.from_arrays(np.full((4, 4), 5.0), s, phantom=np.ones((4, 2)) * [1.0, 2.0])
    >>> subtract_phantom(e).data.data[0].tolist()
    [4.0, 4.0, 3.0, 3.0]
    """
    return SubtractPhantomStep()(exposure)


class PhantomKernel(Kernel):
    """`subtract_phantom` on a block: each row read minus its channels' phantom values.

    The pixels become the common type of pixels, phantom values and float32;
    the block's phantom values are consumed (None afterwards).
    """

    def __init__(self, context):
        if not context.has_phantom:
            raise StepSkipped("the input has no phantom values (c = 0, or already subtracted)")
        super().__init__(context)

    @property
    def output(self):
        return self.context.replace(has_phantom=False)

    def apply(self, coefficients, block):
        if block.phantom is None:
            return block.replace(read_phantom=None)
        dtype = np.result_type(block.data.dtype, block.phantom.dtype, np.float32)
        out = block.writable(dtype)
        f, n, ncols = out.shape
        nch = block.phantom.shape[-1]
        per_channel = out.reshape(f, n, nch, ncols // nch)
        np.subtract(per_channel, block.phantom[..., None], out=per_channel)
        return block.replace(data=out, phantom=None, read_phantom=None,
                             owned=block.owned | {"data"})


class SubtractPhantomStep(Step):
    """Subtract each row read's phantom value (`~spherex_reduce.subtract_phantom`)."""

    name, keyword = "subtract_phantom", "S_PHANTM"
    noise_effect = NoiseEffect("subtract_phantom")

    def kernel(self, context):
        return PhantomKernel(context)


@hookimpl
def register_steps():
    return [SubtractPhantomStep]
