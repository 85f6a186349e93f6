"""Telegraph pixels too faint to be seen jump by jump, fitted as a population.

`~spherex_reduce.analysis.pixel_terms` finds a telegraph pixel by its jumps
(above ``jump_sigma`` of its differences' noise).  A population of smaller
steps is not seen that way, yet it is what raises the slope scatter of long
ramps above the streams' (the paper's ~30 % at N = 74, §5).  This module
fits it from second- and fourth-order statistics of every pixel's ramp:

- each pixel's residual about its line (the mean of its differences) less the
  drift common to the pixels read with it (one row of one channel, one column
  parity: the mean of their residual differences at each read, leaving out the
  pixels that jumped in that dark), summed to a residual ramp ``X``;
- its structure function at a few lags ``L``: ``Q_L = Σ_k (X_{k+L} - X_k)²``,
  less the mean's own variance (``1/n²`` of its ``n`` members' terms, white
  and telegraph: their mean ``Q_L`` over ``n - 1``), and for a member divided
  by ``1 - 2/n`` (what the mean takes of its own terms);
- over the pixels (hot and found telegraph pixels left out), ``E[Q_L] = σ²
  a_L + I s_L + P/4 t_L(r)``: ``a_L``, ``s_L`` and ``t_L`` exact traces of the
  quadratic form with white reads, the dark current's shot noise and a
  two-state telegraph of unit step switching at ``r`` per state
  (autocovariance ``exp(-2 r |Δt|) / 4``).  ``σ²`` and ``P`` (the pixels' mean
  ``A²``, telegraph or not: the fraction times the mean squared step) are
  linear, ``r`` is found by a search in log;
- the split of ``P`` into a fraction and a step, from the scatter over pixels of
  each one's contrast ``c = Q_long / a_long - Q_1 / a_1`` (white reads drop
  out): its mean is ``κ E[A²]`` and its mean square, less each pixel's
  measurement noise (the scatter of its contrast between darks; with one dark,
  white reads' ``2 σ⁴ tr(C²)``), ``κ² E[A⁴]``; the step is ``(E[A⁴]/E[A²])^½`` and the
  fraction ``P`` over its square.

A telegraph faster than the reads is white noise (the read-noise map holds
it); a slow one's structure function grows linearly with the lag, so only
``P r`` is seen (the slow ones with large steps are the ones found jump by
jump): at either end of the rate's range the population is not constrained.
``I`` is the pixels' mean slope over the gain: a slope that is not all Poisson
charge at that gain leaves ``P`` (or ``P r``) below 0 beyond its errors, and
the population is then not constrained, saying so (never ruled out).  Every
estimate is a function of sums over pixels, so its error is the delete-a-group
jackknife of `~spherex_reduce.analysis.pixel_terms`.
"""

import numpy as np
from astropy import units as u
from scipy import sparse
from scipy.optimize import minimize_scalar

__all__ = ["FAINT_TERMS", "add_faint_terms", "common_labels", "lag_design", "lag_sums",
           "telegraph_covariance"]

#: The rows `add_faint_terms` adds (active pixels).
FAINT_TERMS = ("faint_telegraph_power", "faint_telegraph_rate", "faint_telegraph_fraction",
               "faint_telegraph_amplitude", "faint_telegraph_white", "white_read_noise")
#: Fewest pixels of a group whose mean drift is removed (`lag_sums`).
MIN_GROUP = 4
#: Lags of the structure function, at most (spaced evenly in log from 1 to half the ramp).
MAX_LAGS = 8
#: Pixels `lag_sums` takes at a time: their reads' cumulative sums (~2.4 MB at 74 reads)
#: stay in cache for the squares and every lag's products.
LAG_PIXELS = 8192
#: Search range of the rate, in units of 1/(2 dt): from far slower than the ramp to far
#: faster than the reads.
_RATE_RANGE = (1e-4, 20.0)
_GRID = 240


def common_labels(geometry):
    """Labels ``(nrows, ncols)`` of the pixels read together: one row of one channel and
    one column parity (ACN's even and odd streams), -1 on the reference pixels; in the
    orientation of ``geometry``: the stored image's, or the readout frame's when it is a
    frame (`~spherex_reduce.DetectorGeometry.frame`, as a reader's schedule has it).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.analysis.faint_telegraph import common_labels
    >>> lab = common_labels(DetectorGeometry(8, 8, 2, ref_border=1))
    >>> int(lab[0, 3]), int(lab[1, 1]), int(lab[1, 2]), int(lab[1, 5]), int(lab[2, 1])
    (-1, 5, 4, 7, 9)
    """
    frame = geometry.frame
    nch = frame.nchannels
    rows = np.arange(frame.nrows)[:, None]
    cols = np.arange(frame.ncols)[None, :]
    lab = rows * (2 * nch) + frame.channel_of_column()[None, :] * 2 + cols % 2
    if frame is not geometry:  # the stored image of a frame (quadrants, rows)
        lab = np.asarray(geometry.layout.to_stored(lab))
    return np.where(geometry.reference_pixel_mask(), -1, lab).astype(np.int64)


def lag_design(times):
    """The lags and exact traces of `lag_sums`' quadratic forms for reads at ``times`` (s):
    ``{"lags", "times", "forms", "a", "s"}`` (``forms`` ``(lags, n, n)`` the matrices
    ``M_L`` on the reads, ``a`` and ``s`` their traces with white reads and shot noise).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.faint_telegraph import lag_design
    >>> d = lag_design(np.arange(11) * 1.5)
    >>> d["lags"].tolist(), round(float(d["a"][0]), 3)
    ([1, 2, 3, 4, 5], 19.8)
    """
    t = np.asarray(times, dtype=np.float64)
    n = t.size
    m = n - 1
    lags = np.unique(np.rint(np.geomspace(1, max(m // 2, 1), MAX_LAGS)).astype(int))
    # residual about the line through the ends (the mean of the differences), X = B x
    b = np.eye(n) - np.eye(n)[0]
    b -= np.outer((t - t[0]) / (t[-1] - t[0]), np.eye(n)[-1] - np.eye(n)[0])
    forms = []
    for lag in lags:
        d = np.zeros((n - lag, n))
        d[np.arange(n - lag), np.arange(lag, n)] = 1.0
        d[np.arange(n - lag), np.arange(n - lag)] -= 1.0
        db = d @ b
        forms.append(db.T @ db)
    forms = np.array(forms)
    shot = np.minimum.outer(t - t[0], t - t[0])  # Poisson charge, per unit current
    design = {"lags": lags, "times": t, "forms": forms,
              "a": np.trace(forms, axis1=1, axis2=2),
              "s": np.einsum("lij,ij->l", forms, shot)}
    dt = float(np.median(np.diff(t)))
    lo, hi = (np.log(v / (2 * dt)) for v in _RATE_RANGE)
    design["grid"] = np.linspace(lo, hi, _GRID)  # the rate's search, its traces once
    design["tgrid"] = np.array([_telegraph_traces(design, np.exp(v)) for v in design["grid"]])
    return design


def telegraph_covariance(times, rate):
    """Covariance of a telegraph of unit step and switch ``rate`` (Hz) at ``times`` (s):
    ``exp(-2 rate |t_j - t_k|) / 4`` (the simulator's definition; 1/4 at lag 0 for
    any rate, an infinite one included).

    Examples
    --------
    >>> from spherex_reduce.analysis.faint_telegraph import telegraph_covariance
    >>> telegraph_covariance([0.0, 1.0], 0.0).tolist()
    [[0.25, 0.25], [0.25, 0.25]]
    """
    t = np.asarray(times, dtype=np.float64)
    dt = np.abs(np.subtract.outer(t, t))
    with np.errstate(invalid="ignore"):
        return np.where(dt == 0, 1.0, np.exp(-2.0 * float(rate) * dt)) / 4.0


def _telegraph_traces(design, rate):
    """``t_L(rate)``: the traces of the forms with a unit-step telegraph."""
    return np.einsum("lij,ij->l", design["forms"], telegraph_covariance(design["times"], rate))


def lag_sums(e, labels, jumped, lags):
    """Per-pixel structure functions of one band of one dark.

    Parameters
    ----------
    e : `numpy.ndarray`
        ``(m, rows, nx)`` float32: each pixel's differences less its mean rate times
        the intervals.
    labels : `numpy.ndarray`
        ``(rows, nx)`` int: `common_labels` (-1: not used).
    jumped : `numpy.ndarray`
        ``(rows, nx)`` bool: pixels left out of the common drift (they jumped, or a
        read is not finite).
    lags : sequence of int

    Returns
    -------
    `numpy.ndarray`
        ``(len(lags), rows, nx)`` float64: ``Q_L`` less the group mean's own variance,
        over what the removal leaves of the pixel's terms; 0 where ``labels`` is -1.

    Examples
    --------
    A drift common to a group is taken out; white reads of unit variance give
    ``a_L`` (`lag_design`) on average:

    >>> import numpy as np
    >>> from spherex_reduce.analysis.faint_telegraph import lag_design, lag_sums
    >>> rng = np.random.default_rng(0)
    >>> x = rng.normal(0, 1, (11, 64, 64)) + np.cumsum(rng.normal(0, 5, (11, 64, 1)), 0)
    >>> d = np.diff(x, axis=0)
    >>> e = (d - d.mean(axis=0)).astype(np.float32)
    >>> labels = np.repeat(np.arange(64)[:, None], 64, axis=1)      # one group per row
    >>> des = lag_design(np.arange(11) * 1.5)
    >>> q = lag_sums(e, labels, np.zeros((64, 64), bool), des["lags"])
    >>> np.round(q.mean(axis=(1, 2)) / des["a"], 1).tolist()
    [1.0, 1.0, 1.0, 1.0, 1.0]
    """
    m = e.shape[0]
    shape = e.shape[1:]
    lags = np.asarray(lags)
    if lags.size and (lags.min() < 1 or lags.max() > m):
        raise ValueError(f"lag_sums: lags must be 1 to {m} (the differences), got "
                         f"{lags.tolist()}")
    use = (labels >= 0).ravel()
    uniq, inv = np.unique(np.where(use, labels.ravel(), -1), return_inverse=True)
    member = use & ~np.asarray(jumped).ravel()
    who = np.flatnonzero(member)
    # the sum over each group's members at each read: one sparse product
    sel = sparse.csr_matrix((np.ones(who.size, np.float32), (inv[who], who)),
                            shape=(uniq.size, member.size))
    count = np.bincount(inv[who], minlength=uniq.size).astype(np.float64)
    small = (count < MIN_GROUP) | (uniq < 0)  # too few to take a drift from: none removed
    flat = e.reshape(m, -1)
    cm = (np.asarray(sel @ flat.T).T
          / np.where(small, np.inf, count).astype(np.float32)).astype(np.float32)
    npx = flat.shape[1]
    # Q_L = sum_k x_{k+L}^2 + x_k^2 - 2 x_k x_{k+L}: the squares' partial sums it needs
    need = {m} | {m - lag for lag in lags} | {lag - 1 for lag in lags}
    sq = {k: np.empty(npx) for k in need}
    cross = np.empty((len(lags), npx), np.float32)
    x = np.empty((m + 1, min(LAG_PIXELS, npx)), np.float32)
    acc = np.empty(x.shape[1])
    for p0 in range(0, npx, LAG_PIXELS):  # a chunk of pixels at a time, held in cache
        p1 = min(p0 + LAG_PIXELS, npx)
        xc, ac = x[:, :p1 - p0], acc[:p1 - p0]
        xc[0] = 0.0
        np.subtract(flat[:, p0:p1], np.take(cm, inv[p0:p1], axis=1), out=xc[1:])
        for k in range(m):  # a cumulative sum read by read (numpy's along axis 0 is slower)
            np.add(xc[k], xc[k + 1], out=xc[k + 1])
        ac[:] = 0.0
        for k in range(m + 1):
            ac += np.square(xc[k], dtype=np.float64)
            if k in sq:
                sq[k][p0:p1] = ac
        for i, lag in enumerate(lags):
            cross[i, p0:p1] = np.einsum("kp,kp->p", xc[:-lag], xc[lag:])
    n = count[inv]
    factor = np.where(member & ~small[inv], (n - 2) / np.maximum(n, 1), 1.0)
    out = np.zeros((len(lags), member.size))
    for i, lag in enumerate(lags):
        q = sq[m - lag] + (sq[m] - sq[lag - 1]) - 2.0 * cross[i]
        # the mean's own variance, 1/n² of its members' terms, is their mean q over n - 1
        # (each member's q is (1 - 2/n) of its terms plus that): taken out of every pixel
        # (float: with no member at all, bincount gives integers)
        own = np.bincount(inv[who], q[who], minlength=uniq.size).astype(np.float64)
        own /= np.where(small, np.inf, count * (count - 1.0))
        out[i] = np.where(small[inv], q, (q - own[inv]) / np.where(factor > 0, factor, 1.0))
    out[:, ~use] = 0.0
    return out.reshape(len(lags), *shape)


def _solve(design, y, rate):
    """``(σ², P), χ²``: the linear least squares of ``y`` (per pixel) at ``rate``, each lag
    relative to its white trace."""
    a = design["a"]
    x = np.column_stack([a, _telegraph_traces(design, rate)]) / a[:, None]
    coef, *_ = np.linalg.lstsq(x, y / a, rcond=None)
    return coef, float(np.sum((x @ coef - y / a) ** 2))


def _best_rate(design, y):
    grid, a = design["grid"], design["a"]
    u_ = design["tgrid"] / a  # (grid, lags): the two-column least squares at every rate
    yy = y / a
    n, su, suu = a.size, u_.sum(axis=1), (u_ * u_).sum(axis=1)
    sy, suy = yy.sum(), u_ @ yy
    det = n * suu - su * su
    with np.errstate(divide="ignore", invalid="ignore"):
        c1 = (suu * sy - su * suy) / det
        c2 = (n * suy - su * sy) / det
    chi = np.sum((yy[None, :] - c1[:, None] - c2[:, None] * u_) ** 2, axis=1)
    i = int(np.nanargmin(np.where(np.isfinite(chi), chi, np.nan)))
    if i in (0, _GRID - 1):
        return np.exp(grid[i]), True  # at an end: not constrained
    step = grid[1] - grid[0]
    res = minimize_scalar(lambda v: _solve(design, y, np.exp(v))[1],
                          bounds=(grid[i] - step, grid[i] + step), method="bounded",
                          options={"xatol": 1e-6})
    return float(np.exp(res.x)), False


def _fit_power(design, total, shot):
    """``(P, rate, σ², edge)`` from column sums ``total``: ``Q_L`` for each lag then the
    count of pixel-darks; ``shot`` the pixels' mean current over the gain (unit²/s).
    ``edge``: the rate is at an end of its range (not constrained)."""
    count = total[-1]
    if not count > 0:
        return np.nan, np.nan, np.nan, True
    y = np.asarray(total[:-1], dtype=np.float64) / count - shot * design["s"]
    rate, edge = _best_rate(design, y)
    coef, _ = _solve(design, y, rate)
    return float(coef[1]), rate, float(coef[0]), edge


def _contrast_form(design):
    """The quadratic form of a pixel's contrast ``Q_long / a_long - Q_1 / a_1`` and the
    trace of its square (a white pixel's contrast has variance ``2 σ⁴`` times it)."""
    c = design["forms"][-1] / design["a"][-1] - design["forms"][0] / design["a"][0]
    return c, float(np.trace(c @ c))


def _fit_split(design, rate, c1, c2, noise, count):
    """The step ``(E[A⁴]/E[A²])^½`` of a population from the pixels' contrasts: sums of
    ``c`` (``c1``), ``c²`` (``c2``) and of their measurement variance (``noise``) over
    ``count`` pixels, at the fitted ``rate`` (NaN where not positive)."""
    c, _ = _contrast_form(design)
    kappa = float(np.sum(c * telegraph_covariance(design["times"], rate)))
    if not (count > 0 and kappa > 0):
        return np.nan
    m1 = c1 / count / kappa  # E[A²]
    m2 = (c2 - noise) / count / kappa ** 2  # E[A⁴]
    if not (m1 > 0 and m2 > 0):
        return np.nan
    return float(np.sqrt(m2 / m1))


def add_faint_terms(add, refuse, acc, quiet, active, current, ndarks, k, unit, des,
                    jackknife):
    """Add the faint population's rows (`FAINT_TERMS`) to a
    `~spherex_reduce.analysis.pixel_terms` table.

    ``add``/``refuse`` add a row; ``acc`` the per-pixel sums (``lags``, ``lagq``,
    ``csq``, ``labels``); ``quiet`` the active pixels that are not hot nor found
    telegraph; ``current`` each pixel's slope over the gain (its shot noise,
    unit²/s); ``des`` the differences' design (``m``, ``dt``, ``mm``,
    ``ar``); ``jackknife`` the delete-a-group jackknife of ``f`` of column sums
    over ``k`` groups: ``jackknife(f, columns, sel, gid, k)``.

    Examples
    --------
    White reads have no faint telegraph (through
    `~spherex_reduce.analysis.pixel_terms.fit_pixel_terms`, which calls it):

    >>> import numpy as np
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis.pixel_terms import fit_pixel_terms
    >>> x = np.random.default_rng(4).normal(0, 4.0, (2, 20, 32, 32)) * u.electron
    >>> res = fit_pixel_terms(list(x), np.arange(20) * 1.5 * u.s)
    >>> res.row("faint_telegraph_power", "active")["status"]
    'ruled out'
    """
    names = FAINT_TERMS
    units = (unit ** 2, u.Hz, "", unit, unit ** 2, unit)
    design = acc["lags"]
    if not quiet.any():
        for name, un in zip(names, units, strict=True):
            refuse(name, "active", un, "no active pixel but hot or telegraph ones")
        return
    lagq = acc.pop("lagq")
    shot = float(np.mean(current[quiet]))
    # the jackknife's groups hold whole groups of pixels read together: their common mean
    # (and the telegraph pixels among its members) ties their statistics
    labels = acc["labels"]
    _, inv = np.unique(labels, return_inverse=True)
    gid = np.random.default_rng(0).permutation(inv.max() + 1)[inv.reshape(labels.shape)] % k
    # the lags' sums, the count of pixel-darks, the active pixels
    columns = [np.where(quiet, lq, np.float32(0)) for lq in lagq] + [quiet * float(ndarks),
                                                                      1.0]
    cache = {}

    def fit(total):
        key = total.tobytes()
        if key not in cache:
            cache[key] = _fit_power(design, total[:-1], shot)
        return cache[key]

    def power(total):  # the mean over the active pixels (the quiet ones' times their share)
        return fit(total)[0] * total[-2] / ndarks / total[-1]

    p, p_err = jackknife(power, columns, active, gid, k)
    _, rate, _, edge = fit(_totals(columns, active))
    value, err = jackknife(lambda total: fit(total)[2], columns, active, gid, k)
    if value > 0:
        add(names[5], "active", np.sqrt(value), err / (2 * np.sqrt(value)), unit,
            note="root of the white read variance of the pixels that are not hot nor found "
            "telegraph, from their structure function (the drift common to the pixels read "
            "together and the faint telegraph taken out)")
    else:  # its root's error would be unbounded
        refuse(names[5], "active", unit, f"the white read variance from the structure "
               f"function is {value:.3g} ± {err:.2g}, not above zero")
    slow = edge and rate < 1 / float(np.median(des["dt"]))
    z, seen = (p, p_err), ""
    if slow:  # the structure function grows linearly with the lag: only P r is seen
        z = jackknife(lambda total: power(total) * fit(total)[1], columns, active, gid, k)
        seen = f"; P r = {z[0]:.4g} +- {z[1]:.2g} {unit ** 2 / u.s}"
    if not np.isfinite(z[1]) or abs(z[0]) <= 3 * z[1]:
        add(names[0], "active", p, p_err, unit ** 2, "ruled out", "mean squared step over "
            f"the active pixels not found jump by jump; ruled out: within 3 sd of none{seen}")
        for name, un in zip(names[1:5], units[1:5], strict=True):
            refuse(name, "active", un, "no faint telegraph found")
        return
    if z[0] < 0:  # less variance than the white reads and the mean current's shot noise
        why = (f"{'P r' if slow else 'the power'} is {-z[0] / z[1]:.1f} sd below 0: the ramps' "
               "variance is less than the white reads and the shot noise of the pixels' mean "
               f"current over the gain ({shot:.4g} {unit ** 2 / u.s}) give; a mean slope that "
               "is not all Poisson charge at this gain (a wrong gain, a ramp of the bias)?")
        for name, un in zip(names[:5], units[:5], strict=True):
            refuse(name, "active", un, why)
        return
    if edge:
        why = ("slower than the ramps resolve (only the power times the rate is seen"
               f"{seen})" if slow else
               "switches faster than the reads (white noise: in the read-noise map)")
        for name, un in zip(names[:5], units[:5], strict=True):
            refuse(name, "active", un, why)
        return
    add(names[0], "active", p, p_err, unit ** 2, note="fraction times the mean squared step "
        "of the telegraph pixels not found jump by jump (their structure function)")
    r, r_err = jackknife(lambda total: fit(total)[1], columns, active, gid, k)
    add(names[1], "active", r, r_err, u.Hz, note="switching rate of each state (the lags' "
        "structure function)")
    _, tr2 = _contrast_form(design)
    a = design["a"]
    sig2 = lagq[0] / (a[0] * ndarks)
    c = (lagq[-1] / a[-1] - lagq[0] / a[0]) / ndarks
    if ndarks > 1:  # the variance of a pixel's mean contrast, from its darks' scatter
        noise = (acc.pop("csq") - ndarks * c.astype(np.float64) ** 2) / (ndarks * (ndarks - 1))
    else:  # a white pixel's contrast varies by 2 σ⁴ tr(C²); σ⁴ from its own σ², less the
        # estimate's own variance
        inflate = 1 + 2 * float(np.sum(design["forms"][0] ** 2)) / a[0] ** 2
        noise = 2 * tr2 * sig2.astype(np.float64) ** 2 / inflate
    split = [np.where(quiet, c, 0.0), np.where(quiet, c.astype(np.float64) ** 2, 0.0),
             np.where(quiet, noise, 0.0), quiet * 1.0]

    ncol = len(columns)

    def step(total):  # the step scales as the rate's contrast to the -1/2: refitted too
        return _fit_split(design, fit(total[:ncol])[1], *total[ncol:])

    def fraction(total):  # the power over the step squared: fraction x step^2 is the power
        return power(total[:ncol]) / step(total) ** 2

    amp, amp_err = jackknife(step, columns + split, active, gid, k)
    f, f_err = jackknife(fraction, columns + split, active, gid, k)
    add(names[2], "active", f, f_err, "", note="fraction of the active pixels (the power over "
        "the step squared)")
    add(names[3], "active", amp, amp_err, unit, note="root of the mean fourth power of the "
        "steps over their mean square (the pixels' contrasts' scatter)")
    ty = design["times"]
    diff = np.diff(np.eye(ty.size), axis=0)
    tel = diff @ telegraph_covariance(ty, r) @ diff.T
    per = float(np.sum(des["mm"] * tel)) / des["ar"]
    add(names[4], "active", p * per, p_err * per, unit ** 2, note="what the faint telegraph "
        "adds to the active pixels' mean read-noise variance")


def _totals(columns, sel):
    return np.array([float(np.sum(np.broadcast_to(c, sel.shape)[sel], dtype=np.float64))
                     for c in columns])
