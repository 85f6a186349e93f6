"""The ``destripe`` step: subtract each row's sigma-clipped median."""

import numpy as np
from astropy.stats import sigma_clipped_stats

from spherex_reduce import SpherexReduceError, Step
from spherex_reduce.plugin import Parameter, hookimpl

__all__ = ["DestripeStep", "destripe"]


def destripe(exposure, sigma=3.0):
    """Subtract from every physical row the sigma-clipped median of its active pixels.

    Parameters
    ----------
    exposure : `spherex_reduce.Exposure`
        In physical order (run ``unchop`` first); ramps or a 2-D image.
    sigma : float
        Clipping threshold in standard deviations.

    Returns
    -------
    `spherex_reduce.Exposure`
        New exposure; the row medians subtracted are in the table ``DESTRIPE``
        (for ramps, the median over frames of each row's value).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=1), skip=1, ref_reads=0,
    ...                     phantom_reads=0, nframes=1)
    >>> img = np.arange(8.0)[:, None] * np.ones((8, 8))       # each row a constant
    >>> e = Exposure.from_arrays(img, s, order="physical")
    >>> float(np.abs(destripe(e).data.data).max())
    0.0
    """
    if exposure.order != "physical":
        raise SpherexReduceError("destripe needs rows in physical order: run unchop before it")
    data = exposure.data.data
    columns = ~exposure.geometry.reference_column_mask()
    values = np.asarray(data[..., columns], dtype=np.float64)
    mask = exposure.data.mask
    if mask is not None:
        values = np.ma.masked_array(values, mask=np.asarray(mask)[..., columns] != 0)
    _, median, _ = sigma_clipped_stats(values, sigma=sigma, axis=-1)
    median = np.nan_to_num(np.asarray(median, dtype=np.float64))  # fully masked rows: untouched
    out = (data - median[..., None]).astype(data.dtype, copy=False)
    from astropy.table import Table

    per_row = median if median.ndim == 1 else np.median(median, axis=0)
    tables = {**exposure.tables,
              "DESTRIPE": Table({"row": np.arange(per_row.size), "median": per_row})}
    return exposure.replace(data=out, tables=tables)


class DestripeStep(Step):
    """Row-median destriping (example plugin step)."""

    name = "destripe"
    keyword = "S_DESTRP"
    parameters = (Parameter("sigma", 3.0, (float,), "clipping threshold (standard deviations)",
                            minimum=0.5),)

    def run(self, exposure, sigma):
        return destripe(exposure, sigma=sigma)


@hookimpl
def register_steps():
    return [DestripeStep]
