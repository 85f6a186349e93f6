"""The prior ``detect_jumps``' ``expected_rate`` puts on each ramp's slope.

On a dark every pixel's rate is known before the exposure (the master dark), and a
step at mid-ramp tested against a line of that slope has about half the sigma it has
against a free slope.  `set_priors` turns a set of rows' expected rates into
`~spherex_reduce.reduce.steps.jumps.search.SlopePrior` objects: the expected slope of
each ramp, shifted by the set's offset (the median of slope less expected rate: a dark
current that drifted since the master), and the spread of the true rates about it (the
median absolute deviation of that difference below the median, less the line's own
noise), which weighs the prior in the step search's generalised least squares
(`~spherex_reduce.reduce.steps.fit_ramp.step_model.StepModel`'s ``slope_precision``).
"""

import numpy as np

from .search import SlopePrior, cached_search

__all__ = ["PRECISION_BIN", "PRIOR_FLOOR", "PRIOR_MIN_RAMPS", "PRIOR_RAMPS", "SPREAD_MAX",
           "set_priors"]

#: ramps of a set of rows whose slopes less their ``expected_rate`` give the prior's
#: offset and spread: at least this many, at most `PRIOR_RAMPS` (every k-th)
PRIOR_MIN_RAMPS = 100
PRIOR_RAMPS = 1 << 15
#: the prior's spread at least this fraction of a ramp's own slope sigma (rates that match
#: the expected ones to ~0: the prior's weight stays finite)
PRIOR_FLOOR = 0.1
#: the prior's weights (read-noise variance over the prior's) are binned by this many dex,
#: one search for each bin of a set (a read-noise map)
PRECISION_BIN = 0.02
#: a set whose true rates spread about their expected ones by more than this many of a
#: line's sigmas gets no prior (a sky under a dark's map: the prior would add nothing but
#: the bias of its centre, the set's median)
SPREAD_MAX = 3.0


def set_priors(search, y, sigma, gain, expected):
    """The priors of one set's ramps ``y`` (reads usable for ``search``; read noise
    ``sigma``, ``gain`` and ``expected_rate`` per ramp): ``[(columns of y,
    SlopePrior or None)]``, one per bin of the prior's weight (`PRECISION_BIN`); None
    (the slope free) when fewer than `PRIOR_MIN_RAMPS` ramps have a finite slope, for
    the ramps without an expected rate (NaN), and where no prior can be weighed.

    The offset is the median of the slopes less their expected rates (a sample of
    at most `PRIOR_RAMPS`), the spread their median absolute deviation below it
    (cosmic rays and pixels warmer than expected add charge: the upper side is
    theirs), less the line's read and shot noise there, at least `PRIOR_FLOOR` of
    the line's noise; more than `SPREAD_MAX` of it (a sky's rates), no prior."""
    every = np.arange(y.shape[1])
    known = np.isfinite(expected)
    if not known.all():  # a pixel the map has no value for: its slope free
        out = [(every[~known], None)]
        if known.any():
            cols = every[known]
            out += [(cols[c], p) for c, p in set_priors(
                search, y[:, cols], sigma[cols], gain[cols], expected[cols])]
        return out
    take = slice(None, None, max(1, -(-y.shape[1] // PRIOR_RAMPS)))
    rel = np.asarray(y[:, take], np.float64)
    d = search.coef[1] @ (rel - rel[0]) - expected[take]
    finite = np.isfinite(d)
    d = d[finite]
    if d.size < PRIOR_MIN_RAMPS:
        return [(every, None)]
    offset = float(np.median(d))
    below = offset - d[d < offset]
    if below.size < PRIOR_MIN_RAMPS // 2:
        return [(every, None)]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        mad = 1.482602218505602 * np.median(below)
        # the line's noise at the sample's median read noise and expected charge rate
        s2 = np.median(np.square(sigma[take][finite]))
        lam = max(np.median(expected[take][finite]) + offset, 0.0) / np.median(
            gain[take][finite])
        shot = search.shot_var
        line2 = s2 * search.slope_var + lam * shot  # the line's variance there
        spread = np.sqrt(max(mad * mad - line2, 0.0))
        weight2 = np.maximum(spread * spread, PRIOR_FLOOR ** 2 * (np.square(sigma)
                                                                  * search.slope_var))
        precision = np.square(sigma) / weight2
    # rates too large for their squares (an absurd map), a read noise that underflows:
    # no prior this set can be weighed with (counted as searched free)
    if not (np.isfinite(offset) and np.isfinite(spread)
            and (np.isfinite(precision) & (precision > 0)).all()):
        return [(every, None)]
    if spread * spread > SPREAD_MAX ** 2 * line2:  # rates that spread like a sky's
        return [(every, None)]
    spread = float(spread)
    bins = np.round(np.log10(precision) / PRECISION_BIN).astype(np.int64)
    out = []
    for b in np.unique(bins):
        cols = every[bins == b]
        prior_search = cached_search(search.tau, search.factors, search.walk,
                                     10.0 ** (b * PRECISION_BIN))
        out.append((cols, SlopePrior(prior_search, expected[cols] + offset, spread)))
    return out
