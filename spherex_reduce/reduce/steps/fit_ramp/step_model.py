"""A line with a step at one read: the matrices both ``detect_jumps`` and ``fit_ramp`` use.

A ramp's usable reads ``y_i`` at times ``t_i`` are modelled as a line with a step of
amplitude ``A`` at read ``k`` (the first read after the step): ``y_i = a + b t_i + A
[i >= k] + noise``, the noise white read noise of variance ``sigma**2 f_i`` (``f_i`` a
factor per read: 1 for single frames, ``1/n`` for a group averaging ``n``) plus the
shot noise of the charge collected, a random walk of variance ``lambda t``.

The generalised least-squares amplitude of the step, the line's intercept and slope
free, is ``A_k = R_k / q_k`` with ``R_k = h_k' W M y`` (``h_k`` the step, ``W`` the
weights, ``M`` the weighted residual maker of the line): with read-noise weights
``W = diag(1/f)``, ``R_k`` is a tail sum of the line's weighted residuals.  Its
variance is ``sigma**2 q_k + lambda s_k``; ``z_k = R_k / sqrt(sigma**2 q_k + lambda
s_k)`` is the matched-filter statistic of a step at ``k``, and a step ``A`` at ``k``
moves the line's slope by ``A`` times ``slope_of_step[k - 1]``.

With ``slope_precision`` the line's slope has a prior: one more observation of it, of
variance ``sigma**2 / slope_precision`` about zero (``detect_jumps``' ``expected_rate``
subtracts each ramp's expected line from its reads first), so that a step is tested
against a line whose slope is known beforehand (a master dark's) rather than a free one: the same
formulas with the generalised least squares of the reads and that observation (``X' W
X`` gains ``slope_precision`` in its slope's place); ``R_k`` stays a tail sum of the
weighted residuals about the (posterior) line, since the intercept stays free.

`StepModel` holds these for a set of read times, once; ``detect_jumps`` searches
with them (`~spherex_reduce.reduce.steps.jumps.search.StepSearch`) and ``fit_ramp``
weighs the steps a ramp may hold
(`~spherex_reduce.reduce.steps.fit_ramp.step_posterior`, ``jump_prior``).
"""

import numpy as np

from ....core.limits import check_size
from .segments import accumulate_reads

__all__ = ["StepModel"]


class StepModel:
    """The matrices of a line plus a step at each read, for reads at ``times``.

    Parameters
    ----------
    times : array_like
        Times of the usable reads (s), increasing, at least 3.
    factors : array_like, optional
        Read-noise variance of each read relative to one frame's (default 1 for
        every read; a group that averages ``n`` frames has ``1/n``).
    walk : array_like, optional
        Covariance of the reads' charge per unit rate (s), ``(n, n)`` (default
        ``min(t_i, t_j) - t_0``, single frames).
    rho : float
        Shot noise in the weights, ``lambda / sigma**2`` (1/s); 0: read-noise weights.
    slope_precision : float
        Weight of a prior observation of the slope, zero on average: ``sigma**2`` over its
        variance (s**2; 0: the slope free).

    Attributes
    ----------
    q : `numpy.ndarray`
        ``(n - 1,)``: the variance of ``R_k`` over ``sigma**2`` (read noise).
    s : `numpy.ndarray`
        ``(n - 1,)``: the variance of ``R_k`` per unit ``lambda`` (shot noise; zeros
        with ``rho``, whose weights hold it).
    slope_of_step : `numpy.ndarray`
        ``(n - 1,)``: the change of the line's slope per unit step at read ``k``.

    Examples
    --------
    Four reads one second apart: with the slope free, a step at the middle read is
    measured to ``sigma / sqrt(q) = 2.24 sigma`` and moves the slope by 0.4 of itself:

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.fit_ramp.step_model import StepModel
    >>> m = StepModel(np.arange(4.0))
    >>> np.round(m.q, 3).tolist(), np.round(m.slope_of_step, 3).tolist()
    ([0.3, 0.2, 0.3], [0.3, 0.4, 0.3])
    """

    def __init__(self, times, factors=None, walk=None, rho=0.0, slope_precision=0.0):
        t = np.asarray(times, np.float64)
        n = t.size
        if n < 3:
            raise ValueError(f"a line with a step needs at least 3 reads, got {n}")
        check_size(self.nbytes(n), f"the step model of {n} reads")
        tau = t - t[0]
        f = np.ones(n) if factors is None else np.asarray(factors, np.float64)
        walk = np.minimum.outer(tau, tau) if walk is None else np.asarray(walk, np.float64)
        w = 1.0 / f
        # weights: the inverse covariance in units of one read's read-noise variance,
        # read noise alone (rho = 0), or with the shot noise of rho = lambda / sigma**2
        v = np.diag(w) if rho == 0 else np.linalg.inv(np.diag(f) + rho * walk)
        x = np.column_stack([np.ones(n), tau])
        xtv = x.T @ v
        # (2, n): intercept and slope of y (with the slope's prior observation of 0)
        coef = np.linalg.solve(xtv @ x + np.diag([0.0, float(slope_precision)]), xtv)
        wm = v - xtv.T @ coef  # V M, symmetric
        h = (np.arange(n)[None, :] >= np.arange(1, n)[:, None]).astype(np.float64)
        g = h @ wm  # R_k = g[k - 1] @ y for a step at read k
        self.n, self.tau, self.w, self.rho = n, tau, w, rho
        self.slope_precision = float(slope_precision)
        self.coef, self.h, self.gk = coef, h, g
        self.g = g if rho else None  # R = g @ y (with rho = 0: tail sums of weighted residuals)
        self.wm = wm
        self.q = np.einsum("ki,ki->k", g, h)  # variance of R_k / sigma**2
        # shot-noise variance / lambda (none with rho: the shot noise is in q)
        self.s = np.zeros(n - 1) if rho else np.einsum("ki,ij,kj->k", g, walk, g)
        self.slope_of_step = (coef @ h.T)[1]  # change of the line's slope per unit step
        # read-noise variance of the line's slope, in sigma**2, and its shot noise / lambda
        self.slope_var = float(np.sum(coef[1] ** 2 * f))
        self.shot_var = float(coef[1] @ walk @ coef[1])
        self.factors, self.walk = f, walk
        self.uniform_w = bool(np.all(w == w[0]))
        d = np.diff(tau)
        self.dtau = d
        self._types = {}  # dtype -> (w, 1 / q, coef) in it
        self._invq = 1.0 / self.q

    @staticmethod
    def nbytes(n):
        """Bytes the matrices of ``n`` reads take: about ten ``n x n`` float64 matrices
        (the random walk, the weights and their products), checked before any is made."""
        return 8.0 * 10 * float(n) * n

    def _typed(self, dtype):
        """Weights, ``1 / q``, the line's coefficients and the times in ``dtype`` (made once
        per type)."""
        typed = self._types.get(dtype)
        if typed is None:
            typed = self._types[dtype] = (self.w.astype(dtype), self._invq.astype(dtype),
                                          self.coef.astype(dtype), self.tau.astype(dtype))
        return typed

    def screen(self, y, estimate, work=None):
        """``max_k R_k**2 / q_k`` of ramps ``y`` ``(n, m)`` with read-noise weights, and the
        weighted RSS of their lines (None unless ``estimate``), in ``y``'s type.

        Whole-array operations on ``(n, m)`` (the line, the residuals, their squares and
        the maximum over the reads) and one addition per read for the tail sums: each call
        long enough to leave the interpreter's lock to the other threads (a loop of six
        operations per read on ``m`` ramps held it most of the time: two threads screened
        no faster than one).  ``work``: a float ``(n, m')`` buffer of ``y``'s type, ``m'
        >= m``, to write in (made if None); keep ``y`` and it in cache.
        """
        n, m = y.shape
        w, invq, coef, tau = self._typed(y.dtype)
        r = np.empty(y.shape, y.dtype) if work is None else work[:, :m]
        ab = coef @ y
        np.multiply(tau[:, None], ab[1], out=r)  # the line
        r += ab[0]
        np.subtract(y, r, out=r)  # its residuals
        rss = None
        if estimate:
            rss = w @ np.square(r) if not self.uniform_w else np.einsum("im,im->m", r, r)
        if not self.uniform_w:
            r *= w[:, None]
        for i in range(1, n - 1):  # R_(i+1) = -(the sum of the residuals up to read i)
            np.add(r[i - 1], r[i], out=r[i])
        acc = r[:n - 1]
        np.multiply(acc, acc, out=acc)
        acc *= invq[:, None]
        best = acc.max(axis=0)
        if self.uniform_w and w[0] != 1:  # equal weights left out: put them back
            best *= w[0] * w[0]  # R_k is w times the tail sum of the residuals
            if estimate:
                rss *= w[0]
        return best, rss

    def step_sums(self, y):
        """The line's intercept and slope ``(2, m)``, ``R_k`` of every read ``(n - 1, m)`` and
        the weighted RSS ``(m,)`` of float64 ramps ``y`` ``(n, m)``."""
        ab = np.einsum("ci,im->cm", self.coef, y)
        r = y - ab[0] - ab[1] * self.tau[:, None]
        if self.g is None:
            wr = r * self.w[:, None]
            big_r = accumulate_reads(np.add, wr[:0:-1])[::-1]  # (n - 1, m): R_k, tail sums
            rss = np.einsum("im,im->m", wr, r)
        else:
            big_r = np.einsum("ki,im->km", self.g, y)
            rss = np.einsum("im,ij,jm->m", r, self.wm, r)
        return ab, big_r, rss
