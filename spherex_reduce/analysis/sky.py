"""An injected sky: a Gaussian random field on the light-sensitive pixels, added to raw data.

`sky_field` draws the field (in e/s, physical row order) on the rectangle of
light-sensitive pixels (`~spherex_reduce.analysis.light.light_sensitive`), zero
on reference pixels, `inject_sky` adds it to a simulated exposure (slopes or
ramps, in readout or physical order), and `measure_against_sky` measures a
reduced image against the sky it was given: the noise left, and the sky kept
(from its difference with the same noise reduced without the sky).
``compare-strategies`` is built on them.
"""

import numpy as np
import scipy.fft
from astropy import units as u
from astropy.nddata import CCDData

from ..core.errors import SpherexReduceError
from .case import SpectrumMeasure
from .light import light_sensitive
from .spectrum import cross_spectrum, power_spectrum

__all__ = ["RMS_RANGE", "inject_sky", "measure_against_sky", "sky_field"]

_RATE = u.electron / u.s
#: The sky's rms (e/s) must lie in this range: far beyond any real sky on either side, and
#: its power (rms² summed over up to 2048² pixels, twice) stays a normal float64, so the
#: transfer is never 0/0 or x/0 from an underflow (rms 1e-300: power 0, transfer inf).
RMS_RANGE = (1e-20, 1e20)


def sky_field(geometry, rms, index, seed):
    """A Gaussian random field with ``P(k) ∝ k^index`` and this rms, on the light-sensitive pixels.

    The field is drawn on the rectangle of `light_sensitive` pixels: white
    noise, its FFT multiplied by ``k^(index/2)`` (``k = |k|`` in rad/pixel;
    the ``k = 0`` mode set to zero, so its mean is zero), transformed back
    (periodic on the rectangle) and scaled so that its rms over those pixels
    is exactly ``rms``.  Reference pixels are zero.

    Parameters
    ----------
    geometry : `~spherex_reduce.DetectorGeometry`
    rms : float
        e/s over the light-sensitive pixels, in `RMS_RANGE`.
    index : float
        Spectral index of the power spectrum (``-2``: more power on large scales).
    seed : int, sequence of int or `numpy.random.SeedSequence`
        For `numpy.random.default_rng`.

    Returns
    -------
    `~numpy.ndarray`
        ``(nrows, ncols)`` in e/s, physical row order, float64.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.analysis import light_sensitive, sky_field
    >>> g = DetectorGeometry(64, 64, 4, ref_border=4)
    >>> sky = sky_field(g, 0.05, -2.0, seed=11)
    >>> light = light_sensitive(g)
    >>> round(float(np.sqrt(np.mean(sky[light] ** 2))), 6), float(abs(sky[:4]).max())
    (0.05, 0.0)
    """
    rms, index = float(rms), float(index)
    lo, hi = RMS_RANGE
    if not lo <= rms <= hi or not np.isfinite(index):
        raise SpherexReduceError(f"sky: rms must be in [{lo:g}, {hi:g}] e/s and index finite, "
                                 f"got rms={rms}, index={index}")
    rows, cols = light_sensitive(geometry)
    ny, nx = rows.stop - rows.start, cols.stop - cols.start
    white = np.random.default_rng(seed).standard_normal((ny, nx))
    ky = 2 * np.pi * np.fft.fftfreq(ny)[:, None]
    kx = 2 * np.pi * np.fft.rfftfreq(nx)[None, :]
    k = np.hypot(ky, kx)
    amplitude = np.zeros_like(k)
    amplitude[k > 0] = k[k > 0] ** (index / 2)
    field = scipy.fft.irfft2(scipy.fft.rfft2(white) * amplitude, s=(ny, nx))
    field -= field.mean()  # zero already, up to round-off
    norm = np.sqrt(np.mean(field**2))
    if not norm > 0:  # a 1-pixel rectangle has no mode but k = 0
        raise SpherexReduceError(f"sky: the {ny} x {nx} light-sensitive area is too small "
                                 "for a field")
    out = np.zeros((geometry.nrows, geometry.ncols))
    out[rows, cols] = field * (rms / norm)
    return out


def inject_sky(exposure, sky):
    """A new exposure: ``exposure`` plus a sky of ``sky`` e/s on every pixel's reads.

    The exposure's arrays are not changed (a new one is made and returned).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        A slope image (unit convertible to e/s) or ramps (convertible to e),
        in readout order (each read's pixels get the sky of the physical row
        it reads, ``schedule.rows``) or physical order.
    sky : array-like
        ``(nrows, ncols)`` in e/s, physical row order (e.g. `sky_field`).

    Returns
    -------
    `~spherex_reduce.Exposure`
        Slopes: ``data + sky``.  Ramps: frame ``j`` gets the charge collected
        by the time each pixel is read, ``sky × (frame_starts[j] + t)`` with
        ``t`` the time of the pixel's read within the frame
        (``schedule.pixel_times()``), so that the fitted slope gains exactly
        ``sky``.  Same dtype, unit, flags and phantom values.

    Raises
    ------
    SpherexReduceError
        A sky of another shape than the array, or a unit that is not a rate
        (slopes) or a charge (ramps).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce.analysis import inject_sky
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=2), skip=2, ref_reads=0,
    ...                     ref_mode="none", phantom_reads=0, nframes=3)
    >>> e = Exposure.from_arrays(np.zeros((3, s.n_reads, 8)), s)
    >>> out = inject_sky(e, np.full((8, 8), 2.0))
    >>> t = s.frame_starts.value[:, None, None] + s.pixel_times().value[None]
    >>> bool(np.allclose(out.data.data, 2.0 * t)), bool(np.all(e.data.data == 0))
    (True, True)
    """
    s = exposure.schedule
    g = s.geometry
    sky = np.asarray(sky, dtype=float)
    if sky.shape != (g.nrows, g.ncols):
        raise SpherexReduceError(f"sky of shape {sky.shape} on a {g.nrows} x {g.ncols} array")
    ramp = exposure.is_ramp
    target = u.electron if ramp else _RATE
    try:
        factor = (1.0 * (target)).to_value(exposure.unit)
    except u.UnitConversionError:
        what = "ramps" if ramp else "a slope image"
        raise SpherexReduceError(f"cannot add a sky in e/s to {what} in {exposure.unit} "
                                 f"(expected a unit of {target})") from None
    times = s.pixel_times().to_value(u.s)  # (n_reads, ncols)
    if exposure.order == "readout":
        rate = sky[s.rows]
    else:
        rate = sky
        read = s.read_of_row()
        times = np.where((read >= 0)[:, None], times[np.maximum(read, 0)], 0.0)
    data = np.asarray(exposure.data.data)
    if not ramp:
        new = (data + rate * factor).astype(data.dtype, copy=False)
    else:
        new = np.empty_like(data)
        starts = s.frame_starts.to_value(u.s)
        for j in range(data.shape[0]):  # one frame at a time: no cube-sized temporary
            new[j] = data[j] + rate * ((starts[j] + times) * factor)
    return exposure.replace(data=new)


def measure_against_sky(image, without, sky, measure=None, light=None):
    """The noise left in a reduced image and the fraction of the injected sky it kept.

    ``image`` is an exposure reduced with the sky injected, ``without`` the
    same exposure (the same noise) reduced without it.  On the
    light-sensitive pixels (`light_sensitive`; pixels masked in either
    image's ``mask`` or not finite are left out of the transfer, as
    `power_spectrum` does):

    - ``noise_band_power`` (and ``_err``): `band_power` of ``image − sky``,
      with ``k`` and ``power`` its binned P(k) (`SpectrumMeasure`);
    - ``transfer``: per ``k`` bin, ``P_cross(image − without, sky) / P_sky``
      (the same bins; 1 = sky kept, 0 = removed; NaN for an empty bin);
    - ``sky_transfer``: over the band, ``Σ P_cross / Σ P_sky`` over its
      Fourier modes (power-weighted), of the same difference.

    The difference is what the pipeline made of the sky: the noise, the same
    in both, cancels, exactly for a linear pipeline (a reference offset keeps
    a transfer of 1 whatever the noise) and for a non-linear one (a median)
    it is its response to the sky on this noise.  Measured against ``image``
    alone, the noise's chance correlation with a faint sky moved the
    transfer by tens of per cent.

    Parameters
    ----------
    image, without : `~astropy.nddata.CCDData`
        The light-sensitive pixels of a reduced slope image with and without
        the sky (`~spherex_reduce.analysis.light_sensitive_image`, as `run_case`
        gives them to a paired measure), units convertible to e/s.
    sky : array
        The injected sky (`sky_field`), e/s, on the whole array.
    measure : `SpectrumMeasure` or dict, optional
        Band and bins (default: the paper's 5–20′ band, 30 bins).
    light : tuple of slice, optional
        Where the images lie on the array (`light_sensitive` of its
        geometry); default the whole array.

    Returns
    -------
    dict
        The keys above (plain floats and arrays in the image's unit squared ×
        pixel²), ``unit`` and ``masked_fraction`` (of ``image``).

    Examples
    --------
    White noise with and without the sky: the whole sky kept, the noise left:

    >>> import numpy as np
    >>> from astropy.nddata import CCDData
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.analysis import sky_field
    >>> from spherex_reduce.analysis import measure_against_sky
    >>> sky = sky_field(DetectorGeometry(128, 128, 4, ref_border=4), 0.05, -2.0, 1)
    >>> noise = np.random.default_rng(2).normal(0, 0.01, sky.shape)
    >>> light = (slice(4, 124), slice(4, 124))
    >>> m = measure_against_sky(CCDData((sky + noise)[light], unit="electron/s"),
    ...                         CCDData(noise[light], unit="electron/s"), sky,
    ...                         {"bins": 6}, light=light)
    >>> err = 3 * m["noise_band_power_err"]
    >>> round(m["sky_transfer"], 12), bool(abs(m["noise_band_power"] - 1e-4) < err)
    (1.0, True)
    """
    measure = SpectrumMeasure(**(measure or {})) if not isinstance(
        measure, SpectrumMeasure) else measure
    light = (slice(None), slice(None)) if light is None else tuple(light)
    sky = np.asarray(sky, dtype=float)[light]
    for name, im in (("reduced image", image), ("image without the sky", without)):
        if im.data.shape != sky.shape:
            raise SpherexReduceError(f"the {name} {im.data.shape} and the sky {sky.shape} "
                                     "differ in shape")
    try:
        factor = (1.0 * u.electron / u.s).to_value(image.unit)
        same = (1.0 * without.unit).to_value(image.unit)
    except u.UnitConversionError:
        raise SpherexReduceError(f"reduced images in {image.unit} and {without.unit} cannot be "
                                 "compared with a sky in e/s") from None
    sky_cut = sky * factor
    residual = CCDData(np.asarray(image.data, dtype=float) - sky_cut, unit=image.unit,
                       mask=image.mask)
    m = measure(residual)
    kw = {"exclude_horizontal": bool(measure.exclude_horizontal)}
    bad = np.zeros(image.shape, bool)
    for im in (image, without):
        bad |= ~np.isfinite(im.data)
        if im.mask is not None:
            bad |= np.asarray(im.mask) != 0
    with np.errstate(invalid="ignore"):  # inf - inf at a pixel left out anyway
        diff = np.asarray(image.data, dtype=float) - np.asarray(without.data, dtype=float) * same
    edges = measure.edges(image.shape)
    cross = cross_spectrum(diff, sky_cut, mask=bad, bins=edges, **kw)
    auto = power_spectrum(sky_cut, mask=bad, bins=edges, **kw)
    transfer = np.full(edges.size - 1, np.nan)
    pos = np.searchsorted(edges, np.asarray(cross["k_lo"]) * (1 + 1e-12)) - 1
    with np.errstate(divide="ignore", invalid="ignore"):
        transfer[pos] = np.asarray(cross["power"]) / np.asarray(auto["power"])
    band = [measure.kmin, measure.kmax]
    bc = cross_spectrum(diff, sky_cut, mask=bad, bins=band, **kw)
    ba = power_spectrum(sky_cut, mask=bad, bins=band, **kw)
    sky_power = float(ba["power"][0]) if len(ba) else np.nan
    if len(ba) and not (np.isfinite(sky_power) and sky_power > 0):
        raise SpherexReduceError(f"the injected sky's band power is {sky_power:g}: the sky is "
                                 "too faint or too bright for float64 (see sky.rms)")
    sky_transfer = float(bc["power"][0]) / sky_power if len(ba) else np.nan
    return {"noise_band_power": float(m["band_power"].value),
            "noise_band_power_err": float(m["band_power_err"].value),
            "unit": str(m["band_power"].unit), "k": m["k"], "power": m["power"],
            "transfer": transfer, "sky_transfer": sky_transfer,
            "masked_fraction": m["masked_fraction"]}
