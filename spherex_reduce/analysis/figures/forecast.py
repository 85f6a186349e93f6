"""The paper's Figs. 6-9 as forecast curves over Monte Carlo points, drawn from their numbers.

``figures --forecast`` records every number it draws (``figures.ecsv``: one
row per point, ``figure``, ``series``, ``x``, ``y``, ``y_err``, ``unit``);
the forecast of a series ``NAME`` is the series ``NAME, forecast`` (no
error).  `plot_forecast_figure` draws Fig. 6, 7, 8 or 9 from those rows: the
forecast as lines, the Monte Carlo as points with their standard errors, in
one colour per series.  The report of ``figures --forecast`` and the
documentation's page of the paper's figures draw with it.

Rows per figure (``y_name``): Figs. 6 and 8 ``band_power`` against S or r;
Fig. 7 ``power_ky``, the mean ``|FFT|²`` over the cropped ``k_x`` of each
``k_y`` (the Fourier power near the horizontal axis and in the S = 24
packets); Fig. 9 ``power``, P(k) in each bin, and ``photon_power``, the
photon-noise line (its series is the line's label).
"""

import numpy as np
from astropy import units as u
from astropy.table import Table

__all__ = ["FORECAST", "TITLES", "plot_forecast_figure"]

#: What ends the series name of a forecast.
FORECAST = ", forecast"
#: The title of each figure.
TITLES = {
    "6": "Fig. 6: band power (θ = 5–20′, k_y = 0 excluded) against S",
    "7": "Fig. 7: Fourier power near the horizontal axis, phantom-corrected, no reference "
         "correction",
    "8": "Fig. 8: reference correction with repeated / distributed reads, S = 24",
    "9": "Fig. 9b: S = 24, phantom-corrected, before reference correction",
}
_SCANS = {"6": ("skip S (rows)", {"value": "log"}), "8": ("reference row reads r",
                                                         {"value": "log", "base": 2})}


def plot_forecast_figure(numbers, figure):
    """Fig. 6, 7, 8 or 9 of a run's numbers: forecast curves over Monte Carlo points.

    Parameters
    ----------
    numbers : `~astropy.table.Table`
        ``figures.ecsv`` of ``spherex-reduce figures --forecast`` (or its rows).
    figure : {'6', '7', '8', '9'}

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> from astropy.table import Table
    >>> from spherex_reduce.analysis.figures.forecast import plot_forecast_figure
    >>> rows = [{"figure": "6", "series": s, "x_name": "S", "x": x, "y_name": "band_power",
    ...          "y": y, "y_err": e, "unit": "electron2 pix2 / s2"}
    ...         for s, e in (("corrected", 0.1), ("corrected, forecast", 0.0))
    ...         for x, y in ((1, 2.0), (24, 1.5))]
    >>> ax = plot_forecast_figure(Table(rows=rows), "6").axes[0]
    >>> [t.get_text() for t in ax.get_legend().get_texts()]
    ['forecast', 'Monte Carlo (mean ± s.e.)']
    """
    rows = numbers[np.asarray(numbers["figure"]).astype(str) == str(figure)]
    if figure in _SCANS:
        return _scan(rows, figure)
    if figure == "7":
        return _profile(rows)
    if figure == "9":
        return _spectrum(rows)
    raise ValueError(f"figure {figure!r}: only Figs. 6, 7, 8 and 9 are forecast")


def _series(rows, y_name):
    """``{name: (x, y, y_err)}`` of the Monte Carlo series and of their forecasts."""
    rows = rows[rows["y_name"] == y_name]
    out = {}
    for name in dict.fromkeys(str(s) for s in rows["series"]):
        r = rows[rows["series"] == name]
        order = np.argsort(np.asarray(r["x"], float))
        out[name] = tuple(np.asarray(r[c], float)[order] for c in ("x", "y", "y_err"))
    mc = {n: v for n, v in out.items() if not n.endswith(FORECAST)}
    return mc, {n: out.get(n + FORECAST) for n in mc}, _unit(rows)


def _unit(rows):
    return u.Unit(str(rows["unit"][0])) if len(rows) and str(rows["unit"][0]) else u.one


def _draw(ax, mc, fc, **points):
    """Each series' forecast as a line (on top) and its Monte Carlo as points, in one
    colour; ``points`` styles the points (`~matplotlib.axes.Axes.errorbar`)."""
    one = len(mc) == 1
    for name, (x, y, e) in mc.items():
        color = None
        if fc[name] is not None:
            (line,) = ax.plot(fc[name][0], fc[name][1], "-", lw=1.5, zorder=3,
                              label="forecast" if one else f"{name}, forecast")
            color = line.get_color()
        ax.errorbar(x, y, yerr=e, color=color, **({"fmt": "o", "capsize": 3} | points),
                    label="Monte Carlo (mean ± s.e.)" if one else f"{name}, Monte Carlo "
                    "(mean ± s.e.)")


def _scan(rows, figure):
    from matplotlib.figure import Figure

    from ...io.plotting import unit_label

    mc, fc, unit = _series(rows, "band_power")
    xlabel, xscale = _SCANS[figure]
    fig = Figure(figsize=(7, 5), layout="constrained")
    ax = fig.subplots()
    _draw(ax, mc, fc)
    ax.set_xscale(**xscale)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"band power ({unit_label(unit)})")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.set_title(TITLES[figure], fontsize=10)
    return fig


def _profile(rows):
    from matplotlib.figure import Figure

    from ...io.plotting import unit_label

    mc, fc, unit = _series(rows, "power_ky")
    fig = Figure(figsize=(7, 5), layout="constrained")
    ax = fig.subplots()
    _draw(ax, mc, fc, ms=2.5, capsize=0, elinewidth=0.6, alpha=0.6)
    for sign in (-1, 1):
        ax.axvline(sign * 2 * np.pi / 24, color="0.5", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel("k_y (rad / pixel); dotted: ±2π/24, the S = 24 packets")
    ax.set_ylabel(f"mean |FFT|² over k_x ({unit_label(unit)})")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.set_title(TITLES["7"], fontsize=10)
    return fig


def _spectrum(rows):
    from .plots import plot_spectra

    mc, fc, unit = _series(rows, "power")
    photon = rows[rows["y_name"] == "photon_power"]

    def table(x, y, e=None):
        t = Table({"k": x * u.rad / u.pix, "power": y * unit})
        if e is not None:
            t["power_err"] = e * unit
        return t

    one = len(mc) == 1
    spectra = {("one Monte Carlo realisation" if one else f"{n}, one Monte Carlo realisation"):
               table(*v) for n, v in mc.items()}
    curves = {("forecast" if one else f"{n}, forecast"): table(*fc[n][:2])
              for n in mc if fc[n] is not None}
    styles = {label: {"marker": "", "lw": 1.5} for label in curves}  # lines, drawn first
    return plot_spectra({**curves, **spectra}, title=TITLES["9"], styles=styles,
                        photon=float(photon["y"][0]) * _unit(photon) if len(photon) else None,
                        photon_label=str(photon["series"][0]) if len(photon) else "")
