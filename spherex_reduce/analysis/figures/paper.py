"""The paper's simulated figures, one function each: simulate, measure, draw, judge.

Each function of `FIGURES` computes one of the paper's figures for a
`FigureRun` (the sizes, the report, where the sweeps run): it simulates and
reduces its cases with `~spherex_reduce.analysis.case.run_case` or its
parameter scan with `~spherex_reduce.analysis.sweep.run_sweep`, saves the
PNG, records every number plotted and adds its section, and its claim with a
verdict, to the report (`~spherex_reduce.analysis.figures.report.FigureReport`).
`~spherex_reduce.analysis.figures.reproduce.make_figures` walks the table.
"""

import warnings
from dataclasses import dataclass

import numpy as np
from astropy import units as u
from astropy.table import Table

from ...core._text import plural
from ...core.errors import SpherexReduceError
from ...simulation import expected_slope_variance, load_scene
from ..case import SpectrumMeasure, run_case
from ..forecast.engine import forecast
from ..forecast.fft import forecast_fft_magnitude
from ..photon_noise import photon_noise_label, photon_noise_power
from ..spectrum import fft_magnitude
from ..sweep import run_sweep
from .forecast import FORECAST, TITLES, plot_forecast_figure
from .report import sigma_margin, unicode_unit

__all__ = ["FIGURES", "FigureRun"]

#: Pipelines (inline configs) used by the figures.
PIPELINES = {
    "raw": {"name": "raw", "steps": [{"unchop": {}}]},
    "phantom": {"name": "phantom", "steps": [{"unchop": {}}, {"subtract_phantom": {}}]},
    "reference": "spherex-default",
    "acn": "acn",
}
PIXEL_COMPONENTS = ["video8", "roic", "bias_correlated", "bias_pixels_only"]
NO_ROIC = ["video8", "bias_correlated", "bias_phantom_only", "bias_pixels_only"]


def _scene(settings, components=None, geometry=None, **readout):
    ro = {"skip": 24, "ref_reads": 32, "ref_mode": "distributed", "phantom_reads": 4,
          "nframes": settings.nframes}
    ro.update(readout)
    scene = {"geometry": dict(geometry or settings.geometry), "readout": ro}
    if components is not None:
        scene["noise"] = {"components": list(components)}
    return scene


def _measure(scene, pipeline, seed, measure=None):
    """``measure`` (default: the reduced image itself) of a scene reduced with a pipeline."""
    return run_case(scene, PIPELINES[pipeline], measure or (lambda image: image),
                    seed=seed).measurement


def _mean_spectrum(rows):
    """Mean P(k) over the rows (realisations) of a sweep, with the standard error; a bin
    empty in every row (NaN: the light-sensitive area has no mode in it) is left out."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Mean of empty slice|Degrees of freedom",
                                RuntimeWarning)  # the bins dropped below
        k = np.nanmean(np.asarray(rows["k"], float), axis=0)
        p = np.asarray(rows["power"], float)
        mean = np.nanmean(p, axis=0)
        err = (np.nanstd(p, axis=0, ddof=1) / np.sqrt(len(p)) if len(p) > 1
               else np.zeros_like(mean))
    keep = np.isfinite(k) & np.isfinite(mean)
    unit = rows["power"].unit or u.one
    return Table({"k": k[keep] * u.rad / u.pix, "power": mean[keep] * unit,
                  "power_err": err[keep] * unit})


def _band_stats(rows):
    bp = np.asarray(rows["band_power"], float)
    err = bp.std(ddof=1) / np.sqrt(bp.size) if bp.size > 1 else float(rows["band_power_err"][0])
    return float(bp.mean()), float(err)


@dataclass(frozen=True)
class FigureRun:
    """What every figure of a run shares: the sizes, the report, where the sweeps run.

    Parameters
    ----------
    settings : `~spherex_reduce.analysis.figures.reproduce.FigureSettings`
    report : `~spherex_reduce.analysis.figures.report.FigureReport`
    scheduler, workers, progress
        As `~spherex_reduce.analysis.sweep.run_sweep`.
    forecast : bool
        Also forecast Figs. 6-9 (`~spherex_reduce.analysis.forecast`): drawn
        as curves beside the Monte Carlo points, and their claims judged on
        the forecast, with the Monte Carlo's verdict beside it.
    """

    settings: object
    report: object
    scheduler: object = "serial"
    workers: int = 2
    progress: bool = False
    forecast: bool = False

    @property
    def per_point(self):
        """What the standard errors of a scan's points come from."""
        s = self.settings
        return (f"{plural(s.realizations, 'realisation')} per point; standard errors from "
                "their scatter" if s.realizations > 1 else
                "one realisation per point; standard errors of a Gaussian field's band power")

    def sweep(self, scene, grid, pipelines, measure=None, seed=0):
        """The results table of a sweep of ``scene`` over ``grid`` with the named pipelines."""
        s = self.settings
        sw = {"scene": scene, "grid": grid, "pipeline": [PIPELINES[p] for p in pipelines],
              "realizations": s.realizations, "seed": seed,
              "measure": {"bins": s.bins, **(measure or {})}}
        res = run_sweep(sw, scheduler=self.scheduler, workers=self.workers,
                        progress=self.progress, forecast=self.forecast)
        if res.failed:
            f = res.failed[0]
            raise SpherexReduceError(f"figure sweep cell {f['cell']} failed: {f['error']}")
        return res.table


def _spectra_fig(spectra, title, photon=None, photon_label="photon noise"):
    from .plots import plot_spectra

    return plot_spectra(spectra, photon=photon, title=title, photon_label=photon_label)


def _photon_line(s):
    """Photon noise of 1 e/s in the figures' scene: its band power and its legend label."""
    sched = _scene_schedule(_scene(s))
    return (photon_noise_power(1 * u.electron / u.s, schedule=sched),
            photon_noise_label(1 * u.electron / u.s, schedule=sched))


def _sigma_figure(n_values, sig, pred, unit, title):
    """Fig. 12a: pixel σ against N, simulated and analytic, with N on plain tick labels."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    from ...io.plotting import unit_label

    fig = Figure(figsize=(7, 5), layout="constrained")
    ax = fig.subplots()
    ax.plot(n_values, sig, "o-", label="simulated, r = 32 ACN reference correction, 5σ clip")
    ax.plot(n_values, pred, "k--", label="analytic ∫p|H|²df per pixel (before correction)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    # a log axis over less than two decades labels its minor ticks, which then overlap
    ax.set_xticks(list(n_values), [str(n) for n in n_values])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("frames N")
    ax.set_ylabel(f"pixel σ ({unit_label(unit)})")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title, fontsize=10)
    return fig


def _scene_schedule(scene):
    return load_scene(scene).schedule


def _fig4_components(run):
    """Fig. 4: the spectrum of each pixel-visible component alone (S = 1, no corrections)."""
    s, rep = run.settings, run.report
    spectra = {}
    for i, comp in enumerate(PIXEL_COMPONENTS):
        m = _measure(_scene(s, [comp], skip=1, ref_mode="none"), "raw", 400 + i,
                     SpectrumMeasure(bins=s.bins))
        spectra[comp], bp = m["spectrum"], m["band_power"]
        rep.number("4", comp, "k", np.nan, "band_power", bp.value, unit=bp.unit)
    dominant = max(spectra, key=lambda c: float(np.mean(spectra[c]["power"])))
    rep.save(_spectra_fig(spectra, "Fig. 4: one component at a time, S = 1, no corrections"),
             "fig4_components.png")
    rep.md += ["## Fig. 4: component spectra", "", "![](fig4_components.png)", "",
               "Each pixel-visible Table 2 component alone, read in physical order (S = 1), no "
               "correction. `bias_phantom_only` is invisible to pixels (zero image), so it is "
               "not drawn.", ""]
    roic = spectra["roic"]
    margins4 = [sigma_margin(np.asarray(t["power"]), np.asarray(t["power_err"]),
                        np.asarray(roic["power"]), np.asarray(roic["power_err"]))
                for c, t in spectra.items() if c != "roic" and len(t) == len(roic)]
    rep.claim("The ROIC amplifier noise dominates at all spatial frequencies (Fig. 4)",
              np.concatenate(margins4) if dominant == "roic" else [-np.inf],
              f"highest mean P(k): {dominant}",
              "the ROIC has the highest mean P(k), and in every k bin its P(k) exceeds each "
              "other component's", "one realisation per component; standard errors of each "
              "P(k) bin")


def _fig5_phantom(run):
    """Fig. 5: band power and spectra before and after phantom correction (c = 4)."""
    s, rep = run.settings, run.report
    t5 = run.sweep(_scene(s, NO_ROIC, skip=1, ref_mode="none"), {"phantom_reads": [4]},
                   ["raw", "phantom"], seed=5)
    sp = {}
    for name in ("raw", "phantom"):
        rows = t5[t5["pipeline"] == name]
        sp[f"{'before' if name == 'raw' else 'after'} phantom correction"] = _mean_spectrum(rows)
        m, e = _band_stats(rows)
        rep.number("5", name, "c", 4, "band_power", m, e, rows["band_power"].unit)
    before = _band_stats(t5[t5["pipeline"] == "raw"])
    after = _band_stats(t5[t5["pipeline"] == "phantom"])
    rep.save(_spectra_fig(sp, "Fig. 5: all sources but ROIC, c = 4, S = 1"), "fig5_phantom.png")
    rep.md += ["## Fig. 5: phantom correction (c = 4), phantom-visible sources", "",
               "![](fig5_phantom.png)", "",
               f"Band power before {before[0]:.3g} ± {before[1]:.2g}, after "
               f"{after[0]:.3g} ± {after[1]:.2g} ({unicode_unit(t5['band_power'].unit)}).", ""]
    rep.claim("Phantom correction removes phantom-visible 1/f noise (Fig. 5, §4.1)",
              [sigma_margin(after[0], after[1], 0.5 * before[0], 0.5 * before[1])],
              f"band power falls by a factor {before[0] / after[0]:.3g}",
              "the band power after phantom correction is below half of that before",
              run.per_point)


def _fig6_skip(run):
    """Fig. 6: band power against S, reference corrected."""
    s, rep = run.settings, run.report
    from matplotlib.figure import Figure

    from ...io.plotting import unit_label

    t6 = run.sweep(_scene(s), {"skip": list(s.skips)}, ["reference"],
                   measure={"exclude_horizontal": True}, seed=6)
    unit = t6["band_power"].unit
    sk = list(s.skips)
    m6, e6 = map(list, zip(*[_band_stats(t6[t6["skip"] == skip]) for skip in sk], strict=True))
    for skip, m, e in zip(sk, m6, e6, strict=True):
        rep.number("6", "reference corrected, ky=0 excluded", "S", skip, "band_power", m, e,
                   unit)
    f6 = _forecasts(t6, "skip", sk)
    if f6 is not None:
        for skip, f in zip(sk, f6, strict=True):
            rep.number("6", "reference corrected, ky=0 excluded" + FORECAST, "S", skip,
                       "band_power", f, 0.0, unit)
        fig = plot_forecast_figure(Table(rows=rep.numbers), "6")
    else:
        fig = Figure(figsize=(7, 5))
        ax = fig.subplots()
        ax.errorbar(sk, m6, yerr=e6, fmt="o-", capsize=3)
        ax.set_xscale("log")
        ax.set_xlabel("skip S (rows)")
        ax.set_ylabel(f"band power ({unit_label(unit)})")
        ax.set_title(TITLES["6"], fontsize=10)
        ax.grid(True, alpha=0.3)
    rep.save(fig, "fig6_skip.png")
    rep.md += ["## Fig. 6: band power against S", "", "![](fig6_skip.png)", ""]
    if f6 is None:
        rep.md += ["| S | band power | error |", "|---|---|---|"]
        rep.md += [f"| {a} | {b:.4g} | {c:.2g} |" for a, b, c in zip(sk, m6, e6, strict=True)]
    else:
        rep.md += ["| S | forecast | Monte Carlo | error | (MC − forecast) / error |",
                   "|---|---|---|---|---|"]
        rep.md += [f"| {a} | {f:.4g} | {b:.4g} | {c:.2g} | {(b - f) / c:+.1f} |"
                   for a, f, b, c in zip(sk, f6, m6, e6, strict=True)]
    rep.md += [""]

    def judged(m, e):
        best = sk[int(np.argmin(m))]
        inside = [i for i, k in enumerate(sk) if 8 <= k <= 128]
        outside = [i for i in range(len(sk)) if i not in inside]
        lo_in = min(inside, key=lambda i: m[i]) if inside else None
        margins = [-np.inf] if lo_in is None else [
            sigma_margin(m[lo_in], e[lo_in], m[i], e[i]) for i in outside] or [np.inf]
        s24 = f", S = 24 gives {m[sk.index(24)]:.3g}" if 24 in sk else ""
        return margins, (f"minimum at S = {best} ({min(m):.3g}); S = 1 gives {m[0]:.3g}"
                         + s24)

    _claim(run, "The optimal S is a few dozen rows (Fig. 6, §4.2)", judged, (m6, e6), f6,
           "the lowest band power over 8 ≤ S ≤ 128 is below the band power at every S "
           "outside that range")


def _forecasts(table, key, values, **where):
    """The forecast band power of a sweep's rows at each of ``values`` of ``key`` (and the
    ``where`` values of other keys); None: the sweep has no forecast."""
    if "band_power_forecast" not in table.colnames:
        return None
    sel = np.ones(len(table), bool)
    for k, v in where.items():
        sel &= table[k] == v
    return [float(table["band_power_forecast"][sel & (table[key] == v)][0]) for v in values]


def _claim(run, text, judged, mc, forecast, rule):
    """Record a claim judged on the Monte Carlo ``mc`` (values, errors) or, when given,
    on the ``forecast`` values (exact) with the Monte Carlo's verdict beside it;
    ``judged(values, errors)`` gives the comparisons' margins and the evidence."""
    margins, evidence = judged(*mc)
    if forecast is None:
        return run.report.claim(text, margins, evidence, rule, run.per_point)
    f_margins, f_evidence = judged(list(forecast), [0.0] * len(forecast))
    return run.report.claim(text, f_margins, f_evidence, rule,
                            "the forecast: expectations, no random numbers",
                            beside=(margins, evidence, run.per_point))


def _fig7_fft2d(run):
    """Fig. 7: the 2-D FFT near the origin at S = 1 and S = 24."""
    s, rep = run.settings, run.report
    ffts, fracs, exact = {}, {}, {}
    for skip in (1, 24):
        img = _measure(_scene(s, skip=skip), "phantom", 700)
        # crop to |k| <~ 0.35 rad/pixel: the S = 24 packets sit at k_y = 2π/24 ≈ 0.26
        size = max(129, 2 * int(np.ceil(0.35 * img.shape[0] / (2 * np.pi))) + 1)
        f = fft_magnitude(img, size=size)
        ffts[f"S = {skip}" + (", one Monte Carlo realisation" if run.forecast else "")] = f
        fracs[skip] = _axis_power_fractions(f)
        rep.number("7", f"S={skip}", "S", skip, "ky0_power_fraction", fracs[skip][0])
        rep.number("7", f"S={skip}", "S", skip, "near_axis_power_fraction", fracs[skip][1])
        if run.forecast:
            fc = forecast_fft_magnitude(_scene(s, skip=skip), PIPELINES["phantom"], size)
            ffts[f"S = {skip}, forecast √E|FFT|²"] = fc
            exact[skip] = (*_axis_power_fractions(fc)[:2], (0.0, 0.0))
            for name, im, err in ((f"S = {skip}", f, True), (f"S = {skip}" + FORECAST, fc,
                                                               False)):
                power = im.magnitude.value ** 2  # each cell's |FFT|², exponential in one image
                mean = power.mean(axis=1)
                errs = np.sqrt((power**2).sum(axis=1)) / power.shape[1] if err else 0 * mean
                for ky, m, e in zip(im.ky.value, mean, errs, strict=True):
                    rep.number("7", name, "k_y", ky, "power_ky", m, e, im.magnitude.unit**2)
            rep.number("7", f"S={skip}, forecast", "S", skip, "ky0_power_fraction",
                       exact[skip][0], 0.0)
            rep.number("7", f"S={skip}, forecast", "S", skip, "near_axis_power_fraction",
                       exact[skip][1], 0.0)
    from .plots import plot_fft_magnitude

    rep.save(plot_fft_magnitude(ffts, "Fig. 7: |FFT| near the origin, phantom-corrected, "
                                "no reference correction"), "fig7_fft2d.png")

    def judged(fr):
        return ([sigma_margin(fr[24][1], fr[24][2][1], fr[1][1], fr[1][2][1]),
                 sigma_margin(0.01, 0.0, fr[24][0], fr[24][2][0])],
                f"near-axis fraction {fr[1][1]:.3f} → {fr[24][1]:.3f}, on-axis "
                f"{fr[1][0]:.3f} → {fr[24][0]:.3f}")

    if exact:
        rep.save(plot_forecast_figure(Table(rows=rep.numbers), "7"), "fig7_profile.png")
    rep.md += ["## Fig. 7: 2-D FFT before/after S = 24", "",
               "![](fig7_fft2d.png)" + (" ![](fig7_profile.png)" if exact else ""), "",
               "Fraction of the cropped Fourier power on "
               "the horizontal axis k_y = 0, and near it (0 < |k_y| < π/24, between the axis "
               f"and the first S = 24 packet): S = 1: {fracs[1][0]:.3f} and "
               f"{fracs[1][1]:.3f}; S = 24: {fracs[24][0]:.3f} and {fracs[24][1]:.3f}"
               + (f" (forecast: {exact[1][0]:.3f} and {exact[1][1]:.3f}; {exact[24][0]:.3f} "
                  f"and {exact[24][1]:.3f})" if exact else "") + ".", ""]
    text = ("Row chopping moves power from near the horizontal axis to packets, but "
            "significant power remains on the axis (Fig. 7)")
    rule = ("the near-axis fraction of the Fourier power is lower at S = 24 than at S = 1, "
            "and more than 1 % of it stays on the axis at S = 24")
    count = "one realisation of each image; standard errors of sums of Fourier cells"
    if exact:
        rep.claim(text, *judged(exact), rule, "the forecast: expectations, no random numbers",
                  beside=(*judged(fracs), count))
    else:
        rep.claim(text, *judged(fracs), rule, count)


def _axis_power_fractions(f):
    """Fractions of the power of `FFTImage` ``f`` on the axis k_y = 0 and near it.

    Near: ``0 < |k_y| < π/24``, between the axis and the first S = 24 packet.
    Returns ``(on axis, near axis, (error on axis, error near axis))``.
    """
    mag2 = f.magnitude.value ** 2
    aky = np.abs(f.ky.value)[:, None] * np.ones(mag2.shape[1])[None, :]
    iy0 = aky == aky.min()
    near = (~iy0) & (aky < np.pi / 24)  # between the axis and the first S = 24 packet
    # each cell's power is exponentially distributed: the variance of a sum is Σ P²
    return (float(mag2[iy0].sum() / mag2.sum()), float(mag2[near].sum() / mag2.sum()),
            (float(np.sqrt((mag2[iy0] ** 2).sum()) / mag2.sum()),
             float(np.sqrt((mag2[near] ** 2).sum()) / mag2.sum())))


def _fig8_reference_reads(run):
    """Fig. 8: band power against r, distributed against repeated reference reads."""
    from matplotlib.figure import Figure

    from ...io.plotting import unit_label

    s, rep = run.settings, run.report
    t8 = run.sweep(_scene(s), {"ref_reads": list(s.ref_reads),
                               "ref_mode": ["repeated", "distributed"]},
                   ["reference"], seed=8)
    unit = t8["band_power"].unit
    res8, fc8 = {}, {}
    for mode in ("repeated", "distributed"):
        ms, es = [], []
        for r in s.ref_reads:
            rows = t8[(t8["ref_mode"] == mode) & (t8["ref_reads"] == r)]
            m, e = _band_stats(rows)
            ms.append(m)
            es.append(e)
            rep.number("8", mode, "r", r, "band_power", m, e, unit)
        res8[mode] = (np.array(ms), np.array(es))
        f = _forecasts(t8, "ref_reads", s.ref_reads, ref_mode=mode)
        if f is not None:
            fc8[mode] = np.array(f)
            for r, v in zip(s.ref_reads, f, strict=True):
                rep.number("8", mode + FORECAST, "r", r, "band_power", v, 0.0, unit)
    if fc8:
        fig = plot_forecast_figure(Table(rows=rep.numbers), "8")
    else:
        fig = Figure(figsize=(7, 5))
        ax = fig.subplots()
        for mode, (ms, es) in res8.items():
            ax.errorbar(s.ref_reads, ms, yerr=es, fmt="o-", capsize=3, label=mode)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("reference row reads r")
        ax.set_ylabel(f"band power ({unit_label(unit)})")
        ax.legend()
        ax.grid(True, alpha=0.3)
        ax.set_title(TITLES["8"], fontsize=10)
    rep.save(fig, "fig8_reference_reads.png")
    rep.md += ["## Fig. 8: distributed against repeated reference reads", "",
               "![](fig8_reference_reads.png)", ""]
    if fc8:
        rep.md += ["| r | repeated: forecast | Monte Carlo | distributed: forecast | "
                   "Monte Carlo |", "|---|---|---|---|---|"]
        rep.md += [f"| {r} | {fa:.4g} | {a:.4g} ± {ae:.2g} | {fb:.4g} | {b:.4g} ± {be:.2g} |"
                   for r, fa, a, ae, fb, b, be in zip(
                       s.ref_reads, fc8["repeated"], *res8["repeated"], fc8["distributed"],
                       *res8["distributed"], strict=True)] + [""]
    else:
        rep.md += ["| r | repeated | distributed |", "|---|---|---|"]
        rep.md += [f"| {r} | {a:.4g} ± {ae:.2g} | {b:.4g} ± {be:.2g} |"
                   for r, a, ae, b, be in zip(s.ref_reads, *res8["repeated"],
                                              *res8["distributed"], strict=True)] + [""]

    def judged(m, e):
        n = len(s.ref_reads)
        dist, rep_ = (np.asarray(m[:n]), np.asarray(e[:n])), (np.asarray(m[n:]),
                                                             np.asarray(e[n:]))
        wins = [r for r, a, b in zip(s.ref_reads, dist[0], rep_[0], strict=True) if a < b]
        return (sigma_margin(*dist, *rep_),
                f"distributed lower at r = {wins} of {list(s.ref_reads)}")

    _claim(run, "Distributed reference reads beat repeated ones at every r (Fig. 8, §4.3)",
           judged, (np.concatenate([res8["distributed"][0], res8["repeated"][0]]),
                    np.concatenate([res8["distributed"][1], res8["repeated"][1]])),
           np.concatenate([fc8["distributed"], fc8["repeated"]]) if fc8 else None,
           "at every r the band power with distributed reads is below that with repeated "
           "reads")


def _fig9_image(run):
    """Fig. 9: an image and its spectrum before reference correction."""
    s, rep = run.settings, run.report
    img9 = _measure(_scene(s), "phantom", 900)
    from ...io.plotting import plot_image

    rep.save(plot_image(img9, "Fig. 9a: S = 24, phantom-corrected, before reference correction",
                        str(img9.unit)), "fig9_image.png")
    measure = SpectrumMeasure(bins=s.bins)
    m9 = measure(img9)
    sp9, bp9 = m9["spectrum"], m9["band_power"]
    photon, photon_label = _photon_line(s)
    label = "before reference correction"
    rep.number("9", label, "k", np.nan, "band_power", bp9.value, unit=bp9.unit)
    text = (f"Band power {bp9.value:.4g} {unicode_unit(bp9.unit)}; photon noise of 1 e/s: "
            f"{photon.value:.3g}.")
    if run.forecast:
        f9 = forecast(_scene(s), PIPELINES["phantom"], measure)
        fb = f9.meta["band_power"]
        rep.number("9", label + FORECAST, "k", np.nan, "band_power", fb, 0.0, bp9.unit)
        fk, fp = measure.every_bin(f9)
        ferr = measure.every_bin(f9, "power_err")[1]
        mk, mp = m9["k"], m9["power"]
        merr = measure.every_bin(sp9, "power_err")[1]
        for i in np.flatnonzero(np.isfinite(mp) & np.isfinite(fp)):
            rep.number("9", label, "k", mk[i], "power", mp[i], merr[i], sp9["power"].unit)
            rep.number("9", label + FORECAST, "k", fk[i], "power", fp[i], 0.0, f9["power"].unit)
        rep.number("9", photon_label, "k", np.nan, "photon_power", photon.value, 0.0,
                   photon.unit)
        rep.save(plot_forecast_figure(Table(rows=rep.numbers), "9"), "fig9_spectrum.png")
        z = np.abs(mp - fp) / ferr
        text = (f"Band power {bp9.value:.4g} ± {m9['band_power_err'].value:.2g} in one "
                f"realisation, forecast {fb:.4g} {unicode_unit(bp9.unit)}; the realisation's bins "
                f"lie within {np.nanmax(z):.2g} standard errors of the forecast (the error one "
                f"realisation's bin has). Photon noise of 1 e/s: {photon.value:.3g}.")
    else:
        rep.save(_spectra_fig({label: sp9}, "Fig. 9b", photon, photon_label),
                 "fig9_spectrum.png")
    rep.md += ["## Fig. 9: an image and its spectrum before reference correction", "",
               "![](fig9_image.png) ![](fig9_spectrum.png)", "", text, ""]


def _fig10_corrected(run):
    """Fig. 10: corrected against uncorrected spectra, with the photon-noise line."""
    s, rep = run.settings, run.report
    tc = run.sweep(_scene(s), {"skip": [24]}, ["reference"], seed=10)
    tu = run.sweep(_scene(s, skip=1, ref_mode="none"), {"skip": [1]}, ["raw"], seed=10)
    photon, photon_label = _photon_line(s)
    corr, unc = _band_stats(tc), _band_stats(tu)
    rep.number("10", "S=24, r=32, corrected", "k", np.nan, "band_power", *corr,
               tc["band_power"].unit)
    rep.number("10", "uncorrected (S=1)", "k", np.nan, "band_power", *unc,
               tu["band_power"].unit)
    rep.save(_spectra_fig({"S = 24, r = 32 distributed, corrected": _mean_spectrum(tc),
                           "uncorrected (S = 1, no corrections)": _mean_spectrum(tu)},
                          "Fig. 10", photon, photon_label), "fig10_corrected.png")
    rep.md += ["## Fig. 10: S = 24 and r = 32 against uncorrected", "",
               "![](fig10_corrected.png)", "",
               f"Band power corrected {corr[0]:.4g} ± {corr[1]:.2g}, uncorrected "
               f"{unc[0]:.4g} ± {unc[1]:.2g}; ratio {corr[0] / unc[0]:.3g}. Photon noise "
               f"(1 e/s): {photon.value:.3g}.", ""]
    rep.claim("Corrections bring large-scale noise well below the uncorrected level "
              "(Fig. 10, §5.2)", [sigma_margin(corr[0], corr[1], 0.3 * unc[0], 0.3 * unc[1])],
              f"corrected / uncorrected band power = {corr[0] / unc[0]:.3g}",
              "the corrected band power is below 0.3 times the uncorrected one", run.per_point)


def _fig12a_sigma_vs_n(run):
    """Fig. 12a: pixel σ against N, simulated and analytic."""
    s, rep = run.settings, run.report
    sig, pred, npix = [], [], []
    for i, n in enumerate(s.n_values):
        scene = _scene(s, geometry=s.geometry_12a, nframes=n)
        img = _measure(scene, "acn", 1200 + i)
        data = np.asarray(img.data, float)
        good = np.isfinite(data) & (np.asarray(img.mask) == 0 if img.mask is not None else True)
        sig.append(float(np.std(data[good])))
        npix.append(int(np.count_nonzero(good)))
        var = expected_slope_variance("spherex-table2", _scene_schedule(scene))
        pred.append(float(np.sqrt(u.Quantity(var)).to_value(img.unit)))
        rep.number("12a", "simulated, ACN reference-corrected, clipped", "N", n, "sigma",
                   sig[-1], unit=img.unit)
        rep.number("12a", "analytic per-pixel slope sigma (before corrections)", "N", n,
                   "sigma", pred[-1], unit=img.unit)
    sig_err = [x / np.sqrt(2 * (n - 1)) for x, n in zip(sig, npix, strict=True)]
    fig = _sigma_figure(s.n_values, sig, pred, img.unit,
                        f"Fig. 12a: one Video8 ({plural(s.geometry_12a['nchannels'], 'channel')})")
    rep.save(fig, "fig12a_sigma_vs_n.png")
    rep.md += ["## Fig. 12a: pixel σ against N", "", "![](fig12a_sigma_vs_n.png)", "",
               "| N | σ simulated | σ analytic |", "|---|---|---|"]
    rep.md += [f"| {n} | {a:.4g} | {b:.4g} |" for n, a, b in zip(s.n_values, sig, pred,
                                                                   strict=True)] + [""]
    dev = np.array(sig) / np.array(pred) - 1
    rep.claim("Pixel σ falls with N (Fig. 12a)",
              sigma_margin(sig[1:], sig_err[1:], sig[:-1], sig_err[:-1]),
              f"σ from {sig[0]:.3g} (N = {s.n_values[0]}) to {sig[-1]:.3g} "
              f"(N = {s.n_values[-1]}); against the analytic per-pixel σ before correction "
              f"{dev[0]:+.1%} at N = {s.n_values[0]} and {dev[-1]:+.1%} at N = "
              f"{s.n_values[-1]}: at large N the low-frequency, channel-common part that "
              "reference correction removes is a growing share of the uncorrected σ",
              "σ at each N is below σ at the previous N",
              "one image per N; standard error of σ from its pixels, σ/√(2(n − 1))")


#: The figures in the order of the report: ``(label, function of a FigureRun)``.
FIGURES = (
    ("4", _fig4_components),
    ("5", _fig5_phantom),
    ("6", _fig6_skip),
    ("7", _fig7_fft2d),
    ("8", _fig8_reference_reads),
    ("9", _fig9_image),
    ("10", _fig10_corrected),
    ("12a", _fig12a_sigma_vs_n),
)
