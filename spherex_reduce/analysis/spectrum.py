"""Spatial power spectra of images: P(k), band power, 2-D FFT, photon noise.

Conventions (paper §1): the wave number of an angular period ``θ`` is
``k = 2π · pixel_scale / θ`` in rad/pixel, so a pattern repeating every ``p``
pixels has ``k = 2π / p``.  SPHEREx pixels are 6.2″, so the paper's band
θ = 5–20′ is ``0.03 < k < 0.13`` (`band_label`; exactly θ = 4.99–21.6′: `band_theta`).

Normalisation: ``P(k) = |FFT(image)|² / (ny · nx)`` (in image unit² · pixel²),
averaged over the Fourier modes in each annulus of ``|k|``.  White noise of
variance σ² per pixel therefore gives ``P(k) = σ²`` at every ``k``, and by
Parseval the mode-weighted sum of ``P`` over the whole Fourier plane divided
by the number of pixels is the image variance.

Masked pixels: the mean of the unmasked pixels is subtracted, masked pixels
are set to zero and the spectrum is divided by the unmasked fraction ``f``
(the "f_sky" pseudo-spectrum correction).  This is exact on average for white
noise; for a coloured spectrum and a sparse mask (hot or clipped pixels) each
bin is ``≈ f · P(k) + (1 − f) · ⟨P⟩`` to first order, i.e. a fraction ``1 − f``
of the mean power is spread flat over ``k``.  Keep the masked fraction small
(a few per cent) where the shape matters.
"""

import functools
from typing import NamedTuple

import numpy as np
import scipy.fft
from astropy import units as u
from astropy.table import Table

from ..core.errors import SpherexReduceError
from ..core.source_mask import image_and_mask, source_mask

__all__ = [
    "BAND_KMAX",
    "BAND_KMIN",
    "SPHEREX_PIXEL_SCALE",
    "EmptyBandError",
    "FFTImage",
    "band_label",
    "band_power",
    "band_theta",
    "cross_spectrum",
    "fft_magnitude",
    "k_from_theta",
    "power_spectra",
    "power_spectrum",
    "theta_from_k",
]

#: Angular size of a SPHEREx pixel (paper §1).
SPHEREX_PIXEL_SCALE = 6.2 * u.arcsec
#: The paper's band θ = 5–20′ in rad/pixel (Figs. 6, 8, 13, 14).
BAND_KMIN, BAND_KMAX = 0.03, 0.13
#: The paper's name of that band (exactly θ = 4.99–21.6′ on 6.2″ pixels: `band_theta`).
BAND_NOMINAL = "5–20′"
_K_UNIT = u.rad / u.pix


class EmptyBandError(SpherexReduceError):
    """An image has no Fourier mode in the band asked for (e.g. an image too small for it).

    Raised by `band_power`; ``spherex-reduce spectrum`` reports the band power as
    missing instead (its message is the warning).
    """


def k_from_theta(theta, pixel_scale=SPHEREX_PIXEL_SCALE):
    """Wave number ``k = 2π · pixel_scale / θ`` in rad/pixel.

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis import k_from_theta
    >>> k_from_theta([20, 5] * u.arcmin).round(3)
    <Quantity [0.032, 0.13 ] rad / pix>
    """
    theta = u.Quantity(theta, u.arcmin)
    ratio = (u.Quantity(pixel_scale, u.arcsec) / theta).to_value(u.one)
    return 2 * np.pi * ratio * _K_UNIT


def theta_from_k(k, pixel_scale=SPHEREX_PIXEL_SCALE):
    """Angular period ``θ = 2π · pixel_scale / k`` in arcmin (``k`` in rad/pixel).

    Examples
    --------
    >>> from spherex_reduce.analysis import theta_from_k
    >>> theta_from_k(0.13).round(2)
    <Quantity 4.99 arcmin>
    """
    k = _k_value(k)
    with np.errstate(divide="ignore"):
        return (2 * np.pi / k * u.Quantity(pixel_scale, u.arcsec)).to(u.arcmin)


def _is_paper_band(kmin, kmax, pixel_scale):
    return (float(_k_value(kmin)), float(_k_value(kmax))) == (BAND_KMIN, BAND_KMAX) and \
        u.isclose(u.Quantity(pixel_scale, u.arcsec), SPHEREX_PIXEL_SCALE)


def band_label(kmin=BAND_KMIN, kmax=BAND_KMAX, pixel_scale=SPHEREX_PIXEL_SCALE):
    """The band as plots, tables and messages name it: the nominal band and its ``k``.

    The paper's band (``0.03 ≤ k ≤ 0.13`` rad/pixel on 6.2″ pixels) is named
    by the paper's nominal θ = 5–20′; any other band, or another pixel
    scale, by its ``k`` range alone.  The θ range the ``k`` limits really
    give is `band_theta` (a plot's caption, a table's ``band_theta_exact``).

    Parameters
    ----------
    kmin, kmax : float or `~astropy.units.Quantity`
        Band edges in rad/pixel.
    pixel_scale : `~astropy.units.Quantity`
        Angle per pixel.

    Returns
    -------
    str

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis import band_label
    >>> band_label()
    '5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel)'
    >>> band_label(0.03, 0.13, 0.1 * u.arcsec)
    '0.03 ≤ k ≤ 0.13 rad/pixel'
    """
    lo, hi = float(_k_value(kmin)), float(_k_value(kmax))
    k = f"{lo:g} ≤ k ≤ {hi:g} rad/pixel"
    return f"{BAND_NOMINAL} ({k})" if _is_paper_band(lo, hi, pixel_scale) else k


def band_theta(kmin=BAND_KMIN, kmax=BAND_KMAX, pixel_scale=SPHEREX_PIXEL_SCALE):
    """The angular periods a ``k`` band really gives for a pixel scale.

    Parameters
    ----------
    kmin, kmax : float or `~astropy.units.Quantity`
        Band edges in rad/pixel.
    pixel_scale : `~astropy.units.Quantity`
        Angle per pixel.

    Returns
    -------
    str
        ``θ`` in arcmin (′), or arcsec (″) when the longest period is under
        1′, with the pixel scale.

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis import band_theta
    >>> band_theta()
    'θ = 4.99–21.6′ for 6.2″ pixels'
    >>> band_theta(0.03, 0.13, 0.1 * u.arcsec)
    'θ = 4.83–20.9″ for 0.1″ pixels'
    """
    lo, hi = float(_k_value(kmin)), float(_k_value(kmax))
    short, long_ = theta_from_k(hi, pixel_scale), theta_from_k(lo, pixel_scale)
    unit, mark = (u.arcmin, "′") if np.isinf(long_) or long_ >= 1 * u.arcmin else (u.arcsec,
                                                                                    "″")
    short = short.to_value(unit)
    theta = f"θ ≥ {short:.3g}{mark}" if lo == 0 else \
        f"θ = {short:.3g}–{long_.to_value(unit):.3g}{mark}"
    return f"{theta} for {u.Quantity(pixel_scale, u.arcsec).value:g}″ pixels"


def _k_value(k):
    """``k`` as a float array in rad/pixel (plain numbers are taken as rad/pixel)."""
    if isinstance(k, u.Quantity):
        with u.set_enabled_equivalencies(u.dimensionless_angles()):
            return k.to_value(_K_UNIT)
    return np.asarray(k, dtype=float)


# -- input handling -------------------------------------------------------------
def _as_image(image, mask=None):
    """``(data, bad-pixel mask, unit)`` of a 2-D image (see
    `~spherex_reduce.core.source_mask.image_and_mask`), with the power spectrum's
    message for ramps."""
    return image_and_mask(image, mask, "a power spectrum needs a 2-D image",
                          "; fit the ramps first (fit_ramp) or pass one frame")


def _prepared(data, bad):
    """Mean-subtracted float64 image with masked pixels zeroed, and the unmasked fraction."""
    good = ~bad
    ngood = int(good.sum())
    if ngood < 2:
        raise SpherexReduceError(
            f"only {ngood} unmasked finite pixel(s) in the image; nothing to measure"
        )
    x = np.array(data, dtype=np.float64)  # a copy: the input is never changed
    if ngood == x.size:
        x -= x.mean()
    else:
        x[bad] = 0.0
        x[good] -= x[good].mean()
        x[bad] = 0.0
    return x, ngood / x.size


# -- the Fourier grid -------------------------------------------------------------
@functools.lru_cache(maxsize=8)
def rfft_weights(nx):
    """Weight of each rfft column ``(nx // 2 + 1,)`` in the full Fourier plane: interior
    columns stand for +kx and -kx (2), column 0 and an even ``nx``'s Nyquist column for
    themselves (1)."""
    w = np.full(nx // 2 + 1, 2.0)
    w[0] = 1.0
    if nx % 2 == 0:
        w[-1] = 1.0
    return w


@functools.lru_cache(maxsize=4)  # a full-size grid holds ~35 MB
def k_grid(ny, nx, edges, exclude_horizontal):
    """Bin index and weight of every cell of the ``rfft2`` grid, and each bin's sums.

    Cached per shape (a full-size grid holds ~35 MB); the arrays are read-only.

    Parameters
    ----------
    ny, nx : int
        Shape of the image.
    edges : tuple of float
        Bin edges in rad/pixel (the last one inclusive).
    exclude_horizontal : bool
        Whether the row ``ky = 0`` is left out.

    Returns
    -------
    idx : `numpy.ndarray`
        Bin of every cell (raveled); ``len(edges) - 1`` for a cell in no bin
        (outside the edges, the mean, or a left-out row).
    weights : `numpy.ndarray`
        Modes of the full grid each cell stands for (`rfft_weights`).
    nfull, ksum, nself : `numpy.ndarray`
        Per bin: the modes, the sum of their ``|k|``, and the self-conjugate cells.

    Examples
    --------
    >>> from spherex_reduce.analysis.spectrum import k_grid
    >>> idx, weights, nfull, ksum, nself = k_grid(4, 4, (0.0, 1.6, 3.2), False)
    >>> idx.reshape(4, 3).tolist()
    [[2, 0, 1], [0, 1, 2], [1, 2, 2], [0, 1, 2]]
    >>> nfull.tolist(), nself.tolist()
    ([4.0, 6.0], [0.0, 2.0])
    """
    ky = 2 * np.pi * np.fft.fftfreq(ny)
    kx = 2 * np.pi * np.fft.rfftfreq(nx)
    kk = np.hypot(ky[:, None], kx[None, :])
    edges = np.asarray(edges)
    nb = edges.size - 1
    idx = np.searchsorted(edges, kk, side="right") - 1
    idx[(idx < 0) | (idx >= nb)] = nb  # the overflow bin, dropped
    idx[kk == edges[-1]] = nb - 1  # the last edge is inclusive
    idx[0, 0] = nb  # the mean (k = 0) never counts
    if exclude_horizontal:
        idx[0, :] = nb
    wgrid = np.broadcast_to(rfft_weights(nx), kk.shape)
    idx = idx.ravel()
    nfull = np.bincount(idx, weights=wgrid.ravel(), minlength=nb + 1)[:nb]
    ksum = np.bincount(idx, weights=(wgrid * kk).ravel(), minlength=nb + 1)[:nb]
    # self-conjugate cells (their own mirror image) are one mode, not half of a pair
    selfc = np.zeros(kk.shape, dtype=bool)
    rows = [0] + ([ny // 2] if ny % 2 == 0 else [])
    cols = [0] + ([kx.size - 1] if nx % 2 == 0 else [])
    selfc[np.ix_(rows, cols)] = True
    nself = np.bincount(idx, weights=selfc.ravel().astype(float), minlength=nb + 1)[:nb]
    weights = wgrid.ravel().copy()
    for arr in (idx, weights, nfull, ksum, nself):
        arr.setflags(write=False)
    return idx, weights, nfull, ksum, nself


def k_bin_edges(bins, ny, nx):
    """The bin edges in rad/pixel of a spectrum: ``bins`` log-spaced bins, or the edges given.

    Parameters
    ----------
    bins : int or array_like
        A number of bins, log-spaced from the lowest ``k`` of the image
        (``2 pi / max(ny, nx)``) to pi, or the edges (rad/pixel, or a
        `~astropy.units.Quantity` of wavenumbers).
    ny, nx : int
        Shape of the image.

    Returns
    -------
    `numpy.ndarray`

    Raises
    ------
    SpherexReduceError
        No bins, or edges that do not increase or are negative.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.spectrum import k_bin_edges
    >>> bool(np.allclose(k_bin_edges(2, 8, 8), [np.pi / 4, np.pi / 2, np.pi]))
    True
    >>> k_bin_edges([0.1, 0.5, 1.0], 8, 8).tolist()
    [0.1, 0.5, 1.0]
    """
    if isinstance(bins, (int, np.integer)) and not isinstance(bins, bool):
        if bins < 1:
            raise SpherexReduceError(f"bins must be >= 1, got {bins}")
        kmin = 2 * np.pi / max(ny, nx)
        return np.geomspace(kmin, np.pi, int(bins) + 1)
    edges = _k_value(bins).astype(float).ravel()
    if edges.size < 2 or np.any(np.diff(edges) <= 0) or edges[0] < 0:
        raise SpherexReduceError(
            "bins must be a number of bins or at least two increasing, non-negative bin "
            f"edges in rad/pixel; got {bins!r}"
        )
    return edges


#: What each column of a `power_spectrum` table holds (written into ECSV files).
SPECTRUM_COLUMNS = {
    "k": "mean |k| of the bin's Fourier modes (k = 2 pi pixel scale / theta)",
    "theta": "angular scale of k for the pixel scale (theta = 2 pi pixel scale / k)",
    "power": "P(k): mean of |FFT|^2 over the bin's modes, normalised (pixel variance x pix^2)",
    "power_err": "standard error of power: its scatter over the bin's independent modes",
    "nmodes": "independent Fourier modes in the bin (a mode and its conjugate count once)",
    "k_lo": "lower edge of the bin",
    "k_hi": "upper edge of the bin",
}


def power_spectrum(image, pixel_scale=SPHEREX_PIXEL_SCALE, mask=None, bins=30,
                   mask_sources=False, exclude_horizontal=False):
    """Azimuthally averaged spatial power spectrum ``P(k)`` of a 2-D image.

    Parameters
    ----------
    image : `~astropy.nddata.CCDData`, `~astropy.nddata.NDData`, `~astropy.units.Quantity` or array
        The image (e.g. a slope image in e/s).  Its ``mask`` (NDData) and any
        non-finite pixels are excluded.  The input is not changed.
    pixel_scale : `~astropy.units.Quantity`
        Angle per pixel (6.2″ for SPHEREx); used only for the ``theta`` column.
    mask : array-like of bool, optional
        Extra pixels to exclude (True = bad), e.g. hot or clipped pixels.
    bins : int or array-like
        Number of logarithmic bins from the fundamental ``2π/max(ny, nx)`` to
        the Nyquist wave number ``π`` (the corners of the Fourier plane beyond
        ``π`` are left out), or bin edges in rad/pixel (floats or a Quantity).
        Empty bins are dropped.
    mask_sources : bool
        Also mask sources and hot pixels found by `source_mask` (photutils
        segmentation on a `photutils.background.Background2D` estimate), for
        images that contain sky.
    exclude_horizontal : bool
        Leave out the horizontal axis of the Fourier plane (``k_y = 0``: the
        modes that channel offsets feed), as the paper does for Fig. 6.

    Returns
    -------
    spectrum : `~astropy.table.Table`
        One row per non-empty bin: ``k`` (rad/pixel, mode-weighted mean of
        ``|k|`` in the bin), ``theta`` (arcmin), ``power`` (image unit² ·
        pixel²), ``power_err`` and ``nmodes`` (independent Fourier modes: a
        real image's ``k`` and ``−k`` count once).  ``power_err`` is the
        standard error of the bin mean for a Gaussian field,
        ``sqrt(Σ P_i²) / n`` over the ``n`` cells of the full plane (≈
        ``P / sqrt(nmodes)`` when the bin is isotropic); bins of a few modes
        are χ²-distributed with ``2 · nmodes`` degrees of freedom and their
        error estimate is itself uncertain.  ``meta`` holds
        ``pixel_scale``, ``shape``, ``masked_fraction``, ``mask_method``,
        ``exclude_horizontal`` and ``kmin``/``kmax`` of each bin as columns
        ``k_lo``/``k_hi``.

    Notes
    -----
    ``P(k) = |FFT|² / (ny · nx) / f`` with ``f`` the unmasked fraction
    (masked pixels zeroed after subtracting the unmasked mean); see the module
    documentation for what masking does to a coloured spectrum.

    Examples
    --------
    White noise of σ = 2 gives ``P(k) ≈ σ² = 4`` at every ``k``:

    >>> import numpy as np
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis import power_spectrum
    >>> img = np.random.default_rng(1).normal(0, 2, (256, 256)) * u.electron / u.s
    >>> t = power_spectrum(img, bins=8)
    >>> t.colnames
    ['k', 'theta', 'power', 'power_err', 'nmodes', 'k_lo', 'k_hi']
    >>> bool(np.all(abs(t["power"].value - 4) < 4 * t["power_err"].value)), t["power"].unit
    (True, Unit("electron2 pix2 / s2"))
    """
    return power_spectra(image, [bins], pixel_scale, mask, mask_sources, exclude_horizontal)[0]


def power_spectra(image, binnings, pixel_scale=SPHEREX_PIXEL_SCALE, mask=None,
                  mask_sources=False, exclude_horizontal=False):
    """`power_spectrum` of one image in several binnings, from one FFT (and source mask).

    Parameters
    ----------
    image, pixel_scale, mask, mask_sources, exclude_horizontal
        As `power_spectrum`.
    binnings : sequence
        Each a ``bins`` of `power_spectrum`.

    Returns
    -------
    list of `~astropy.table.Table`
        ``power_spectrum(image, bins=b, ...)`` for every ``b`` of ``binnings``, in order.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.spectrum import power_spectra, power_spectrum
    >>> img = np.random.default_rng(1).normal(0, 2, (64, 64))
    >>> t8, band = power_spectra(img, [8, [0.2, 1.0]])
    >>> len(t8), bool(band["power"][0] == power_spectrum(img, bins=[0.2, 1.0])["power"][0])
    (8, True)
    """
    data, bad, unit = _as_image(image, mask)
    if mask_sources:
        bad = bad | source_mask(np.where(bad, np.nan, data), mask=bad)
    return _binned_spectra(data, None, bad, unit, unit, binnings, pixel_scale,
                           exclude_horizontal)


def cross_spectrum(image, other, pixel_scale=SPHEREX_PIXEL_SCALE, mask=None, bins=30,
                   exclude_horizontal=False):
    """Azimuthally averaged cross power spectrum ``P_ab(k)`` of two images of one shape.

    ``P_ab(k) = Re(FFT(a) · conj(FFT(b))) / (ny · nx · f)``, averaged over the
    Fourier modes of each annulus exactly as `power_spectrum` averages
    ``|FFT|²`` (it is the same code: ``cross_spectrum(a, a)`` is
    ``power_spectrum(a)``).  Pixels masked or non-finite in *either* image are
    masked in both, each image's unmasked mean is subtracted and ``f`` is the
    unmasked fraction.  The ratio of ``cross_spectrum(out, sky)`` to
    ``power_spectrum(sky)`` (same mask and bins) is the transfer function of
    whatever turned ``sky`` into ``out``.

    Parameters
    ----------
    image, other : CCDData, NDData, Quantity or array
        The two images (their masks are or-ed).  Not changed.
    pixel_scale, mask, bins, exclude_horizontal
        As `power_spectrum`.

    Returns
    -------
    spectrum : `~astropy.table.Table`
        The columns of `power_spectrum`; ``power`` is in (unit of ``image``) ·
        (unit of ``other``) · pixel².  ``power_err`` is the standard error of
        the bin mean for Gaussian fields, ``sqrt(Σ (|A_i|² |B_i|² + C_i²) / 2)
        / n`` over the ``n`` cells (``C_i`` the cross power of cell ``i``),
        which is `power_spectrum`'s error when ``other`` is ``image``.

    Examples
    --------
    An image and half of it: the cross power is half the image's power.

    >>> import numpy as np
    >>> from spherex_reduce.analysis import cross_spectrum, power_spectrum
    >>> a = np.random.default_rng(4).normal(0, 1, (64, 64))
    >>> c, p = cross_spectrum(0.5 * a, a, bins=4), power_spectrum(a, bins=4)
    >>> bool(np.allclose(c["power"], 0.5 * p["power"]))
    True
    """
    data, bad, unit = _as_image(image, mask)
    data_b, bad_b, unit_b = _as_image(other)
    if data_b.shape != data.shape:
        raise SpherexReduceError(f"cross_spectrum: the images differ in shape, {data.shape} "
                                 f"and {data_b.shape}")
    bad = bad | bad_b
    return _binned_spectra(data, data_b, bad, unit, unit_b, [bins], pixel_scale,
                           exclude_horizontal)[0]


def _binned_spectra(data, data_b, bad, unit, unit_b, binnings, pixel_scale,
                    exclude_horizontal):
    """The tables of `power_spectrum` (``data_b`` None) or `cross_spectrum`, one per
    binning: one implementation."""
    ny, nx = data.shape
    edges = [k_bin_edges(bins, ny, nx) for bins in binnings]
    x, fgood = _prepared(data, bad)
    f = scipy.fft.rfft2(x, workers=-1)
    del x
    if data_b is None:
        p = f.real**2
        p += f.imag**2
        var = None  # each cell's Gaussian variance (|A|²|B|² + C²) / 2 is then p²
    else:
        g = scipy.fft.rfft2(_prepared(data_b, bad)[0], workers=-1)
        p = f.real * g.real
        p += f.imag * g.imag
        var = (np.abs(f) ** 2 * np.abs(g) ** 2 + p * p) / 2
        del g
    del f
    return [spectrum_table(p, (ny, nx), e, unit * unit_b, fgood, pixel_scale,
                           exclude_horizontal, var) for e in edges]


def spectrum_table(p, shape, edges, unit, fgood=1.0, pixel_scale=SPHEREX_PIXEL_SCALE,
                   exclude_horizontal=False, var=None):
    """The table of `power_spectrum` from ``p``, the ``|FFT|²`` (or its expectation) of every
    cell of the ``rfft2`` grid of an image of ``shape``, not normalised; ``unit`` is the
    image's squared, ``fgood`` its unmasked fraction, ``var`` each cell's Gaussian variance
    (None: ``p²``).  The one binning of measured and forecast spectra."""
    ny, nx = shape
    idx, w, nfull, ksum, nself = k_grid(ny, nx, tuple(edges), bool(exclude_horizontal))
    nb = edges.size - 1
    pw = p.ravel() * w
    psum = np.bincount(idx, weights=pw, minlength=nb + 1)[:nb]
    p2w = pw * p.ravel() if var is None else var.ravel() * w
    p2sum = np.bincount(idx, weights=p2w, minlength=nb + 1)[:nb]
    scale = 1.0 / (ny * nx * fgood)
    keep = nfull > 0
    n = nfull[keep]
    k = ksum[keep] / n
    power = psum[keep] / n * scale
    err = np.sqrt(p2sum[keep]) / n * scale
    nmodes = np.rint((n + nself[keep]) / 2).astype(np.int64)
    punit = unit * u.pix**2
    table = Table(
        {
            "k": k * _K_UNIT,
            "theta": theta_from_k(k, pixel_scale),
            "power": power * punit,
            "power_err": err * punit,
            "nmodes": nmodes,
            "k_lo": edges[:-1][keep] * _K_UNIT,
            "k_hi": edges[1:][keep] * _K_UNIT,
        },
        meta={
            "pixel_scale": f"{u.Quantity(pixel_scale, u.arcsec).value} arcsec",
            "shape": [int(ny), int(nx)],
            "masked_fraction": float(1 - fgood),
            "mask_method": "mean-subtracted, masked pixels zeroed, divided by unmasked fraction",
            "exclude_horizontal": bool(exclude_horizontal),
        },
    )
    for name, text in SPECTRUM_COLUMNS.items():
        table[name].description = text
    return table


def band_power(spectrum, kmin=BAND_KMIN, kmax=BAND_KMAX, return_error=False, **kwargs):
    """Mean noise power over ``kmin ≤ |k| ≤ kmax`` (default: the paper's θ = 5–20′ band, Fig. 6).

    Parameters
    ----------
    spectrum : `~astropy.table.Table` or image
        An image (``kwargs`` go to `power_spectrum`), or a table from
        `power_spectrum` whose bins tile the band exactly (edges at ``kmin``
        and ``kmax``; others are refused).  Either way the band power is the
        one definition used everywhere (``demo``, ``spectrum``, sweeps,
        figures): the mean power of every Fourier mode with
        ``kmin ≤ |k| ≤ kmax``, i.e. `power_spectrum` with the band as its
        only bin.
    kmin, kmax : float or `~astropy.units.Quantity`
        Band edges in rad/pixel.
    return_error : bool
        Also return the standard error.

    Returns
    -------
    power : `~astropy.units.Quantity`
        Band power in the spectrum's unit; ``(power, error)`` if ``return_error``.

    Raises
    ------
    EmptyBandError
        The image has no Fourier mode in the band: its lowest ``k``,
        ``2π / max(ny, nx)``, is above ``kmax`` (an image of fewer than
        ``2π / kmax`` pixels on its longer side: 49 for the default band), or
        the band falls between its modes.  The message names the band, the
        image's shape and its lowest ``k``.
    SpherexReduceError
        ``kmin``/``kmax`` out of order, or a table whose bins do not tile the band.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis import band_power
    >>> img = np.random.default_rng(2).normal(0, 3, (512, 512))
    >>> p, err = band_power(img, return_error=True)
    >>> bool(abs(p.value - 9) < 4 * err.value)
    True
    >>> band_power(img[:32, :32])
    Traceback (most recent call last):
    ...
    spherex_reduce.analysis.spectrum.EmptyBandError: no Fourier mode of the 32 x 32 image has ...
    """
    lo, hi = float(_k_value(kmin)), float(_k_value(kmax))
    if not 0 <= lo < hi:
        raise SpherexReduceError(f"band needs 0 <= kmin < kmax, got kmin={lo}, kmax={hi}")
    if isinstance(spectrum, Table) and len(spectrum) == 0 and "shape" in spectrum.meta:
        raise _empty_band(spectrum.meta["shape"], lo, hi)
    if isinstance(spectrum, Table):
        for col in ("k", "power", "power_err", "nmodes", "k_lo", "k_hi"):
            if col not in spectrum.colnames:
                raise SpherexReduceError(
                    f"spectrum table lacks column {col!r}; use a table from power_spectrum"
                )
        k_lo = _k_value(u.Quantity(spectrum["k_lo"]))
        k_hi = _k_value(u.Quantity(spectrum["k_hi"]))
        sel = (k_lo >= lo * (1 - 1e-9)) & (k_hi <= hi * (1 + 1e-9))
        # only bins that tile the band exactly give the same number as the image
        tiled = sel.any() and np.isclose(k_lo[sel].min(), lo, rtol=1e-9, atol=0) and \
            np.isclose(k_hi[sel].max(), hi, rtol=1e-9, atol=0) and \
            np.allclose(k_lo[sel][1:], k_hi[sel][:-1], rtol=1e-9, atol=0)
        if not tiled:
            raise SpherexReduceError(
                f"no spectrum bins tile {lo:g} <= k <= {hi:g} rad/pixel exactly (bins span "
                f"{k_lo.min():.3g}–{k_hi.max():.3g}); pass the image, or a spectrum whose "
                "bin edges include the band limits"
            )
        n = np.asarray(spectrum["nmodes"][sel], dtype=float)
        pw = u.Quantity(spectrum["power"][sel])
        pe = u.Quantity(spectrum["power_err"][sel])
        if n.size == 1:  # the band's own bin: the image's number to the last digit
            power, error = pw[0], pe[0]
        else:
            power = (pw * n).sum() / n.sum()
            error = np.sqrt(((pe * n) ** 2).sum()) / n.sum()
    else:
        t = power_spectrum(spectrum, bins=[lo, hi], **kwargs)
        if len(t) == 0:
            raise _empty_band(t.meta["shape"], lo, hi)
        power, error = u.Quantity(t["power"])[0], u.Quantity(t["power_err"])[0]
    return (power, error) if return_error else power


def _empty_band(shape, lo, hi):
    """The `EmptyBandError` of an image of ``shape`` with no mode in ``lo <= k <= hi``."""
    ny, nx = shape
    side = max(ny, nx)
    return EmptyBandError(
        f"no Fourier mode of the {ny} x {nx} image has {lo:g} <= k <= {hi:g} rad/pixel "
        f"(its lowest k is 2 pi/{side} = {2 * np.pi / side:.3g} rad/pixel)")


class FFTImage(NamedTuple):
    """Centred 2-D FFT magnitude near the origin (paper Fig. 7)."""

    #: ``sqrt(|FFT|² / (ny · nx · f))`` (image unit · pixel), ``ky`` down, ``kx`` across.
    magnitude: u.Quantity
    #: wave numbers of the columns (rad/pixel)
    kx: u.Quantity
    #: wave numbers of the rows (rad/pixel)
    ky: u.Quantity

    @classmethod
    def around_origin(cls, magnitude, size, unit=u.one):
        """The ``size × size`` cells around ``k = 0`` of a full ``fft2`` plane of magnitudes
        (not shifted), in ``unit`` · pixel."""
        ny, nx = magnitude.shape
        half = max(int(size), 1) // 2
        ys = slice(max(ny // 2 - half, 0), min(ny // 2 + half + 1, ny))
        xs = slice(max(nx // 2 - half, 0), min(nx // 2 + half + 1, nx))
        ky = 2 * np.pi * np.fft.fftshift(np.fft.fftfreq(ny))[ys]
        kx = 2 * np.pi * np.fft.fftshift(np.fft.fftfreq(nx))[xs]
        return cls(np.fft.fftshift(magnitude)[ys, xs] * unit * u.pix, kx * _K_UNIT,
                   ky * _K_UNIT)


def fft_magnitude(image, mask=None, size=129):
    """2-D FFT magnitude of an image, centred and cropped to the origin (Fig. 7).

    Normalised like `power_spectrum`: the magnitude squared is the power of
    each Fourier cell, so white noise of variance σ² gives magnitudes of
    order σ.  Masked pixels are treated as in `power_spectrum`.

    Parameters
    ----------
    image : CCDData, NDData, Quantity or array
    mask : array-like of bool, optional
    size : int
        Cells kept along each axis around ``k = 0`` (odd; clipped to the image).

    Returns
    -------
    `FFTImage`
        ``magnitude`` (``size × size``), ``kx``, ``ky``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis import fft_magnitude
    >>> img = np.sin(2 * np.pi * np.arange(64) / 16)[None, :] * np.ones((64, 1))
    >>> f = fft_magnitude(img, size=33)
    >>> iy, ix = np.unravel_index(np.argmax(f.magnitude.value), f.magnitude.shape)
    >>> round(abs(float(f.kx[ix].value)), 4), float(f.ky[iy].value)   # 2π/16
    (0.3927, 0.0)
    """
    data, bad, unit = _as_image(image, mask)
    x, fgood = _prepared(data, bad)
    return FFTImage.around_origin(np.abs(scipy.fft.fft2(x, workers=-1)) / np.sqrt(x.size * fgood),
                                  size, unit)
