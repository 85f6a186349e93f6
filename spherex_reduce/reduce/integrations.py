"""Files of several integrations: a 4-D ``SCI`` (integrations, groups, rows, columns).

This is the JWST "uncal" layout: each integration is a ramp of ``groups``
reads of the array.  `reduce_integrations` reads one integration at a time
(`spherex_reduce.read` with ``integration=``, the file's header and the
pipeline's ``geometry:``/``readout:`` for the keywords it lacks), runs the
pipeline on it, which must turn it into an image (``fit_ramp``), and combines
the images with `combine_integrations`: the inverse-variance weighted mean of
the usable slopes of each pixel.  `reduce_input` is what ``spherex-reduce
reduce`` does with one input, whatever its layout.

The output file (`Integrations.write`) holds the mean as ``SCI``/``ERR``/``DQ``
and the per-integration slopes, their uncertainties and flags as the image
extensions ``INTSLOPE``, ``INTERR`` and ``INTDQ`` (integrations, rows,
columns); the tables of the steps (``PROVENANCE``, ``RAMPFIT`` ...) hold the
rows of every integration, with a first column ``integration``.
"""

from dataclasses import dataclass

import numpy as np
from astropy import units as u
from astropy.nddata import StdDevUncertainty
from astropy.table import Table, vstack

from ..core import dq
from ..core.errors import ConfigError
from ..core.exposure import Exposure
from ..core.limits import check_size
from ..io import integration_count, read, write
from ..io.jwst_products import variance_parts

__all__ = [
    "INTEGRATION_IMAGES",
    "Integrations",
    "combine_integrations",
    "reduce_input",
    "reduce_integrations",
]

#: The image extensions of the per-integration results in an output file.
INTEGRATION_IMAGES = ("INTSLOPE", "INTERR", "INTDQ")


@dataclass(frozen=True, eq=False)
class Integrations:
    """The reduction of several integrations: their weighted mean and each one's image.

    Attributes
    ----------
    exposure : `~spherex_reduce.Exposure`
        The weighted mean (2-D), with its uncertainty and flags.
    slopes, errors : `~astropy.units.Quantity`
        Each integration's image and its standard deviation, shape
        (integrations, rows, columns).
    flags : `numpy.ndarray` of uint32
        Each integration's `spherex_reduce.core.dq` flags, same shape.
    """

    exposure: Exposure
    slopes: u.Quantity
    errors: u.Quantity
    flags: np.ndarray

    def images(self):
        """The image extensions of the per-integration results, as `write` takes them."""
        return dict(zip(INTEGRATION_IMAGES,
                        (self.slopes, self.errors, self.flags.astype(np.int32)), strict=True))

    def write(self, path, overwrite=False):
        """Write the mean and the ``INTSLOPE``/``INTERR``/``INTDQ`` extensions to ``path``."""
        return write(self.exposure, path, overwrite=overwrite, images=self.images())


def _parts(result, k):
    """``(slope, sigma, flags)`` arrays of integration ``k``'s reduced image."""
    if result.is_ramp:
        raise ConfigError(f"integration {k} is still ramps after the pipeline: a 4-D SCI is "
                          "reduced to one image per integration, so the pipeline must fit the "
                          "ramps (add fit_ramp)")
    unc = result.data.uncertainty
    if unc is None:
        sigma = np.full(result.shape, np.nan)
    else:
        sigma = unc.represent_as(StdDevUncertainty).array
    flags = np.zeros(result.shape, np.uint32) if result.dq is None else result.dq
    return result.data.data, sigma, flags


def combine_integrations(results):
    """The inverse-variance weighted mean of the images of several integrations.

    A slope is used if it is finite and its flags are only informational
    (`~spherex_reduce.core.dq.image_usable`).  When every integration was
    fitted with a read-noise model (``fit_ramp``'s ``read_noise``: its
    ``RAMPFIT`` table has ``var_rnoise`` and ``var_per_rate``), a slope's
    weight is ``1 / (var_rnoise + rate * var_per_rate)`` with the rate
    *pooled over the integrations* (first the read-noise-weighted mean, then
    the result once more), as stcal does: a weight from an integration's own
    measured slope would favour the integrations that fluctuated low, biasing
    the mean low (-3.6 % for 4 integrations of 6 groups of 1.5 s at 3 e/s and 5 e read
    noise).  Otherwise the weight is ``1 / sigma**2``; a pixel where a used
    slope has no finite, positive uncertainty is the plain mean of its used
    slopes, with uncertainty NaN.  A pixel with no usable slope is NaN,
    flagged `~spherex_reduce.core.dq.DO_NOT_USE` and the flags of its
    integrations; a pixel with usable slopes carries the informational
    flags (``JUMP``, ``SATURATED``, ``REFERENCE``) of all its integrations.

    Parameters
    ----------
    results : sequence of `~spherex_reduce.Exposure`
        One reduced 2-D image per integration, of one shape and unit; never
        modified.

    Returns
    -------
    `Integrations`
        Its exposure is the first image's (header, tables of every
        integration with a column ``integration``) with the mean; the
        uncertainty is ``1 / sqrt(sum(1 / sigma**2))``.

    Raises
    ------
    ConfigError
        An integration is still ramps (the pipeline lacks ``fit_ramp``).

    Notes
    -----
    The weights are as good as the uncertainties: ``fit_ramp``'s from the
    residuals of a few groups scatter from pixel to pixel, and so do the
    weights; its ``read_noise`` gives model uncertainties instead.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce.reduce.integrations import combine_integrations
    >>> s = ReadoutSchedule(DetectorGeometry(2, 2, 1, ref_border=0), ref_mode="none",
    ...                     phantom_reads=0, nframes=2)
    >>> a = Exposure.from_arrays(np.full((2, 2), 1.0), s, uncertainty=np.full((2, 2), 1.0))
    >>> b = Exposure.from_arrays(np.full((2, 2), 4.0), s, uncertainty=np.full((2, 2), 2.0),
    ...                          mask=np.eye(2, dtype=bool))
    >>> mean = combine_integrations([a, b]).exposure
    >>> mean.data.data.tolist()  # (1/1 + 4/4) / (1/1 + 1/4) off the diagonal
    [[1.0, 1.6], [1.6, 1.0]]
    """
    results = list(results)
    if not results:
        raise ValueError("no integrations to combine")
    first = results[0]
    for k, result in enumerate(results):
        _parts(result, k)  # each one an image
        if result.shape != first.shape or result.unit != first.unit:
            raise ValueError(f"integration {k} has shape {result.shape} and unit {result.unit}, "
                             f"integration 0 {first.shape} and {first.unit}")
    slopes, sigma, flags = (np.stack(a) for a in zip(*(_parts(r, k)
                                                       for k, r in enumerate(results)),
                                                     strict=True))
    parts = [variance_parts(r) for r in results]
    if all(p is not None for p in parts):
        rnoise, per_rate = (np.stack(a) for a in zip(*parts, strict=True))
        sigma_used = _pooled_sigma(slopes, flags, rnoise, per_rate)
    else:
        sigma_used = sigma
    mean, err, mflags = _weighted_mean(slopes, sigma_used, flags)
    unit = first.unit or u.one
    header = first.header.copy()
    header.remove("SXRINT", ignore_missing=True)
    header["SXRNINT"] = (len(results), "integrations averaged (INTSLOPE INTERR INTDQ)")
    header.add_history(f"inverse-variance weighted mean of {len(results)} integrations; "
                       "each integration's image in INTSLOPE, INTERR, INTDQ")
    exposure = first.replace(data=mean, uncertainty=err, dq=mflags, header=header,
                             tables=_stacked_tables([r.tables for r in results]))
    return Integrations(exposure, slopes * unit, sigma * unit, flags)


def _pooled_sigma(slopes, flags, rnoise, per_rate):
    """Each integration's standard deviation for the rate pooled over the integrations:
    ``sqrt(var_rnoise + max(rate, 0) * var_per_rate)``, the rate first the mean weighted by
    ``1 / var_rnoise``, then the mean weighted by the result."""
    sigma = np.sqrt(rnoise)
    for _ in range(2):
        rate, _, _ = _weighted_mean(slopes, sigma, flags)
        with np.errstate(invalid="ignore"):
            sigma = np.sqrt(rnoise + np.maximum(np.nan_to_num(rate), 0.0) * per_rate)
    return sigma


def _weighted_mean(slopes, sigma, flags):
    """Mean, standard deviation and flags over axis 0 (see `combine_integrations`)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        usable = np.isfinite(slopes) & dq.image_usable(flags)
        weighed = usable & np.isfinite(sigma) & (sigma > 0)
        weighted = (usable == weighed).all(axis=0)  # every used slope has a weight
        w = np.where(weighted, np.where(weighed, 1.0 / sigma**2, 0.0), usable.astype(float))
        total = w.sum(axis=0)
        mean = (w * np.where(usable, slopes, 0.0)).sum(axis=0) / total
        err = np.where(weighted, 1.0 / np.sqrt(total), np.nan)
    none = ~usable.any(axis=0)
    mean[none] = np.nan
    err[none] = np.nan
    # the informational flags of every integration (JUMP, SATURATED ...) carry over, as in
    # stcal: a pixel saturated in one integration says SATURATED
    anyflag = np.bitwise_or.reduce(flags, axis=0)
    mflags = np.where(none, anyflag | dq.DO_NOT_USE, anyflag & dq.INFORMATIONAL)
    return mean, err, mflags.astype(np.uint32)


def _stacked_tables(tables):
    """Each table name's rows of every integration, with a first column ``integration``."""
    out = {}
    for name in tables[0]:
        parts = []
        for k, t in enumerate(tables):
            if name in t:
                part = Table(t[name], copy=True)
                part.add_column(np.full(len(part), k, np.int16), name="integration", index=0)
                parts.append(part)
        out[name] = vstack(parts, metadata_conflicts="silent")
    return out


def reduce_integrations(path, pipeline, *, progress=False, threads=None):
    """Reduce every integration of a file with a 4-D ``SCI`` and combine them.

    Parameters
    ----------
    path : str or `pathlib.Path`
        FITS file whose ``SCI`` is (integrations, groups, rows, columns);
        opened read-only, checked once and never changed.
    pipeline : `~spherex_reduce.Pipeline`
        Run on each integration (a ramp of ``groups`` frames); it must end
        in an image (``fit_ramp``).  Its ``geometry:``/``readout:`` supply
        the keywords the file lacks (``NFRAMES`` is the number of groups).
    progress : bool
        The pipeline's progress bars.
    threads : int, optional
        As for `Pipeline.run <spherex_reduce.Pipeline.run>`.

    Returns
    -------
    `Integrations`
        See `combine_integrations`.

    Raises
    ------
    FormatError
        ``SCI`` is not 4-D, or an integration does not match the schedule.
    ConfigError
        The pipeline leaves ramps.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce import Pipeline, reduce_integrations
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "uncal.fits"
    >>> t = np.arange(4.0)[None, :, None, None]  # 4 groups, 1 s apart
    >>> sci = 100 + np.array([2.0, 4.0])[:, None, None, None] * t + np.zeros((2, 4, 8, 8))
    >>> fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(sci.astype("f4"), name="SCI")]
    ...              ).writeto(path)
    >>> p = Pipeline({"geometry": {"nrows": 8, "ncols": 8, "nchannels": 1, "ref_border": 0,
    ...                            "pixel_rate": 1e5},
    ...               "readout": {"ref_mode": "none", "phantom_reads": 0, "nframes": 4,
    ...                           "skip": 4, "frame_time": 1.0},
    ...               "steps": [{"fit_ramp": {}}]})
    >>> r = reduce_integrations(path, p)  # noiseless: no uncertainty, so the plain mean
    >>> r.slopes.shape, float(r.slopes[1, 0, 0].value), float(r.exposure.data.data[0, 0])
    ((2, 8, 8), 4.0, 3.0)
    """
    if integration_count(path) is None:  # let the reader say what the file is
        read(path, input=pipeline.input_options, integration=0, **pipeline.supplied())
    with pipeline.open(path) as inp:
        return _reduced(inp, pipeline, progress, threads)


def _reduced(inp, pipeline, progress, threads):
    """Each integration of an opened 4-D input through ``pipeline``, then combined."""
    results = []
    for k in range(inp.integrations):
        ramps = inp.source(integration=k)
        if k == 0:  # the per-integration images (and the mean), before fitting them all
            nrows, ncols = ramps.exposure().shape[-2:]
            check_size(inp.integrations * nrows * ncols * 40,
                       f"the images of {inp.integrations} integrations of {inp.label}")
        results.append(pipeline.run(ramps, progress=progress, threads=threads))
        _parts(results[-1], k)  # refuse ramps before fitting every integration
    return combine_integrations(results)


def reduce_input(what, pipeline, *, progress=False, threads=None):
    """Reduce one input, as ``spherex-reduce reduce`` does, whatever its layout.

    The input is opened once by `~spherex_reduce.io.sources.open_input`: a
    file with a 4-D ``SCI`` has each integration reduced and combined (as
    `reduce_integrations`); any other input (a raw or reduced file, the files
    of a ramp stored one per read, an exposure) goes through
    `Pipeline.run <spherex_reduce.Pipeline.run>`, streamed where it can be.

    Parameters
    ----------
    what : path, sequence of paths, `~spherex_reduce.Exposure` ...
        The input (anything `~spherex_reduce.io.sources.open_input` takes);
        never changed.
    pipeline : `~spherex_reduce.Pipeline`
    progress : bool
        Show progress bars.
    threads : int, optional
        As for `Pipeline.run <spherex_reduce.Pipeline.run>`.

    Returns
    -------
    exposure : `~spherex_reduce.Exposure`
        The result (for several integrations, their mean).
    images : dict
        The extra image extensions to write with it (`Integrations.images`:
        ``INTSLOPE``, ``INTERR``, ``INTDQ``), empty for one ramp:
        ``write(exposure, output, images=images)``.
    """
    if not hasattr(pipeline, "open"):
        raise TypeError(f"reduce_input(input, pipeline): the second argument must be a "
                        f"Pipeline, got {type(pipeline).__name__}")
    with pipeline.open(what) as inp:
        if inp.integrations is None:
            return pipeline.run(inp.source(), progress=progress, threads=threads), {}
        result = _reduced(inp, pipeline, progress, threads)
    return result.exposure, result.images()
