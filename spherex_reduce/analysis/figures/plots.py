"""Figures of the analysis: P(k) (paper Figs. 9, 10, 13), 2-D FFT (Fig. 7), PSD fits.

Built on `matplotlib.figure.Figure` (no pyplot state); save them with
`spherex_reduce.io.plotting.save_figure`.
"""

import numpy as np
from astropy import units as u
from matplotlib.figure import Figure

from ..spectrum import BAND_KMAX, BAND_KMIN, SPHEREX_PIXEL_SCALE, band_label, band_theta

__all__ = ["plot_comparison", "plot_fft_magnitude", "plot_forecast", "plot_noise_fit",
           "plot_spectra"]


def plot_spectra(spectra, band=(BAND_KMIN, BAND_KMAX), photon=None, title="",
                 pixel_scale=SPHEREX_PIXEL_SCALE, photon_label="photon noise", ax=None,
                 styles=None):
    """Log-log P(k) of one or more spectra with the band shaded.

    Bins with no power (P ≤ 0, e.g. a component that feeds only some modes)
    cannot be drawn on a log axis and are left out, breaking the line.  Error
    bars are drawn where the spectra have them (a lower end that would reach
    zero stops one decade below the point); a spectrum without errors (one
    realisation of a mean) is a plain line, and its legend entry shows no bar.

    Parameters
    ----------
    spectra : dict of label -> `~astropy.table.Table`
        Tables from `~spherex_reduce.analysis.power_spectrum` (``k``,
        ``power`` and optionally ``power_err``).
    band : (float, float) or None
        Band to shade, in rad/pixel; labelled by `band_label` (the nominal
        band), the θ it really gives (`band_theta`) in the figure's caption.
    photon : `~astropy.units.Quantity`, optional
        Photon-noise power, drawn as a horizontal line.
    title : str
    pixel_scale : `~astropy.units.Quantity`
        For the θ axis and the band label.
    photon_label : str
        Legend of the photon-noise line: say its photocurrent and time, e.g.
        ``"photon noise, 1 e/s for 112 s"`` (`photon_noise_label`).
    ax : `matplotlib.axes.Axes`, optional
        Draw into this axes (a panel of a larger figure) instead of a new figure.
    styles : dict of label -> dict, optional
        Matplotlib keywords overriding the style of a spectrum's line (default:
        points joined by a thin line).

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis import power_spectrum
    >>> from spherex_reduce.analysis.figures.plots import plot_spectra
    >>> t = power_spectrum(np.random.default_rng(0).normal(size=(64, 64)), bins=6)
    >>> fig = plot_spectra({"white": t}, photon=1.0)
    >>> fig.axes[0].get_xscale()
    'log'
    """
    from ...io.plotting import unit_label

    if ax is None:
        fig = Figure(figsize=(7, 5.2), layout="constrained")
        ax = fig.subplots()
        if band is not None:
            _band_caption(fig, band, pixel_scale)
    fig = ax.figure
    unit = None
    styles = styles or {}
    for label, t in spectra.items():
        style = {"marker": "o", "ls": "-", "ms": 3, "lw": 1, **styles.get(label, {})}
        p = u.Quantity(t["power"])
        unit = unit or p.unit
        k = np.asarray(u.Quantity(t["k"]).value, dtype=float)
        pv = p.to_value(unit)
        drawn = np.isfinite(pv) & (pv > 0)  # a log axis has no place for P <= 0
        pv = np.where(drawn, pv, np.nan)
        err = (u.Quantity(t["power_err"]).to_value(unit) if "power_err" in t.colnames
               else np.zeros_like(pv))
        err = np.where(drawn & np.isfinite(err) & (err > 0), err, 0.0)
        if np.any(err > 0):
            lower = np.minimum(err, 0.9 * np.nan_to_num(pv))  # stop a decade below at most
            ax.errorbar(k, pv, yerr=[lower, err], capsize=2, label=label, **style)
        else:
            ax.plot(k, pv, label=label, **style)
    if band is not None:
        ax.axvspan(band[0], band[1], color="tab:red", alpha=0.15,
                   label="band " + band_label(band[0], band[1], pixel_scale))
    if photon is not None:
        ph = u.Quantity(photon)
        value = ph.to_value(unit) if (unit is not None and ph.unit != u.one) else ph.value
        ax.axhline(value, color="0.3", ls="--", lw=1, label=photon_label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("k (rad / pixel)")
    shown = unit_label(unit) if unit not in (None, u.one) else "pixel$^{2}$"
    ax.set_ylabel(f"P(k) ({shown})")
    _theta_axis(ax, pixel_scale)
    ax.legend(fontsize=8, loc="best")  # the place that covers fewest points
    ax.grid(True, which="both", alpha=0.2)
    if title:
        ax.set_title(title, fontsize=10)
    return fig


#: A component's P below this fraction of the total's largest is its rounding (a component
#: the reduction cancels): drawn as no power.
ROUNDING = 1e-12


def plot_forecast(table, measured=None, measured_label="measured", title="",
                  pixel_scale=SPHEREX_PIXEL_SCALE, photon=None, photon_label="photon noise"):
    """A forecast P(k), total and per noise component, with measured points over it.

    Parameters
    ----------
    table : `~astropy.table.Table`
        From `~spherex_reduce.analysis.forecast`: ``k``, ``power`` and a
        ``power_<name>`` column per noise component; its meta's ``band_kmin``
        and ``band_kmax`` are the band shaded.
    measured : `~astropy.table.Table`, optional
        A measured spectrum (`~spherex_reduce.analysis.power_spectrum`, the
        ``spectrum`` command's ECSV): drawn as points with their error bars.
    measured_label : str
        What the measured points are, for the legend.
    title : str
        Default: the pipeline (the meta's ``config``, else its ``pipeline``)
        and the forecast band power.
    pixel_scale : `~astropy.units.Quantity`
        For the θ axis and the band label.
    photon, photon_label
        The photon-noise line and its legend, as `plot_spectra` draws them
        (`~spherex_reduce.analysis.photon_noise_power`,
        `~spherex_reduce.analysis.photon_noise_label`).

    Returns
    -------
    `matplotlib.figure.Figure`
        The P axis holds every drawn line.  A component's bins below
        `ROUNDING` times the total's largest bin are its rounding (a component
        the reduction cancels exactly) and drawn as no power; a component with
        no other bin is left out, like one with none.

    Examples
    --------
    >>> from spherex_reduce.analysis import forecast
    >>> from spherex_reduce.analysis.figures.plots import plot_forecast
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0}}
    >>> fig = plot_forecast(forecast(scene, measure={"bins": 6}))
    >>> [t.get_text() for t in fig.axes[0].get_legend().get_texts()][:2]
    ['forecast: total', 'forecast: video8']
    """
    from astropy.table import Table

    from ...io.plotting import unit_label

    meta = table.meta
    k = u.Quantity(table["k"])
    total = u.Quantity(table["power"])
    spectra = {"forecast: total": Table({"k": k, "power": total})}
    styles = {"forecast: total": {"marker": "", "lw": 2.2, "color": "k"}}
    rounding = ROUNDING * float(np.nanmax(total.value, initial=0.0))
    for name in table.colnames:
        if not name.startswith("power_") or name == "power_err":
            continue
        power = u.Quantity(table[name])
        label = f"forecast: {name.removeprefix('power_')}"
        if name == "power_masked":  # signed: the power a clip's mask moves between scales
            power, label = np.abs(power), "forecast: |masked| (moved by the clip's mask)"
        kept = np.where(power.value > rounding, power.value, 0.0)
        if np.any(kept > 0):
            spectra[label] = Table({"k": k, "power": kept * power.unit})
            styles[label] = {"marker": "", "ls": ":" if name == "power_masked" else "--"}
    if measured is not None:
        label = f"measured: {measured_label}"
        spectra[label] = measured
        styles[label] = {"marker": "o", "ls": "", "ms": 4, "color": "tab:red", "zorder": 3}
    band = (meta.get("band_kmin", BAND_KMIN), meta.get("band_kmax", BAND_KMAX))
    if not title:
        value = meta.get("band_power")
        shown = "missing" if value is None else f"{value:.3g} {unit_label(total.unit)}"
        title = (f"forecast P(k) through {meta.get('config') or meta.get('pipeline', 'none')}"
                 f"; band power {shown}")
    fig = plot_spectra(spectra, band=band, title=title, pixel_scale=pixel_scale,
                       styles=styles, photon=photon, photon_label=photon_label)
    _hold_every_line(fig.axes[0])
    # outside the axes: inside, the components' curves leave it no free corner
    fig.axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                       borderaxespad=0.0)
    fig.set_size_inches(9.5, 5.2)
    return fig


def _hold_every_line(ax):
    """Set the log P range of ``ax`` to its lines' positive finite values, a fifth of a
    decade to spare at each end."""
    values = np.concatenate([np.asarray(line.get_ydata(), float) for line in ax.get_lines()])
    values = values[np.isfinite(values) & (values > 0)]
    if values.size:
        ax.set_ylim(values.min() / 10**0.2, values.max() * 10**0.2)


def _band_caption(fig, band, pixel_scale):
    """The θ range the shaded band really gives, as the figure's caption (its legend
    names the nominal band)."""
    fig.supxlabel(f"shaded band: {band_theta(band[0], band[1], pixel_scale)}", fontsize=8,
                  color="0.3")


def _theta_axis(ax, pixel_scale):
    """A secondary x axis at the top: the angular period θ (arcmin) of the k axis."""
    scale = u.Quantity(pixel_scale, u.arcmin).value

    def to_theta(k):
        with np.errstate(divide="ignore"):
            return 2 * np.pi * scale / np.asarray(k, dtype=float)

    top = ax.secondary_xaxis("top", functions=(to_theta, to_theta))
    top.set_xlabel("θ (arcmin)")
    return top


def plot_fft_magnitude(images, title=""):
    """Side-by-side 2-D FFT magnitudes (paper Fig. 7).

    Parameters
    ----------
    images : dict of label -> `~spherex_reduce.analysis.FFTImage`
        Drawn in rows of two, on one colour scale.

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    from ...io.plotting import show_image

    ncols = min(len(images), 2)
    nrows = -(-len(images) // ncols)
    fig = Figure(figsize=(5.5 * ncols, 4.6 * nrows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols)).ravel()[:len(images)]
    vmax = max(float(np.max(im.magnitude.value)) for im in images.values())
    for ax, (label, im) in zip(axes, images.items(), strict=True):
        kx, ky = im.kx.value, im.ky.value
        mag = im.magnitude.value
        show_image(ax, np.log10(np.maximum(mag, vmax * 1e-6)), "log10 |FFT|",
                   extent=(kx[0], kx[-1], ky[0], ky[-1]), aspect="auto", cmap="viridis",
                   vmin=np.log10(vmax) - 4, vmax=np.log10(vmax))
        ax.set_xlabel("k_x (rad / pixel)")
        ax.set_ylabel("k_y (rad / pixel)")
        ax.set_title(label, fontsize=10)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_noise_fit(fits, title="", unit=None):
    """Binned temporal PSDs with their fitted ``α + β/f + γ/f^e`` models.

    Parameters
    ----------
    fits : dict of label -> `~spherex_reduce.analysis.NoiseModelFit`
        A fit of several spectra at once (e.g. the reference columns and the
        reference-row reads of `~spherex_reduce.analysis.fit_raw_noise`)
        draws each, named from its ``bins.meta["spectra"]``.
    title : str
    unit : `~astropy.units.Unit`, optional
        Unit of the PSD values; default ``bins.meta["psd_unit"]`` (set by
        `~spherex_reduce.analysis.fit_raw_noise`).

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    from ...io.plotting import unit_label

    fig = Figure(figsize=(7, 5.2), layout="constrained")
    ax = fig.subplots()
    for i, (label, fit) in enumerate(fits.items()):
        b = fit.bins
        unit = unit if unit is not None else b.meta.get("psd_unit")
        which = np.unique(b["spectrum"])
        names = list(b.meta.get("spectra") or [f"spectrum {s}" for s in which])
        markers = "os^vD"
        for j, s in enumerate(which):
            sel = b["spectrum"] == s
            f = np.asarray(b["frequency"][sel])
            name = names[int(s)] if int(s) < len(names) else f"spectrum {s}"
            text = label if len(which) == 1 and name == label else f"{label}: {name}"
            ax.errorbar(f, b["psd"][sel], yerr=b["psd_err"][sel], fmt=markers[j % 5], ms=3,
                        color=f"C{i}", label=text)
            ax.plot(f, b["model"][sel], "-", color=f"C{i}", lw=1)
    ax.plot([], [], "-", color="0.3", lw=1, label="lines: fitted model")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frequency (Hz)")
    shown = unit_label(unit)
    ax.set_ylabel(f"one-sided PSD ({shown})" if shown else "one-sided PSD")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.2)
    ax.set_title(title or "temporal PSD and fitted α + β/f + γ/f^e", fontsize=10)
    return fig


def _mean(values):
    """Mean over the rows of the finite values (NaN where a column has none)."""
    good = np.isfinite(values)
    n = good.sum(axis=0)
    total = np.where(good, values, 0.0).sum(axis=0)
    return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def _sem(values):
    """Standard error of the mean over the rows of the finite values (0 with fewer than 2)."""
    good = np.isfinite(values)
    n = good.sum(axis=0)
    dev = np.where(good, values - _mean(values), 0.0)
    var = (dev**2).sum(axis=0) / np.maximum(n - 1, 1)
    return np.where(n > 1, np.sqrt(var / np.maximum(n, 1)), 0.0)


def plot_comparison(table, title="", pixel_scale=SPHEREX_PIXEL_SCALE):
    """The two panels of ``compare-strategies``: residual noise P(k) and sky transfer T(k).

    Left: the P(k) of ``reduced − injected sky`` per pipeline (mean over
    realisations, error bars their standard error), the band shaded, the
    photon-noise level and the white floor (the noise model's white terms,
    which no correction removes).  Right: the transfer ``T(k) = P_cross(Δ,
    sky) / P_sky`` per pipeline, ``Δ`` the reduced image with the sky minus
    the same noise reduced without it (1: the sky is kept at that scale, 0:
    removed).

    Parameters
    ----------
    table : `~astropy.table.Table`
        From `~spherex_reduce.analysis.compare.compare_strategies` (its
        columns ``pipeline``, ``k``, ``power``, ``transfer`` and its meta).
    title : str
    pixel_scale : `~astropy.units.Quantity`
        For the θ axes.

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    from astropy.table import Table

    meta = table.meta
    band = tuple(meta.get("band", (BAND_KMIN, BAND_KMAX)))
    fig = Figure(figsize=(13, 5.6), layout="constrained")
    left, right = fig.subplots(1, 2)
    _band_caption(fig, band, pixel_scale)
    names = list(dict.fromkeys(str(p) for p in table["pipeline"]))
    unit = u.Unit(table["power"].unit or "")
    spectra, transfers = {}, {}
    k_all = np.asarray(table["k"], dtype=float)
    for name in names:
        sel = np.asarray(table["pipeline"]) == name
        k = _mean(k_all[sel])
        power = np.asarray(table["power"][sel], dtype=float)
        tr = np.asarray(table["transfer"][sel], dtype=float)
        spectra[name] = Table({"k": k, "power": _mean(power) * unit,
                               "power_err": _sem(power) * unit})
        transfers[name] = (k, _mean(tr), _sem(tr))
    photon = meta.get("photon_noise")
    plot_spectra(spectra, band=band, photon=None if photon is None else photon * unit,
                 pixel_scale=pixel_scale, ax=left,
                 photon_label=meta.get("photon_noise_label") or "photon noise")
    if meta.get("floor") is not None:
        left.axhline(meta["floor"], color="0.3", ls=":", lw=1.2,
                     label="white floor (noise model's α terms)")
    left.legend(fontsize=8, loc="upper right")
    left.set_title("residual: reduced − injected sky (noise left + sky lost)", fontsize=10)
    for i, (name, (k, t, err)) in enumerate(transfers.items()):
        good = np.isfinite(t)
        right.errorbar(k[good], t[good], yerr=err[good], fmt="o-", ms=3, lw=1, capsize=2,
                       color=f"C{i}", label=name)
    right.axvspan(*band, color="tab:red", alpha=0.15,
                  label="band " + band_label(band[0], band[1], pixel_scale))
    right.axhline(1.0, color="0.3", ls="--", lw=1)
    right.axhline(0.0, color="0.3", ls="-", lw=0.8)
    right.set_xscale("log")
    right.set_xlabel("k (rad / pixel)")
    right.set_ylabel("sky transfer T(k) = P_cross(Δ, sky) / P_sky")
    _theta_axis(right, pixel_scale)
    right.grid(True, which="both", alpha=0.2)
    right.legend(fontsize=8, loc="center right")  # T is near 1 or dips: the middle is free
    right.set_title("sky kept at each scale: 1 = all kept, 0 = all removed\n"
                    "Δ = reduced with the sky − the same noise reduced without it", fontsize=10)
    sky = (meta.get("config") or {}).get("sky") or {}
    n_real = len(table) // max(len(names), 1)
    fig.suptitle(title or f"{len(names)} pipelines, {n_real} realisation(s), sky rms "
                 f"{sky.get('rms', '?')} e/s, P(k) ∝ k^{sky.get('index', '?')}; "
                 "mean ± s.e. over realisations", fontsize=11)
    return fig
