"""Phantom-pixel correction (paper §2.5)."""

import numpy as np

from ..errors import StepSkipped

__all__ = ["subtract_phantom"]


def _subtract_rows(values, phantom, width):
    """``values (..., n, ncols) - phantom (..., n, nch)`` repeated over each channel's columns."""
    values = np.asarray(values)
    dtype = np.result_type(values.dtype, phantom.dtype, np.float32)
    out = np.empty(values.shape, dtype=dtype)
    lead = values.shape[:-2]
    n, ncols = values.shape[-2:]
    nch = ncols // width
    # one frame at a time: temporaries stay the size of a frame
    for idx in np.ndindex(*lead):
        np.subtract(values[idx].reshape(n, nch, width), phantom[idx][:, :, None],
                    out=out[idx].reshape(n, nch, width))
    return out


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

    Raises
    ------
    StepSkipped
        The exposure has no phantom values (``c = 0``, or already subtracted).

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
    if exposure.phantom is None:
        raise StepSkipped("the input has no phantom values (c = 0, or already subtracted)")
    width = exposure.geometry.channel_width
    data = _subtract_rows(exposure.data.data, exposure.phantom, width)
    reference = exposure.reference
    if reference is not None and reference.phantom is not None:
        reference = reference.replace(
            data=_subtract_rows(reference.data, reference.phantom, width), phantom=None)
    return exposure.replace(data=data, phantom=None, reference=reference)
