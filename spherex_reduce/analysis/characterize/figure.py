"""The figure of a characterisation: each spectrum measured and its fit (paper Fig. 4), and
where the darks' slope images were measured, their scatter against N (Fig. 12a) and their
reduced P(k) against the forecast."""

import numpy as np
from astropy import units as u
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

__all__ = ["plot_characterization"]

#: Auto-spectra (positive: log axes) and cross-spectra (either sign: linear axis), with
#: what each curve is, in words.
AUTO = {"pixels": "light-sensitive pixels (each channel)",
        "acn": "even - odd columns / 2 (ACN)",
        "phantom": "phantom reads (each channel)",
        "reference": "reference pixels"}
CROSS = {"pixels_common": "pixels, channel x other channel (common)",
         "phantom_common": "phantom, channel x other channel (common)",
         "both": "pixels x phantom, same channel",
         "both_common": "pixels x phantom, other channels"}


def plot_characterization(model):
    """Measured spectra (points, the mean over darks) and fitted models (lines); the slope
    scatter against N and the reduced P(k), measured and predicted, when the model has them.

    Top left: the auto-spectra (light-sensitive pixels' channel streams, the
    even-odd difference, the phantom reads, the reference-row bursts), log
    axes.  Top right: the cross-spectra (between channels, pixels × phantom),
    which can be negative where a term is absent, on a linear axis scaled by
    the pixels' spectrum.  With ``model.check``
    (`~spherex_reduce.analysis.characterize.check.compare`), bottom left: the
    slope scatter over pixels against the frame count N (points: measured;
    line: predicted; dashed: predicted without the telegraph pixels, paper
    Fig. 12a); bottom right: the reduced P(k) measured and forecast, the
    5-20′ band shaded.

    Parameters
    ----------
    model : `~spherex_reduce.analysis.characterize.Characterization`

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize import characterize
    >>> from spherex_reduce.analysis.characterize.figure import plot_characterization
    >>> len(plot_characterization(characterize(example_raw_exposure(), segments=2)).axes)
    2
    """
    check = model.check
    rows = 1 if check is None else 2
    fig = Figure(figsize=(12, 4.8 * rows), layout="constrained")
    axes = np.atleast_2d(fig.subplots(rows, 2))
    _spectra(model, *axes[0])
    if check is not None:
        _scatter(check, axes[1, 0])
        _power(check, axes[1, 1])
    fig.suptitle(f"{len(model.darks)} dark(s), {model.ngroups} segments: spectra and fits "
                 f"(exponent {model.exponent:.3g})", fontsize=11)
    return fig


def _spectra(model, left, right):
    from ...io.plotting import unit_label

    unit = unit_label(model.unit**2 / u.Hz)
    bins = model.bins
    for i, name in enumerate(n for n in AUTO if n in bins):
        b = bins[name]
        f = np.asarray(b["frequency"])
        ok = np.asarray(b["psd"]) > 0
        left.plot(f[ok], np.asarray(b["psd"])[ok], "o", ms=3, color=f"C{i}", label=AUTO[name])
        left.plot(f, np.asarray(b["model"]), "-", lw=1, color=f"C{i}")
    left.set_xscale("log")
    left.set_yscale("log")
    left.set_title("auto-spectra (points: measured, lines: fit)", fontsize=10)
    left.set_ylabel(f"one-sided PSD ({unit})")
    ref = bins.get("pixels")
    for i, name in enumerate(n for n in CROSS if n in bins):
        b = bins[name]
        f = np.asarray(b["frequency"])
        scale = np.interp(f, np.asarray(ref["frequency"]), np.asarray(ref["model"]))
        right.plot(f, np.asarray(b["psd"]) / scale, "o", ms=3, color=f"C{i + 4}",
                   label=CROSS[name])
        right.plot(f, np.asarray(b["model"]) / scale, "-", lw=1, color=f"C{i + 4}")
    right.axhline(0, color="0.5", lw=0.8)
    right.set_xscale("log")
    right.set_title("cross-spectra / the pixels' fitted PSD (points: measured, lines: fit)",
                    fontsize=10)
    right.set_ylabel("cross-spectrum / pixels' PSD")
    for ax in (left, right):
        ax.xaxis.set_minor_formatter(NullFormatter())  # labelled decades only: no overlap
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.2)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)


def _scatter(check, ax):
    from ...io.plotting import unit_label

    t = check[check["quantity"] == "slope_scatter"]
    n = np.asarray(t["frames"], dtype=float)
    ax.errorbar(n, t["measured"], yerr=t["error"], fmt="o", ms=4, color="C0",
                label=f"measured ({check.meta['pairs']} pair(s) of darks)")
    ax.plot(n, t["predicted"], "-", color="C1", label="predicted by the model")
    ax.plot(n, t["predicted_streams"], "--", color="C2",
            label="predicted without the telegraph pixels")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xticks(n, [str(int(v)) for v in n])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("frame count N")
    ax.set_ylabel(f"slope scatter sigma ({unit_label(u.Unit(check.meta['unit']))})")
    ax.set_title("pixel standard deviation, 5 sigma clipped, against N (paper Fig. 12a)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.2)
    ax.legend(fontsize=8)


def _power(check, ax):
    from ...analysis.spectrum import BAND_KMAX, BAND_KMIN
    from ...io.plotting import unit_label

    t = check[check["quantity"] == "power_spectrum"]
    k = np.asarray(t["k"])
    ok = np.asarray(t["measured"]) > 0
    ax.plot(k[ok], np.asarray(t["measured"])[ok], "o", ms=3, color="C0",
            label=f"measured at N = {t['frames'][0]}")
    ax.plot(k, t["predicted"], "-", color="C1", label="forecast of the model")
    ax.plot(k, t["predicted_streams"], "--", color="C2",
            label="forecast without the telegraph pixels")
    ax.axvspan(BAND_KMIN, BAND_KMAX, color="0.85", zorder=0, label="5-20' band")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("k (rad/pixel)")
    ax.set_ylabel(f"P(k) ({unit_label(u.Unit(check.meta['power_unit']))})")
    ax.set_title("reduced slope image's power spectrum", fontsize=10)
    ax.grid(True, which="both", alpha=0.2)
    ax.legend(fontsize=8)
