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
``tau_j`` = `AMPLITUDES` times the read noise, equal weights (a prior spread over
three decades of amplitude), the line's intercept and slope flat.  For a step at
``k`` of amplitude prior ``N(0, tau**2)``, with ``A_k``, ``V_k`` the step's
least-squares amplitude and variance (`~spherex_reduce.reduce.steps.fit_ramp.step_model`)
and ``z_k**2 = A_k**2 / V_k``, the evidence against "no jump" is
``sqrt(V_k / (V_k + tau**2)) exp(z_k**2 tau**2 / (2 (V_k + tau**2)))``; the slope is the
line's less ``c_k s A_k`` (``c_k``: the line's slope change per unit step, ``s = tau**2 /
(tau**2 + V_k)``) with the line's variance plus ``c_k**2 s V_k``.  For white read noise
and reads of equal weight these are exact (the step's amplitude is independent of the
slope of the line fitted to the reads less the step); with shot noise, ``V_k`` holds
its share and they are a close approximation.

Only ramps where a step is plausible are weighed: every ramp of fewer than
`WEIGH_ALL_READS` reads, and longer ramps whose largest ``|z_k|`` (read noise alone)
reaches `WEIGH_FROM`.  Below it, on 74 reads of white noise, the steps' posterior moves
the slope and its error by less than a percent of the line's sigma (a numpy study over
every ramp: ``benchmarks/bench_jump_marginal.py``).
"""

import numpy as np

__all__ = ["AMPLITUDES", "WEIGH_ALL_READS", "WEIGH_FROM", "step_posterior"]

#: sigmas of the Gaussian components of the prior on a step's amplitude, in read-noise
#: sigmas (one frame's): an equal-weight mixture over three decades
AMPLITUDES = np.array([1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0])
#: ramps of fewer reads are all weighed (few candidate reads, cheap; there the steps of
#: |z| 2-3 carry the weight that matters: 50-100 e jumps in 4 reads of 10 e)
WEIGH_ALL_READS = 16
#: longer ramps are weighed where their largest |z| of a step (read noise alone) reaches
#: this
WEIGH_FROM = 3.0
#: ramps weighed at once (their (n - 1) x ramps arrays stay a few MB)
PIECE = 2048


def step_posterior(model, y, sigma2, lam, prior, slope_weights, jumped=None):
    """The posterior shift of each ramp's line slope and the variance it adds.

    Parameters
    ----------
    model : `~spherex_reduce.reduce.steps.fit_ramp.step_model.StepModel`
        The reads' step model (read-noise weights: ``rho = 0``).
    y : `numpy.ndarray`
        Reads ``(n, m)`` of ``m`` ramps, float64, every read usable (data unit).
    sigma2 : `numpy.ndarray`
        Read-noise variance of one frame, ``(m,)`` (data unit squared), > 0.
    lam : `numpy.ndarray`
        Shot noise, ``(m,)``: rate over gain (data unit squared per second).
    prior : float
        Probability that a ramp holds a jump, in (0, 1).
    slope_weights : `numpy.ndarray`
        ``(n,)``: the weights of the line's slope the caller fits (``sum w y``).
    jumped : `numpy.ndarray` of bool, optional
        ``(m,)``: ramps known to hold a step (a search flagged one): weighed over the
        reads it may be at only, without "no jump", its amplitude free (a flat prior:
        the search chose the ramp for its step, and a prior that shrinks the step
        would undo the choice).

    Returns
    -------
    shift : `numpy.ndarray`
        ``(m,)``: posterior mean slope less the line's (data unit / s).
    extra : `numpy.ndarray`
        ``(m,)``: posterior variance less the line's ((data unit / s)**2), >= 0.
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
    >>> shift, extra, p = step_posterior(StepModel(t), y, np.full(2, 100.0), np.zeros(2),
    ...                                  0.03, ramp_weights(t))
    >>> np.round(p, 2).tolist()  # the flat ramp keeps "no jump"; the other does not
    [0.01, 0.66]
    >>> sigma_line = np.sqrt(100.0 * (ramp_weights(t) ** 2).sum())  # the line's ERR
    >>> np.round(np.sqrt(extra) / sigma_line, 2).tolist()  # the error each adds
    [0.1, 4.04]
    """
    n, m = y.shape
    shift, extra, p_step = np.zeros(m), np.zeros(m), np.zeros(m)
    c = model.h @ slope_weights  # (n - 1,): the fitted slope's change per unit step
    none = np.full(m, np.log1p(-prior))
    jumped = np.zeros(m, bool) if jumped is None else np.asarray(jumped, bool)
    none[jumped] = -np.inf
    log_each = np.log(prior / ((n - 1) * AMPLITUDES.size))
    for lo in range(0, m, PIECE):
        cut = slice(lo, min(m, lo + PIECE))
        _, big_r, _ = model.step_sums(y[:, cut])
        s2 = sigma2[cut]
        var = s2 * model.q[:, None] + lam[cut] * model.s[:, None]  # Var(R_k)
        v = var / model.q[:, None] ** 2  # Var(A_k)
        amp = big_r / model.q[:, None]
        z2 = big_r ** 2 / var
        logs, shrinks = [], []
        known = jumped[cut]
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
        log_none = none[cut]
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
        shift[cut] = -mu
        extra[cut] = np.maximum(s2nd / total - mu * mu, 0.0)
        p_step[cut] = w_step / total
    return shift, extra, p_step
