"""Figures of the analysis: P(k) (paper Figs. 9, 10, 13), 2-D FFT (Fig. 7), PSD fits.

Built on `matplotlib.figure.Figure` (no pyplot state); save them with
`spherex_reduce.plotting.save_figure`.
"""

import numpy as np
from astropy import units as u
from matplotlib.figure import Figure

from .spectrum import BAND_KMAX, BAND_KMIN, SPHEREX_PIXEL_SCALE, theta_from_k

__all__ = ["plot_fft_magnitude", "plot_noise_fit", "plot_spectra"]


def plot_spectra(spectra, band=(BAND_KMIN, BAND_KMAX), photon=None, title="",
                 pixel_scale=SPHEREX_PIXEL_SCALE):
    """Log-log P(k) of one or more spectra with the 5–20′ band shaded.

    Parameters
    ----------
    spectra : dict of label -> `~astropy.table.Table`
        Tables from `~spherex_reduce.analysis.power_spectrum`.
    band : (float, float) or None
        Band to shade, in rad/pixel.
    photon : `~astropy.units.Quantity`, optional
        Photon-noise power, drawn as a horizontal line.
    title : str

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis import power_spectrum
    >>> from spherex_reduce.analysis.plots import plot_spectra
    >>> t = power_spectrum(np.random.default_rng(0).normal(size=(64, 64)), bins=6)
    >>> fig = plot_spectra({"white": t}, photon=1.0)
    >>> fig.axes[0].get_xscale()
    'log'
    """
    fig = Figure(figsize=(7, 5))
    ax = fig.subplots()
    unit = None
    for label, t in spectra.items():
        p = u.Quantity(t["power"])
        unit = unit or p.unit
        k = np.asarray(t["k"])
        pv = p.to_value(unit)
        err = u.Quantity(t["power_err"]).to_value(unit)
        lower = np.minimum(err, 0.9 * pv)  # keep the bar on a log axis
        ax.errorbar(k, pv, yerr=[lower, err], fmt="o-", ms=3, lw=1, capsize=2, label=label)
    if band is not None:
        ax.axvspan(band[0], band[1], color="tab:red", alpha=0.15,
                   label=f"band {band[0]:g} < k < {band[1]:g} "
                   f"(θ ≈ {theta_from_k(band[1], pixel_scale).value:.0f}–"
                   f"{theta_from_k(band[0], pixel_scale).value:.0f}′)")
    if photon is not None:
        ph = u.Quantity(photon)
        value = ph.to_value(unit) if (unit is not None and ph.unit != u.one) else ph.value
        ax.axhline(value, color="0.3", ls="--", lw=1, label="photon noise")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("k (rad / pixel)")
    ax.set_ylabel(f"P(k) ({unit.to_string() if unit not in (None, u.one) else 'pixel²'})")
    scale = u.Quantity(pixel_scale, u.arcmin).value

    def to_theta(k):
        with np.errstate(divide="ignore"):
            return 2 * np.pi * scale / np.asarray(k, dtype=float)

    top = ax.secondary_xaxis("top", functions=(to_theta, to_theta))
    top.set_xlabel("θ (arcmin)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.2)
    if title:
        ax.set_title(title, fontsize=10)
    return fig


def plot_fft_magnitude(images, title=""):
    """Side-by-side 2-D FFT magnitudes (paper Fig. 7).

    Parameters
    ----------
    images : dict of label -> `~spherex_reduce.analysis.FFTImage`

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    fig = Figure(figsize=(5.5 * len(images), 4.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(images)))
    vmax = max(float(np.max(im.magnitude.value)) for im in images.values())
    for ax, (label, im) in zip(axes, images.items(), strict=True):
        kx, ky = im.kx.value, im.ky.value
        mag = im.magnitude.value
        shown = ax.imshow(np.log10(np.maximum(mag, vmax * 1e-6)), origin="lower",
                          extent=(kx[0], kx[-1], ky[0], ky[-1]), aspect="auto", cmap="viridis",
                          vmin=np.log10(vmax) - 4, vmax=np.log10(vmax))
        ax.set_xlabel("k_x (rad / pixel)")
        ax.set_ylabel("k_y (rad / pixel)")
        ax.set_title(label, fontsize=10)
        fig.colorbar(shown, ax=ax, label="log10 |FFT|")
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_noise_fit(fits, title=""):
    """Binned temporal PSDs with their fitted ``α + β/f + γ/f^e`` models.

    Parameters
    ----------
    fits : dict of label -> `~spherex_reduce.analysis.NoiseModelFit`

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    fig = Figure(figsize=(7, 5))
    ax = fig.subplots()
    for i, (label, fit) in enumerate(fits.items()):
        b = fit.bins
        colour = f"C{i}"
        for s in np.unique(b["spectrum"]):
            sel = b["spectrum"] == s
            f = np.asarray(b["frequency"][sel])
            ax.errorbar(f, b["psd"][sel], yerr=b["psd_err"][sel], fmt="o", ms=3, color=colour,
                        label=f"{label} (spectrum {s})" if len(np.unique(b["spectrum"])) > 1
                        else label)
            ax.plot(f, b["model"][sel], "-", color=colour, lw=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of the stream (unit² / Hz)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.2)
    ax.set_title(title or "temporal PSD and fitted α + β/f + γ/f^e", fontsize=10)
    return fig
