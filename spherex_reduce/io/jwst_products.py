"""Products the JWST pipeline opens: ``rate`` and ``rateints`` files (``reduce --format jwst``).

`write_jwst` writes a reduced image (or the images of several integrations)
in the layout of the JWST pipeline's ``rate`` (``rateints``) files, which
`stdatamodels.jwst.datamodels.ImageModel` (``CubeModel``) open and validate,
so that a reference correction and jumps made here go on into JWST's stage 2:

``SCI``
    The slopes (float32), ``BUNIT`` the unit of our image (``DN/s`` for
    ``adu / s``, as JWST spells it).
``ERR``
    ``sqrt(VAR_POISSON + VAR_RNOISE)`` (float32), as in JWST's files.
``DQ``
    Our flags in JWST's bits (`jwst_dq`), uint32.
``VAR_POISSON``, ``VAR_RNOISE``
    The two parts of the slope's variance (float32), from ``fit_ramp``'s
    ``RAMPFIT`` table (`variance_parts`): read noise with the dark current's
    shot noise, and the shot noise of the rate: a ``rate`` file's is our
    ``ERR``'s (``ERR**2 - VAR_RNOISE``: each pixel's expected rate given the
    exposure's slopes, ``fit_ramp``), a ``rateints`` file's that of
    ``max(slope, 0)`` of each integration.
``SXRMETA``
    An extension without data whose header is the primary header of our own
    output (the readout keywords, the steps' keywords and ``HISTORY``), and
    the steps' tables (``PROVENANCE``, ``RAMPFIT`` ...) after it.

The primary header says which model the file is (``DATAMODL``) and when it
was written (``DATE``); nothing in it claims a JWST observation.  Only an
exposure read from a JWST file (its header's ``TELESCOP = 'JWST'``) has its
header cards carried into the primary header, where the JWST pipeline finds
the instrument and the exposure type it needs, without our readout keywords
(a reader puts them there in our meanings: ``NFRAMES`` the groups); the
keywords of any other file keep their own meanings in ``SXRMETA`` (a lab's
``DETECTOR = 5`` or our ``FASTAXIS = 'columns'`` in the primary header would
be read in JWST's meaning, and refused by the schema).
"""

import datetime
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits

from ..core import dq
from ..core.errors import ConfigError
from .atomic import atomic_output
from .fits_write import table_hdu
from .layout import unit_string
from .readers.jwst_level1 import JWST_PIXEL, dms_keywords, dms_view, remove_readout_keywords

__all__ = ["JWST_PIXEL", "jwst_dq", "variance_parts", "write_jwst"]

_J = JWST_PIXEL
#: Each of our bits (`spherex_reduce.core.dq`) and the JWST bits it becomes: a bit that
#: masks a pixel here gets DO_NOT_USE there (the bit JWST's steps test), with the
#: nearest JWST meaning; JWST marks its reference pixels DO_NOT_USE too.
_TO_JWST = {
    dq.DO_NOT_USE: _J["DO_NOT_USE"],
    dq.SATURATED: _J["SATURATED"],
    dq.HOT: _J["OUTLIER"] | _J["DO_NOT_USE"],
    dq.NO_REFERENCE: _J["OTHER_BAD_PIXEL"] | _J["DO_NOT_USE"],
    dq.FEW_READS: _J["DO_NOT_USE"],
    dq.NOT_READ: _J["DROPOUT"] | _J["DO_NOT_USE"],
    dq.JUMP: _J["JUMP_DET"],
    dq.REFERENCE: _J["REFERENCE_PIXEL"] | _J["DO_NOT_USE"],
}
_OTHER = _J["OTHER_BAD_PIXEL"] | _J["DO_NOT_USE"]  # a bit we do not define (a plug-in's)

# cards of a header that describe its own HDU, not the data set
_STRUCTURE = ("SIMPLE", "XTENSION", "BITPIX", "NAXIS", "EXTEND", "NEXTEND", "PCOUNT", "GCOUNT",
              "EXTNAME", "EXTVER", "CHECKSUM", "DATASUM", "BUNIT", "BZERO", "BSCALE", "DATAMODL")


def jwst_dq(flags):
    """Our data-quality flags in JWST's bits.

    ``DO_NOT_USE`` -> ``DO_NOT_USE``; ``SATURATED`` -> ``SATURATED``; ``JUMP``
    -> ``JUMP_DET``; ``REFERENCE`` -> ``REFERENCE_PIXEL | DO_NOT_USE``;
    ``HOT`` (clipped) -> ``OUTLIER | DO_NOT_USE``; ``FEW_READS`` ->
    ``DO_NOT_USE``; ``NOT_READ`` -> ``DROPOUT | DO_NOT_USE``;
    ``NO_REFERENCE`` and any bit we do not define -> ``OTHER_BAD_PIXEL |
    DO_NOT_USE``.  So a pixel our mask leaves out (`~spherex_reduce.core.dq.image_usable`)
    has ``DO_NOT_USE``, and one it keeps has not, reference pixels aside.

    Parameters
    ----------
    flags : array of int
        `spherex_reduce.core.dq` flags (not changed).

    Returns
    -------
    `numpy.ndarray` of uint32

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.core import dq
    >>> from spherex_reduce.io.jwst_products import jwst_dq
    >>> jwst_dq(np.array([0, dq.JUMP, dq.SATURATED | dq.FEW_READS, dq.REFERENCE])).tolist()
    [0, 4, 3, 2147483649]
    """
    flags = np.asarray(flags).astype(np.uint32)
    out = np.zeros(flags.shape, np.uint32)
    rest = flags.copy()
    for bit, jwst in _TO_JWST.items():
        hit = (flags & np.uint32(bit)) != 0
        out[hit] |= np.uint32(jwst)
        rest &= ~np.uint32(bit)
    out[rest != 0] |= np.uint32(_OTHER)
    return out


def variance_parts(exposure, table=None):
    """``(var_rnoise, var_per_rate)`` images of a fit with a read-noise model, or None.

    They are the columns of ``fit_ramp``'s ``RAMPFIT`` table (see
    `~spherex_reduce.fit_ramp`), in the image's row order: the slope's variance
    at zero rate ((unit / s)**2: read noise and the dark current's shot noise)
    and its shot-noise variance per unit of rate (unit / s); the variance of a
    slope ``rate`` is ``var_rnoise + max(rate, 0) * var_per_rate``.

    ``RAMPFIT`` keeps the row order of the fit (its meta ``order``): slopes
    fitted in readout order and un-chopped afterwards take, for each physical
    row, the parts of its first read (a reference row averaged over several
    reads has its variance overstated by the number of reads).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A reduced image.
    table : `~astropy.table.Table`, optional
        The rows of ``RAMPFIT`` to use (e.g. one integration's); default
        ``exposure.tables['RAMPFIT']``.

    Returns
    -------
    tuple of two `numpy.ndarray` of float64, or None
        None when there is no such table, it lacks the columns (a fit
        without ``read_noise``) or its rows do not fit the image.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, fit_ramp
    >>> from spherex_reduce.io.jwst_products import variance_parts
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=0), ref_mode="none",
    ...                     phantom_reads=0, nframes=3, skip=1, frame_time=1.0)
    >>> ramps = (10.0 * np.arange(3))[:, None, None] * np.ones((3, 4, 4))
    >>> rnoise, per_rate = variance_parts(fit_ramp(Exposure.from_arrays(ramps, s),
    ...                                            read_noise=2.0))
    >>> float(rnoise[0, 0])  # 12 * 2**2 / (3 * (3**2 - 1) * 1 s**2)
    2.0
    """
    table = exposure.tables.get("RAMPFIT") if table is None else table
    if table is None or not {"var_rnoise", "var_per_rate"} <= set(table.colnames):
        return None
    parts = tuple(np.asarray(table[name], np.float64) for name in ("var_rnoise", "var_per_rate"))
    fitted = table.meta.get("order", exposure.order)
    if fitted == "readout" and exposure.order == "physical":
        first = exposure.schedule.read_of_row()
        if parts[0].shape[0] != exposure.schedule.n_reads:
            return None
        parts = tuple(np.where(first[:, None] >= 0, p[np.maximum(first, 0)], np.nan)
                      for p in parts)
    elif fitted != exposure.order:
        return None  # re-chopped: not ours to re-order
    return parts if parts[0].shape == exposure.shape else None


def write_jwst(exposure, path, *, slopes=None, flags=None, overwrite=False):
    """Write a reduced image as a JWST ``rate`` file, or integrations as ``rateints``.

    See the module's description for the extensions.  The file is written
    atomically (a temporary file renamed into place), with FITS checksums;
    an existing file is kept unless ``overwrite``.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A reduced image (``fit_ramp`` with a ``read_noise``, so that its
        ``RAMPFIT`` has the variance's parts), in physical row order.  With
        ``slopes``, the reduction of several integrations (its ``RAMPFIT``
        has their rows, with a column ``integration``), which
        `~spherex_reduce.reduce.integrations.reduce_input` gives.
    path : str or `pathlib.Path`
    slopes : array or `~astropy.units.Quantity`, optional
        Each integration's slopes ``(integrations, rows, columns)`` (the
        ``INTSLOPE`` image): a ``rateints`` file (``CubeModel``) of them;
        without, a ``rate`` file (``ImageModel``) of ``exposure``.
    flags : array of int, optional
        Each integration's flags (``INTDQ``), with ``slopes``.
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    path : `pathlib.Path`

    Raises
    ------
    ConfigError
        The fit has no variance parts (no ``read_noise``), or the image is
        in readout order of a chopped schedule.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, fit_ramp
    >>> from spherex_reduce.io.jwst_products import write_jwst
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=0), ref_mode="none",
    ...                     phantom_reads=0, nframes=3, skip=1, frame_time=1.0)
    >>> ramps = (10.0 * np.arange(3))[:, None, None] * np.ones((3, 4, 4))
    >>> rate = fit_ramp(Exposure.from_arrays(ramps, s), read_noise=2.0)
    >>> out = write_jwst(rate, pathlib.Path(tempfile.mkdtemp()) / "x_rate.fits")
    >>> with fits.open(out) as f:  # 10 e/s: shot noise 6 (n**2 + 1) / (5 n (n**2 - 1)) * 10
    ...     print(f[0].header["DATAMODL"], f["SCI"].data[0, 0], f["VAR_POISSON"].data[0, 0],
    ...           f["VAR_RNOISE"].data[0, 0])
    ImageModel 10.0 5.0 2.0
    """
    schedule = exposure.schedule
    g = schedule.geometry
    if exposure.order != "physical" and not np.array_equal(schedule.rows, np.arange(g.nrows)):
        raise ConfigError("the JWST format holds images of the array: un-chop the slopes "
                          "(add the unchop step) to write them in physical row order")
    unit = exposure.unit or u.one
    if slopes is None:
        model = "ImageModel"
        sci = np.asarray(exposure.data.data, np.float64)
        rnoise, per_rate = _parts(exposure, None, "the image")
        flag_images = exposure.dq if exposure.dq is not None else np.zeros(sci.shape, np.uint32)
    else:
        model = "CubeModel"
        sci = np.asarray(slopes.to_value(unit) if isinstance(slopes, u.Quantity) else slopes,
                         np.float64)
        table = exposure.tables.get("RAMPFIT")
        if table is None or "integration" not in table.colnames:
            raise ConfigError("the integrations' fits are not in the RAMPFIT table (a column "
                              "integration): give the reduction of the 4-D file")
        both = [_parts(exposure, table[table["integration"] == k], f"integration {k}")
                for k in range(sci.shape[0])]
        rnoise, per_rate = (np.stack(a) for a in zip(*both, strict=True))
        flag_images = (np.zeros(sci.shape, np.uint32) if flags is None
                       else np.asarray(flags))
    with np.errstate(invalid="ignore"):
        var_poisson = np.maximum(sci, 0.0) * per_rate
        unc = None if slopes is not None else exposure.data.uncertainty
        if unc is not None:  # our ERR's shot noise (fit_ramp's expected rates), where it is
            total = np.asarray(unc.array, np.float64) ** 2 - rnoise
            var_poisson = np.where(np.isfinite(total), np.maximum(total, 0.0), var_poisson)
    unusable = ~np.isfinite(sci)
    var_poisson[unusable] = np.nan
    rnoise = np.where(unusable, np.nan, rnoise)
    err = np.sqrt(var_poisson + rnoise)
    dms = dms_keywords(exposure.header, (g.stored_geometry.nrows, g.stored_geometry.ncols))

    def stored(image):  # the file's orientation: a JWST input's DMS one, as it came
        image = g.layout.to_stored(image)
        return dms_view(image, dms["FASTAXIS"], dms["SLOWAXIS"]) if dms else image

    name = _bunit(unit)
    hdus = [_primary(exposure.header, model, dms),
            _image(stored(sci), "SCI", name), _image(stored(err), "ERR", name),
            fits.ImageHDU(stored(jwst_dq(flag_images)), name="DQ"),
            _image(stored(var_poisson), "VAR_POISSON", _bunit(unit**2)),
            _image(stored(rnoise), "VAR_RNOISE", _bunit(unit**2)),
            fits.ImageHDU(header=_without_structure(schedule.to_header(exposure.header)),
                          name="SXRMETA")]
    hdus[-1].header["ORDER"] = (exposure.order.upper(), "row order of the slopes fitted")
    hdus += [table_hdu(t, name.upper()) for name, t in exposure.tables.items()]
    with atomic_output(path, overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp, checksum=True)
    return Path(path)


def _parts(exposure, table, what):
    parts = variance_parts(exposure, table)
    if parts is None:
        raise ConfigError(f"the JWST format needs the slope variance's parts (VAR_RNOISE, "
                          f"VAR_POISSON) of {what}: give fit_ramp a read_noise (and gain)")
    return parts


def _image(values, name, bunit):
    hdu = fits.ImageHDU(np.asarray(values, np.float32), name=name)
    hdu.header["BUNIT"] = bunit
    return hdu


def _bunit(unit):
    """``BUNIT`` as JWST writes it: ``DN`` for our ``adu``."""
    return unit_string(unit).replace("adu", "DN")


def _without_structure(header):
    out = header.copy()
    for key in _STRUCTURE:
        out.remove(key, ignore_missing=True, remove_all=True)
    for key in [k for k in out if k.startswith("NAXIS")]:
        out.remove(key, ignore_missing=True, remove_all=True)
    return out


def _primary(header, model, dms):
    """``DATAMODL`` and ``DATE``; a JWST file's header cards (not our readout keywords, which
    a reader of it adds in our meanings, but its orientation, subarray and frames per group
    in JWST's: ``dms``, `~spherex_reduce.io.readers.jwst_level1.dms_keywords`), no other
    file's."""
    jwst = header is not None and str(header.get("TELESCOP", "")).strip().upper() == "JWST"
    primary = fits.PrimaryHDU(header=_without_structure(header) if jwst else None)
    h = primary.header
    remove_readout_keywords(h)  # ours (NFRAMES: groups here, frames per group in JWST's)
    if dms:
        for key in ("JWFASTAX", "JWSLOWAX", "JWSTRT1", "JWSTRT2"):
            h.remove(key, ignore_missing=True)
        h.update(dms)
        # JWST's NFRAMES: frames averaged into a group (ours, NFRGRP, written when not 1)
        h["NFRAMES"] = (int(header.get("NFRGRP", 1)), "number of frames per group")
    h.set("EXTEND", True, after="NAXIS")
    h["DATAMODL"] = (model, "stdatamodels model of this file")
    h["DATE"] = (datetime.datetime.now(datetime.UTC).isoformat(timespec="milliseconds")
                 [:23], "UTC date file created")
    h.add_history("written by spherex_reduce (reduce --format jwst); its own keywords and "
                  "tables are in the extension SXRMETA and after it")
    return primary
