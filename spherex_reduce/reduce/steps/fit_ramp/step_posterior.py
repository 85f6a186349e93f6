"""A slope that weighs the steps no search flagged: ``fit_ramp``'s ``jump_prior``.

A ramp fitted as one line may still hold a step too small to flag: a 10-30 e cosmic
ray at mid-ramp, where a step is nearly degenerate with a change of slope, or a 50-100
e jump in a ramp of 4 reads (with the slope free, a step at the middle of 4 reads is
measured to 2.24 read-noise sigmas).  Its slope is then off by several of the line's
sigmas while the line's ``ERR`` says nothing of it.

With a prior probability ``p`` that a ramp holds a jump (``jump_prior``), the slope
and its variance are the posterior mean and variance over the models "no jump"
(prior ``1 - p``) and "a step at read k" (``p / (n - 1)`` for each of the ``n - 1``
reads after the first), the step's amplitude a scale mixture of Gaussians of sigma
``tau_j`` = `AMPLITUDES` times the read noise, equal weights (half-decades from one
read-noise sigma to a thousand, and a million), the line's intercept and slope flat.
For a step at ``k`` of amplitude prior ``N(0, tau**2)``, with ``A_k``, ``V_k`` the
step's least-squares amplitude and variance
(`~spherex_reduce.reduce.steps.fit_ramp.step_model`) and ``z_k**2 = A_k**2 / V_k``, the
evidence against "no jump" is ``sqrt(V_k / (V_k + tau**2)) exp(z_k**2 tau**2 / (2 (V_k +
tau**2)))``; the slope is the line's less ``c_k s A_k`` (``c_k``: the line's slope
change per unit step, ``s = tau**2 / (tau**2 + V_k)``) with the line's variance plus
``c_k**2 s V_k``.  A ramp a search flagged is taken to hold a step: its slope is weighed
over the read the step is at, its amplitude free (flat), without "no jump" (weighing
"no jump" in moved the slopes of real 20-30 e jumps towards the line: twice as many
hit ramps > 5 line sigmas off); its variance is the mean squared distance of that slope
from the posterior's without the flag, "no jump" included (the flag is the data's
doing): a clean ramp flagged where its noise looked most like a step had (slope -
truth) / ERR of rms 2.5-3, now ~1.  For white read
noise and reads of equal weight (single reads or equal groups) these are exact: the
step's amplitude is independent of the slope of the line fitted to the reads less the
step.  With shot noise, ``V_k`` holds its share, at the rate of the line less the
ramp's best step (so that a jump does not inflate it), and they are a close
approximation; for reads of unequal weight they are not (``fit_ramp`` refuses them).

Only ramps where a step is plausible are weighed: every ramp of fewer than
`WEIGH_ALL_READS` reads, ramps a search flagged, and longer ramps whose largest
``|z_k|`` (read noise alone, in float64) reaches `WEIGH_FROM`.  Below it, on 74 reads
of white noise, the exact posterior's slope is within 0.02 of the line's sigma of the
line's and its error 1.9 % above the line's on average (6 % at most) for ramps of
``|z|`` 2.5-3 (less below); leaving them out changes the fraction of hit ramps more than
5 errors off by a few hundredths of a percent (a numpy study over every ramp:
``benchmarks/bench_jump_marginal.py``).  At 3.5 the weighing costs a quarter as much,
but the error of ramps of ``|z|`` 3-3.5 would be 6 % low on average (21 % at most).
"""

import numpy as np

__all__ = ["AMPLITUDES", "WEIGH_ALL_READS", "WEIGH_FROM", "step_posterior"]

#: sigmas of the Gaussian components of the prior on a step's amplitude, in read-noise
#: sigmas (one frame's): an equal-weight mixture, half-decades from 1 to 1000 (cosmic rays
#: near the threshold), and 1e6 (a step far beyond the widest component would keep a share
#: V / tau**2 of its effect on the slope; one wide component costs an eighth more time
#: where decades to 1e6 cost two fifths)
AMPLITUDES = np.array([1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1e3, 1e6])
#: ramps of fewer reads are all weighed (few candidate reads, cheap; there the steps of
#: |z| 2-3 carry the weight that matters: 50-100 e jumps in 4 reads of 10 e)
WEIGH_ALL_READS = 16
#: longer ramps are weighed where their largest |z| of a step (read noise alone) reaches
#: this
WEIGH_FROM = 3.0
#: ramps weighed at once (their (n - 1) x ramps arrays stay a few MB)
PIECE = 2048
#: z**2 is clipped here (a step of a read noise ~1e-300: no overflow to inf - inf)
_Z2_MAX = 1e300


def step_posterior(model, y, sigma2, prior, *, pscale=0.0, dark=0.0, jumped=None,
                   weigh_from=None):
    """The posterior shift of each ramp's line slope and the variance it adds.

    Parameters
    ----------
    model : `~spherex_reduce.reduce.steps.fit_ramp.step_model.StepModel`
        The reads' step model (read-noise weights: ``rho = 0``), reads of equal
        read-noise factors: its line is then the uniform least-squares line.
    y : `numpy.ndarray`
        Reads ``(n, m)`` of ``m`` ramps, float64, every read usable (data unit).
    sigma2 : `numpy.ndarray`
        Read-noise variance of one frame, ``(m,)`` (data unit squared), > 0.
    prior : float
        Probability that a ramp holds a jump, in (0, 1).
    pscale, dark : float or `numpy.ndarray`
        1 / gain (data unit per electron) and the dark current already subtracted
        (data unit / s), numbers or ``(m,)``: the shot noise of a step's amplitude is
        that of the rate ``max(line - best step, 0) + dark``.
    jumped : `numpy.ndarray` of bool, optional
        ``(m,)``: ramps taken to hold a step (a search flagged one): the shift is
        weighed over the reads it may be at only, without "no jump", its amplitude
        free (a flat prior: the search chose the ramp for its step, and a prior that
        shrinks the step would undo the choice); the variance is the posterior's
        without the flag about that shift.
    weigh_from : float, optional
        Ramps (not ``jumped``) whose largest ``|z_k|`` with read noise alone is below
        this are not weighed (zeros); None: every ramp.

    Returns
    -------
    shift : `numpy.ndarray`
        ``(m,)``: posterior mean slope less the line's (data unit / s).
    extra : `numpy.ndarray`
        ``(m,)``: posterior variance less the line's ((data unit / s)**2), >= 0 (of a
        ``jumped`` ramp: the mean squared distance of the posterior without the flag
        from the shift, less the line's variance).
    p_step : `numpy.ndarray`
        ``(m,)``: posterior probability that the ramp holds a step.

    Examples
    --------
    Four reads of 10 e one second apart, a line without a step and one with a step of
    100 e at the third read (4.5 sigmas of a step there with the slope free):

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.step_model import StepModel
    >>> from spherex_reduce.reduce.steps.fit_ramp.least_squares import ramp_weights
    >>> t = np.arange(4.0)
    >>> y = np.column_stack([[0.0, 3.0, -2.0, 1.0], [0.0, 3.0, 98.0, 101.0]])
    >>> shift, extra, p = step_posterior(StepModel(t), y, np.full(2, 100.0), 0.03)
    >>> np.round(p, 2).tolist()  # the flat ramp keeps "no jump"; the other does not
    [0.01, 0.63]
    >>> sigma_line = np.sqrt(100.0 * (ramp_weights(t) ** 2).sum())  # the line's ERR
    >>> np.round(np.sqrt(extra) / sigma_line, 2).tolist()  # the error each adds
    [0.09, 4.09]
    """
    n, m = y.shape
    shift, extra, p_step = np.zeros(m), np.zeros(m), np.zeros(m)
    jumped = np.zeros(m, bool) if jumped is None else np.asarray(jumped, bool)
    pscale, dark = (np.broadcast_to(np.asarray(a, np.float64), (m,)) for a in (pscale, dark))
    c = model.slope_of_step  # (n - 1,): the line's slope change per unit step
    q = model.q[:, None]
    for lo in range(0, m, PIECE):
        cut = slice(lo, min(m, lo + PIECE))
        ab, big_r, _ = model.step_sums(y[:, cut])
        s2 = sigma2[cut]
        z2 = big_r ** 2 / (s2 * q)  # read noise alone
        kb = np.argmax(z2, axis=0)
        take = np.arange(z2.shape[1])
        if weigh_from is not None:
            take = take[jumped[cut] | (z2[kb, take] >= weigh_from ** 2)]
            if not take.size:
                continue
        idx = lo + take
        # a lone ramp is weighed beside a copy of itself: numpy's sums over the reads of
        # one column take other paths, whose rounding would differ (bands of one pixel)
        pair = np.concatenate([take, take]) if take.size == 1 else take
        big_r, s2, kb, line = big_r[:, pair], s2[pair], kb[pair], ab[1, pair]
        cols = np.arange(pair.size)
        amp = big_r / q
        rate = np.maximum(line - c[kb] * amp[kb, cols], 0.0)
        lam = (rate + dark[lo + pair]) * pscale[lo + pair]
        var = s2 * q + lam * model.s[:, None]  # Var(R_k)
        v = var / q ** 2  # Var(A_k)
        z2 = np.minimum(big_r ** 2 / var, _Z2_MAX)
        out = _posterior(z2, v, amp, s2, c, prior, n, jumped[lo + pair])
        for arr, value in zip((shift, extra, p_step), out, strict=True):
            arr[idx] = value[:take.size]
    return shift, extra, p_step


def _posterior(z2, v, amp, s2, c, prior, n, known):
    """``(shift, extra, p_step)`` of ramps whose steps have ``z_k**2``, variances ``v`` and
    amplitudes ``amp`` (``(n - 1, m)``), read-noise variance ``s2``; ``known``: flagged."""
    # C order whatever the columns taken: numpy's sums over the reads then add each
    # column's terms in one order, however many columns come with it (bands)
    z2, v, amp = (np.ascontiguousarray(a) for a in (z2, v, amp))
    log_each = np.log(prior / ((n - 1) * AMPLITUDES.size))
    logs, shrinks = [], []
    for tau in AMPLITUDES:
        t2 = tau * tau * s2
        shrink = np.add(v, t2, out=np.empty_like(v))
        np.divide(t2, shrink, out=shrink)
        lw = np.log1p(-shrink)
        lw += z2 * shrink
        lw *= 0.5
        lw += log_each
        lw[:, known] = -np.inf
        logs.append(lw)
        shrinks.append(shrink)
    if known.any():  # a flat amplitude: the evidence of a step at k is ~ sqrt(V_k) e^(z2/2)
        lw = np.full_like(z2, -np.inf)
        lw[:, known] = 0.5 * (np.log(v[:, known]) + z2[:, known])
        logs.append(lw)
        shrinks.append(np.ones_like(z2))
    log_none = np.where(known, -np.inf, np.log1p(-prior))
    top = np.maximum(log_none, np.max([lw.max(axis=0) for lw in logs], axis=0))
    total = np.exp(log_none - top)
    w_step = np.zeros_like(total)
    s1 = np.zeros_like(total)
    s2nd = np.zeros_like(total)
    a = c[:, None] * amp  # a step's full shift of the slope (the shift is -a shrink)
    a2 = a * a
    cv = c[:, None] ** 2 * v
    for lw, shrink in zip(logs, shrinks, strict=True):
        w = np.subtract(lw, top, out=lw)
        np.exp(w, out=w)
        w_step += w.sum(axis=0)
        w *= shrink
        s1 += np.einsum("km,km->m", w, a)
        # each model's variance less the line's, c**2 v shrink, plus its mean squared
        shrink *= a2
        shrink += cv
        s2nd += np.einsum("km,km->m", w, shrink)
    total += w_step
    mu = s1 / total
    extra = np.maximum(s2nd / total - mu * mu, 0.0)
    if known.any():
        # a flagged ramp keeps the slope of its step, but its error is that of the
        # posterior without the flag (which the data decided): the mean squared distance
        # of that slope from the slopes of "no jump" and of every step, under the prior
        # (a clean ramp whose noise looked like a step was 2.8 ERR off in rms)
        kn = np.flatnonzero(known)
        sub = np.concatenate([kn, kn]) if kn.size == 1 else kn  # (one column: see caller)
        f_shift, f_extra, _ = _posterior(z2[:, sub], v[:, sub], amp[:, sub], s2[sub], c,
                                         prior, n, np.zeros(sub.size, bool))
        extra[kn] = f_extra[:kn.size] + (f_shift[:kn.size] + mu[kn]) ** 2
    return -mu, extra, w_step / total
