"""Read images for the analysis: our FITS format or any 2-D FITS image."""

from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData

from ..errors import FormatError, SpherexReduceError

__all__ = ["read_image"]


def read_image(path, ext=None):
    """A 2-D image from a FITS file as `~astropy.nddata.CCDData` in physical row order.

    Files in this package's format (readout keywords present) are read with
    `spherex_reduce.read`; an image still in readout order (slopes straight
    from the simulator or an on-board processor) is un-chopped first, so rows
    are where they are on the array.  The ``DQ`` flags become the mask.
    Other FITS files: the first 2-D image HDU (or ``ext``), with ``BUNIT`` if
    present.  The header goes to ``meta``; the file is never modified.

    Parameters
    ----------
    path : str or `pathlib.Path`
    ext : int or str, optional
        HDU to read from a file not in this package's format.

    Returns
    -------
    `~astropy.nddata.CCDData`

    Raises
    ------
    SpherexReduceError
        The file holds ramps (3-D); fit the ramps first.
    """
    from ..fits_format import read

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    try:
        exposure = read(path)
    except FormatError:
        exposure = None
    if exposure is not None:
        if exposure.is_ramp:
            raise SpherexReduceError(
                f"{path} holds ramps {exposure.shape}; fit them first (spherex-reduce reduce "
                "with a pipeline that ends in fit_ramp) to get an image"
            )
        if exposure.order == "readout":
            from ..steps import unchop

            exposure = unchop(exposure)
        ccd = exposure.to_ccddata()
        ccd.meta["SCHEDULE"] = exposure.schedule.summary()[:68]
        ccd.meta["INTTIME"] = exposure.schedule.integration_time.to_value(u.s)
        ccd.meta["NFRAMES"] = exposure.schedule.nframes
        return ccd
    with fits.open(path, memmap=True) as hdul:
        hdus = [hdul[ext]] if ext is not None else [h for h in hdul
                                                    if h.data is not None and h.data.ndim == 2]
        if not hdus or hdus[0].data is None or hdus[0].data.ndim != 2:
            raise FormatError(f"{path} has no 2-D image HDU")
        hdu = hdus[0]
        unit = hdu.header.get("BUNIT", hdul[0].header.get("BUNIT", ""))
        try:
            unit = u.Unit(str(unit).strip(), parse_strict="raise") if unit else u.one
        except ValueError as exc:
            raise FormatError(f"BUNIT={unit!r} in {path} is not a unit astropy knows") from exc
        header = hdul[0].header.copy()
        header.update(hdu.header)
        return CCDData(np.array(hdu.data), unit=unit, meta=header)
