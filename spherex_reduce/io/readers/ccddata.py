"""A reduced image as astropy's `~astropy.nddata.CCDData`: `read_ccddata`, and the format
``'spherex_reduce'`` of astropy's I/O registry (``CCDData.read(path, format=...)``).

astropy's own FITS reader of `~astropy.nddata.CCDData` looks for an uncertainty in
an extension ``UNCERT`` and a mask in ``MASK`` (a mask of every non-zero value):
given ``hdu_uncertainty='ERR', hdu_mask='DQ'`` it would mask every informational
flag too (``REFERENCE``, ``JUMP``, ``SATURATED`` on a slope).  This reader reads
the file as `~spherex_reduce.read` does and keeps its meaning: the mask holds the
unusable pixels only (`~spherex_reduce.core.dq.image_usable`), and every bit stays
in ``flags``.  It is registered with astropy when this module is imported, which
``from spherex_reduce.io import read_ccddata`` does (``import spherex_reduce``
alone imports no astropy, to start fast).
"""

import numpy as np
from astropy.io import registry
from astropy.nddata import CCDData, StdDevUncertainty

from ...core.errors import FormatError
from .read_exposure import read

__all__ = ["FORMAT", "read_ccddata"]

#: The name of the format in astropy's I/O registry.
FORMAT = "spherex_reduce"


def read_ccddata(path, verify_checksum=None, **kwargs):
    """A 2-D image written by `~spherex_reduce.write` as `~astropy.nddata.CCDData`.

    Also ``CCDData.read(path, format='spherex_reduce')`` (and what passes
    its keywords on to it, e.g. ``ccdproc.combine(paths, format='spherex_reduce')``)
    once this function has been imported.

    Parameters
    ----------
    path : str or `pathlib.Path`
        A FITS file in this package's layout holding a 2-D image (a reduced
        exposure); never changed.
    verify_checksum : bool, optional
        As for `~spherex_reduce.read`.
    **kwargs
        More arguments of `~spherex_reduce.read` (``dq_bits``, ``input``, ...).

    Returns
    -------
    `~astropy.nddata.CCDData`
        ``data`` as stored (float32 for this package's products), ``unit``
        from ``BUNIT``, ``uncertainty`` a `~astropy.nddata.StdDevUncertainty`
        (``ERR``; None without it), ``mask`` True where the pixel is unusable
        (a ``DQ`` bit other than ``JUMP``, ``SATURATED`` and ``REFERENCE``),
        ``flags`` the ``DQ`` bits (uint32; None without ``DQ``) and ``meta``
        the primary header, with the readout keywords; arrays of its own,
        writable (ccdproc scales in place).

    Raises
    ------
    FormatError
        The file holds ramps, not an image (or as `~spherex_reduce.read`).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from astropy.nddata import CCDData
    >>> from spherex_reduce import fit_ramp, write
    >>> from spherex_reduce.io import read_ccddata
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> path = write(fit_ramp(example_raw_exposure(seed=1)),
    ...              pathlib.Path(tempfile.mkdtemp()) / "slopes.fits")
    >>> ccd = CCDData.read(path, format="spherex_reduce")
    >>> ccd.unit, type(ccd.uncertainty).__name__, ccd.mask.dtype
    (Unit("electron / s"), 'StdDevUncertainty', dtype('bool'))
    """
    exposure = read(path, verify_checksum=verify_checksum, **kwargs)
    if exposure.is_ramp:
        raise FormatError(f"{path}: SCI holds ramps {exposure.shape}, not an image: reduce it "
                          "first (e.g. with fit_ramp) or read it with spherex_reduce.read")
    ccd = exposure.to_ccddata()  # its arrays are read's, read-only: copies the caller owns
    return CCDData(np.array(ccd.data), unit=ccd.unit, meta=ccd.meta,
                   uncertainty=None if ccd.uncertainty is None else StdDevUncertainty(
                       np.array(ccd.uncertainty.represent_as(StdDevUncertainty).array)),
                   mask=None if ccd.mask is None else np.array(ccd.mask),
                   flags=None if exposure.dq is None else np.array(exposure.dq))


registry.register_reader(FORMAT, CCDData, read_ccddata, force=True)
