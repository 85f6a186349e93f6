"""The figure of a characterisation: each spectrum measured and its fit (paper Fig. 4)."""

import numpy as np
from astropy import units as u
from matplotlib.figure import Figure

__all__ = ["plot_characterization"]

#: Auto-spectra (positive: log axes) and cross-spectra (either sign: linear axis).
AUTO = ("pixels", "acn", "phantom", "reference")
CROSS = ("pixels_common", "phantom_common", "both", "both_common")


def plot_characterization(model):
    """Measured spectra (points, the mean over darks) and fitted models (lines).

    Left: the auto-spectra (light-sensitive pixels' channel streams, the
    even-odd difference, the phantom reads, the reference-row bursts), log
    axes.  Right: the cross-spectra (between channels, pixels × phantom),
    which can be negative where a term is absent, on a linear axis scaled by
    the pixels' spectrum.

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
    from ...io.plotting import unit_label

    fig = Figure(figsize=(11, 4.6), layout="constrained")
    left, right = fig.subplots(1, 2)
    unit = unit_label(model.unit**2 / u.Hz)
    bins = model.bins
    for i, name in enumerate(n for n in AUTO if n in bins):
        b = bins[name]
        f = np.asarray(b["frequency"])
        ok = np.asarray(b["psd"]) > 0
        left.plot(f[ok], np.asarray(b["psd"])[ok], "o", ms=3, color=f"C{i}", label=name)
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
        right.plot(f, np.asarray(b["psd"]) / scale, "o", ms=3, color=f"C{i + 4}", label=name)
        right.plot(f, np.asarray(b["model"]) / scale, "-", lw=1, color=f"C{i + 4}")
    right.axhline(0, color="0.5", lw=0.8)
    right.set_xscale("log")
    right.set_title("cross-spectra, relative to the pixels' fitted spectrum", fontsize=10)
    right.set_ylabel("cross-spectrum / pixels' PSD")
    for ax in (left, right):
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.2)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.suptitle(f"{len(model.darks)} dark(s), {model.ngroups} segments: spectra and fits "
                 f"(exponent {model.exponent:.3g})", fontsize=11)
    return fig
