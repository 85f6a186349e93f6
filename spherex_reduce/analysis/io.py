"""Read images for the analysis: our FITS format or any 2-D FITS image."""

from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData

from ..core.errors import FormatError, SpherexReduceError
from ..core.limits import check_size
from ..io import open_checked
from ..reduce.steps import unchop
from .light import light_sensitive_image, stored_image

__all__ = ["read_image"]


def read_image(path, ext=None, pipeline=None, light=False):
    """A 2-D image from a FITS file as `~astropy.nddata.CCDData` in physical row order.

    Files in this package's format (readout keywords present) are read with
    `spherex_reduce.read`; an image still in readout order (slopes straight
    from the simulator or an on-board processor) is un-chopped first, so rows
    are where they are on the array.  The ``DQ`` flags become the mask.
    Other FITS files: the first 2-D image HDU (or ``ext``), with ``BUNIT`` if
    present.  With ``pipeline``, the file is read as `Pipeline.read
    <spherex_reduce.Pipeline.read>` reads a pipeline's input (the config's
    ``geometry:`` and ``readout:`` sections supply the keywords the file
    lacks), then un-chopped if in readout order.  The header goes to
    ``meta``; the file is never modified.

    Parameters
    ----------
    path : str or `pathlib.Path`
    ext : int or str, optional
        HDU to read from a file not in this package's format (not with ``pipeline``).
    pipeline : `~spherex_reduce.Pipeline`, optional
        Read the file as this pipeline reads its input, e.g. the one
        ``spherex-reduce spectrum -c`` names.
    light : bool
        Only the light-sensitive pixels of an image in this package's format
        (`~spherex_reduce.analysis.light.light_sensitive_image`: the rectangle
        inside the reference pixels, any reference pixel in it masked), for
        statistics of the image.  A file in no known format has no reference
        pixels we know of: it is read whole.

    Returns
    -------
    `~astropy.nddata.CCDData`

    Raises
    ------
    SpherexReduceError
        The file holds ramps (3-D); fit the ramps first.
    FormatError
        The file is truncated, damaged (checksum, see
        `~spherex_reduce.io.checksum_policy`), in this package's
        format but inconsistent, or has no 2-D image.

    Examples
    --------
    A file without readout keywords is a plain image; with a pipeline whose
    ``geometry:``/``readout:`` say how it was read (rows chopped by ``S = 2``),
    it is un-chopped:

    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce import Pipeline
    >>> from spherex_reduce.analysis.io import read_image
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "lab.fits"
    >>> fits.PrimaryHDU(np.arange(8.0)[:, None].repeat(4, axis=1)).writeto(path)
    >>> read_image(path).data[:, 0].tolist()
    [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    >>> lab = Pipeline({
    ...     "geometry": {"nrows": 8, "ncols": 4, "nchannels": 2, "ref_border": 0,
    ...                  "pixel_rate": 1e5},
    ...     "readout": {"skip": 2, "ref_mode": "none", "phantom_reads": 0, "nframes": 2,
    ...                 "frame_time": 1.0},
    ...     "steps": [{"unchop": {}}]})
    >>> read_image(path, pipeline=lab).data[:, 0].tolist()
    [0.0, 4.0, 1.0, 5.0, 2.0, 6.0, 3.0, 7.0]
    """
    path = Path(path)
    if pipeline is not None:
        if ext is not None:
            raise ValueError("read_image: give ext or pipeline, not both")
        exposure = pipeline.read(path)
    else:
        with open_checked(path) as f:  # truncation, checksums, unreadable cards
            if "READOUT" not in f.hdul and "ROWSKIP" not in f.hdul[0].header:
                return _foreign_image(f, path, ext)
            # this package's format: its errors are the answer (no second guess as a plain image)
            exposure = f.exposure()
    if exposure.is_ramp:
        raise SpherexReduceError(
            f"{path} holds ramps {exposure.shape}; fit them first (spherex-reduce reduce "
            "with a pipeline that ends in fit_ramp) to get an image"
        )
    if exposure.order == "readout":
        exposure = unchop(exposure)
    ccd = light_sensitive_image(exposure) if light else stored_image(exposure)
    ccd.meta["SCHEDULE"] = exposure.schedule.summary()[:68]
    ccd.meta["INTTIME"] = exposure.schedule.integration_time.to_value(u.s)
    ccd.meta["NFRAMES"] = exposure.schedule.nframes
    return ccd


def _foreign_image(f, path, ext):
    """The 2-D image of a FITS file not in this package's format (``f``: `open_checked`)."""
    hdul = f.hdul

    try:
        hdus = [hdul[ext]] if ext is not None else list(hdul)
    except (KeyError, IndexError) as exc:
        raise FormatError(f"{path} has no HDU {ext!r}") from exc
    hdus = [h for h in hdus if isinstance(h, (fits.PrimaryHDU, fits.ImageHDU, fits.CompImageHDU))
            and h.header.get("NAXIS", 0) == 2]
    if not hdus:
        raise FormatError(f"{path} has no 2-D image HDU")
    hdu = hdus[0]
    shape = tuple(hdu.shape)
    check_size(8.0 * shape[0] * shape[1], f"the {shape} image of {path}")
    unit = hdu.header.get("BUNIT", hdul[0].header.get("BUNIT", ""))
    try:
        unit = u.Unit(str(unit).strip(), parse_strict="raise") if unit else u.one
    except ValueError as exc:
        raise FormatError(f"BUNIT={unit!r} in {path} is not a unit astropy knows") from exc
    header = hdul[0].header.copy()
    header.update(hdu.header)
    for key in ("CHECKSUM", "DATASUM", "NEXTEND"):
        header.remove(key, ignore_missing=True)
    for key in ("NFRAMES", "INTTIME"):  # used by the photon-noise line: numbers or nothing
        value = header.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not value > 0):
            raise FormatError(f"{path}: keyword {key} = {value!r} is not a positive number")
    f.note_bad_checksums(header)
    return CCDData(np.array(f.physical(hdu), dtype=float), unit=unit, meta=header)
