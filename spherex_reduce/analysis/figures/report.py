"""The report of the paper's figures: numbers, claims and their verdicts.

A claim of the paper is put as comparisons of measured numbers; each
comparison's margin is how far it is met in standard errors (`sigma_margin`), and
the claim's verdict follows from the smallest margin (`_verdict`).
`FigureReport` collects what the figures record: their Markdown sections,
every number plotted and every claim with its verdict.
"""

import numpy as np
from astropy import units as u

__all__ = ["FAILS", "HOLDS", "NOISE", "NOISE_SIGMAS", "FigureReport", "sigma_margin",
           "unicode_unit"]


#: A claim is decided only when every comparison it needs is met (or one fails) by more
#: than this many standard errors; otherwise its verdict is "within the noise".
NOISE_SIGMAS = 2.0
HOLDS, FAILS, NOISE = "holds", "does not hold", "within the noise"


def _verdict(margins):
    """HOLDS, FAILS or NOISE from the margins (in standard errors) of a claim's comparisons.

    Examples
    --------
    >>> from spherex_reduce.analysis.figures.report import _verdict
    >>> _verdict([5.0, 2.5]), _verdict([5.0, -3.0]), _verdict([5.0, 1.0])
    ('holds', 'does not hold', 'within the noise')
    """
    worst = float(np.nanmin(margins))
    return HOLDS if worst > NOISE_SIGMAS else FAILS if worst < -NOISE_SIGMAS else NOISE


def sigma_margin(a, a_err, b, b_err):
    """How far ``a < b`` holds, in standard errors of ``b − a`` (negative: it fails).

    Parameters
    ----------
    a, a_err, b, b_err : array_like
        The values compared and their standard errors.

    Returns
    -------
    `numpy.ndarray`
        ``(b - a) / hypot(a_err, b_err)``; ±inf where both errors are 0.

    Examples
    --------
    >>> from spherex_reduce.analysis.figures.report import sigma_margin
    >>> sigma_margin(1.0, 0.3, 2.0, 0.4).tolist(), sigma_margin(2.0, 0.0, 1.0, 0.0).tolist()
    (2.0, -inf)
    """
    err = np.hypot(a_err, b_err)
    diff = np.asarray(b, float) - np.asarray(a, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(err > 0, diff / err, np.sign(diff) * np.inf)


class FigureReport:
    """What a run of the figures reports: its Markdown sections, numbers and claims.

    Each figure appends its section to ``md``, its numbers (`number`) and
    its claim with the verdict (`claim`), and saves its PNG (`save`) into
    ``outdir``.

    Examples
    --------
    >>> from spherex_reduce.analysis.figures.report import FigureReport
    >>> rep = FigureReport(".", overwrite=False)
    >>> rep.claim("a < b", [3.5], "a = 1, b = 2", "a is below b", "one realisation")
    'holds'
    >>> rep.number("6", "corrected", "S", 24, "band_power", 1.0, 0.1)
    >>> len(rep.claims), rep.numbers[0]["x"]
    (1, 24.0)
    """

    def __init__(self, outdir, overwrite):
        self.outdir = outdir
        self.overwrite = overwrite
        self.md = []
        self.numbers = []
        self.claims = []

    def save(self, fig, name):
        """Save a matplotlib figure as ``outdir / name``; returns ``name``."""
        from ...io.plotting import save_figure

        save_figure(fig, self.outdir / name, overwrite=self.overwrite)
        return name

    def number(self, figure, series, x_name, x, y_name, y, y_err=np.nan, unit=""):
        """Record one number plotted (a row of ``figures.ecsv``)."""
        self.numbers.append({"figure": figure, "series": str(series), "x_name": x_name,
                             "x": float(x), "y_name": y_name, "y": float(y),
                             "y_err": float(y_err), "unit": str(unit)})

    def claim(self, text, margins, evidence, rule, count, beside=None):
        """Record a claim's verdict, decided by the smallest of its ``margins``.

        Each margin is how far one comparison the claim needs is met, in
        standard errors (negative: it fails).  ``rule`` states the comparison
        with its thresholds, ``count`` what the standard errors come from.
        Numbers without error (a forecast) give infinite margins: the
        verdict is exact.  ``beside``, ``(margins, evidence, count)`` of the
        Monte Carlo when the claim is judged on the forecast, is reported
        after it with its own verdict.
        """
        verdict = _verdict(margins)
        where = "in the forecast" if beside is not None else "in our simulation"
        line = (f"- {text}: **{verdict}** {where} — {evidence}. *Rule:* {rule}; "
                f"{_worst(margins, count)}.")
        if beside is not None:
            mc_margins, mc_evidence, mc_count = beside
            line += (f" The Monte Carlo beside it: {_verdict(mc_margins)} — {mc_evidence}; "
                     f"{_worst(mc_margins, mc_count)}.")
        self.claims.append(line)
        return verdict


def _worst(margins, count):
    """The smallest margin, in words (exact when the numbers have no error)."""
    worst = float(np.nanmin(margins))
    if np.isfinite(worst):
        return f"smallest margin {worst:+.1f} standard errors ({count})"
    return f"decided exactly ({count})"


def unicode_unit(unit):
    """A unit for the Markdown report: ``electron² pix² s⁻²``, not ``electron2 pix2 / s2``.

    Parameters
    ----------
    unit : `astropy.units.UnitBase` or str

    Returns
    -------
    str

    Examples
    --------
    >>> from spherex_reduce.analysis.figures.report import unicode_unit
    >>> unicode_unit("electron2 / s2")
    'electron² s⁻²'
    """
    return u.Unit(unit).to_string("unicode")
