"""Where a ramp's charge stepped: the numerics of ``detect_jumps``.

A pixel's usable reads ``y_i`` at times ``t_i`` are modelled as a line with a
step of amplitude ``A`` at read ``k`` (the first read after the step):
``y_i = a + b t_i + A [i >= k] + noise``.  The noise is white read noise of
variance ``sigma**2 f_i`` (``f_i``: a factor per read, 1 for single frames;
a group averaging ``n`` frames has ``f = 1/n``) plus the shot noise of the
charge collected, a random walk of variance ``lambda t`` (``lambda`` = rate /
gain in data units squared per second).

For every candidate ``k`` the generalised least-squares amplitude of the step
given intercept and slope is ``A_k = R_k / q_k`` with ``R_k = h_k' W M y``
(``h_k`` the step, ``W = diag(1/f)``, ``M`` the weighted residual maker of the
line): ``R_k`` is a tail sum of the line's weighted residuals, a cumulative
sum.  Its variance is ``sigma**2 q_k + lambda s_k`` (``q_k = h_k' W M h_k``,
``s_k`` the random walk's share), so ``z_k = R_k / sqrt(sigma**2 q_k +
lambda s_k)`` is the matched-filter (likelihood-ratio) statistic of a step at
``k``; ``max_k |z_k|`` above the threshold is a jump, at the ``k`` of the
maximum.  With read noise only (dark ramps) this is the exact likelihood-ratio
test for one step at an unknown read.  The step found is subtracted and the
search repeated, for ramps with several jumps.

``lambda`` comes from the pixel's slope with the best step removed (so a jump
does not inflate it; in the first round of a ramp of at most `LINE_RATE_READS`
reads with the read noise given and no slope prior, from the line's slope: a jump
inflates it, but
it is independent of the step statistic when there is none), ``sigma`` from the
read-noise map or, when none is
given, from the pixel's own residuals about the line with the best step
(``(RSS - R_k**2 / q_k) / (n - 3)``, which a jump does not inflate either).

`StepSearch.find` first screens every pixel with float32 cumulative sums over
the reads (whole-array operations on a few thousand pixels at a time, in cache):
with read noise alone ``z`` can only be larger, so pixels whose read-noise
``max z`` is below the threshold have no jump.  The few left are searched in
float64 with the full noise model.  Each pixel's result depends on its own
reads only.

The matrices (the line's coefficients, ``q``, ``s``, the slope's change per
unit step) and the screen are those of
`~spherex_reduce.reduce.steps.fit_ramp.step_model.StepModel`, which
``fit_ramp`` weighs the steps it did not flag with (``jump_prior``).
"""

import functools
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtri, log_ndtr  # scipy.stats would load scipy.optimize

from ....core.limits import check_size
from ....core.recently_used import RecentlyUsed
from ..fit_ramp.step_model import StepModel

__all__ = ["OWN_SIGMA", "SCALE_DOF", "SCREEN_MARGIN", "Found", "SlopePrior", "StepSearch",
           "cached_search"]

#: the float32 screen keeps pixels down to this fraction of the threshold, so that its
#: rounding never drops a pixel the float64 search would flag
SCREEN_MARGIN = 0.98
#: bytes of the shot-weighted searches kept per set of reads (bins of rho, the least recently
#: used let go; `StepSearch.nbytes` each, 73 of them for 74 reads): the dark strip's ramps
#: fall in 20 bins, a sky's rates over two decades in ~40, and a search remade costs ~1-2 ms
SHOT_CACHE_BYTES = 32 << 20
#: E[x**2 | x**2 below its 90 % quantile] for a unit Gaussian x (1 - 2 z phi(z) / 0.9 at
#: z = 1.6449)
_TRIMMED_90 = 0.62302
#: shot noise (lambda / sigma**2 times the longest charge variance per unit rate) above
#: which a ramp is searched with weights for its shot noise, in bins of RHO_BIN dex
SHOT_WEIGHTED = 0.1
RHO_BIN = 0.05
#: a pair of steps whose chi2 is within this of the best one's is flagged too (shot noise
#: can make the groups on either side of a jump almost equally likely to hold it)
PAIR_MARGIN = 9.0
#: bytes of reads screened at once: the reads minus the first and the screen's residuals
#: (as many bytes again) stay in a core's 2 MB L2 cache between the line's fit and the sums
#: over reads (1.5 MB: the 128 x 2048 strip's search in 0.10-0.14 s of CPU where 6 MB took
#: 0.21-0.29 s, 2 MB 0.34-0.40 s and 1 MB 0.15-0.16 s, on two cores shared with other work;
#: with the screen's whole-array operations, 262 144 ramps of 74 reads in 45 ms on one
#: thread and two such bands in 57 ms on two at 1.5 MB, 106 ms at 2.3 MB)
SCREEN_BYTES = 3 << 19
#: the read noise given is scaled to the ramps' own scatter (`StepSearch.scatter`) when
#: their ramps x degrees of freedom (reads - 2) reach this: the median's relative error is
#: then below ~1 % in variance (at 4 sigma a read noise 1 % off moves the false alarms ~18 %)
SCALE_DOF = 1 << 15
#: ramps x degrees of freedom the scatter is measured on at most (every k-th ramp): the
#: median's relative error in variance ~1.25 sqrt(2 / SCALE_SAMPLE) = 0.35 %, in ~10 ms
SCALE_SAMPLE = 1 << 18
#: ramps with a step of this many sigma (of the read noise given) are left out of the scatter
SCALE_OUT_Z = 8.0
#: ramps whose shot noise (their own slope's) would hold more than this fraction of their
#: first differences' expected variance are left out of the scatter (read noise, mostly)
SCALE_SHOT = 0.1
#: the charge rate whose shot noise a step is tested with: the slope less the best step,
#: less this many of its read-noise sigmas, clipped at 0 (a dark ramp's slope is read
#: noise: clipped at 0 alone its mean is 0.4 sigma and the shot noise it adds hides
#: small steps and lowers the false alarms below the stated rates; at 1 sigma 0.08 sigma)
SHOT_RATE_SIGMAS = 1.0
#: ramps of at most this many reads, read noise given and no slope prior, take the line's
#: slope as their shot noise's rate in their first round instead:
#: the slope less the best step is lowest where the step statistic is largest (on 3 reads
#: it is the smaller difference), so the jump-free ramps it searched false-alarmed at
#: 0.63-0.81 of the stated rate on 4-5 reads of a 0.01 e/s dark (gain 1) and up to 1.42x
#: on 100 e/s, 1.6-3.3x on 3 bright reads; with the line 0.85-0.98 (2^22 ramps per case)
#: and 0.90-1.04 (1.01-1.17 on 3).  A jump inflates the line's slope and so its own test's
#: noise: on 4 / 5 reads 4.27 -> 5.19 % / 3.05 -> 3.51 % of hit pixels > 5 sigma0 wrong,
#: acceptable where the false-alarm rate is otherwise wrong; on JWST's 10 groups 3.66 ->
#: 5.34 %, so not there
#: (6-10 reads keep the slope less the step: 0.72-0.85 of the rate, stated)
LINE_RATE_READS = 5
#: with a slope prior (`SlopePrior`), a ramp whose two-segment slope at the prior search's
#: best step is this many of its sigmas (and the prior's spread) off its expected slope is
#: searched with its slope free: a pixel warmer than expected, a source (at the
#: slope-free search's best step instead, a 10-30 e step placed at the wrong read would
#: look off the expected slope)
OWN_SIGMA = 4.0


@dataclass(frozen=True)
class SlopePrior:
    """The rate each ramp is expected to hold, as a prior on its line's slope in the step
    search (``detect_jumps``' ``expected_rate``).

    Attributes
    ----------
    search : `StepSearch`
        The search of the same reads whose ``slope_precision`` is the read noise's
        variance over the prior's (its ``spread``, or its floor), in the ramps' ``sigma``.
    slope : float or `numpy.ndarray`
        The expected slope (data unit / s): one for all, or one per ramp given to
        `StepSearch.find` (its columns).
    spread : float
        How much the ramps' true rates spread about ``slope`` (data unit / s).
    """

    search: object
    slope: float
    spread: float


class StepSearch(StepModel):
    """The step search for ramps read at ``times``: its matrices, computed once (a
    `~spherex_reduce.reduce.steps.fit_ramp.step_model.StepModel` with those of
    several steps at once and of the shot-weighted searches).

    Parameters
    ----------
    times, factors, walk, rho, slope_precision
        As `~spherex_reduce.reduce.steps.fit_ramp.step_model.StepModel`'s, at least 3
        reads (a group's ``walk`` is the mean over its frames,
        `~spherex_reduce.ReadoutSchedule.shot_covariance`); with ``slope_precision`` the
        reads given to `find` are those less the expected line (`find`'s ``prior``).

    Examples
    --------
    A dark ramp of 20 reads (read noise 1, 0.01 per second) with a step of 8 at read 12:

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.jumps.search import StepSearch
    >>> t = np.arange(20.0)
    >>> y = (100 + 0.01 * t + 8.0 * (t >= 12) + np.random.default_rng(1).normal(0, 1, 20))[:, None]
    >>> found = StepSearch(t).find(y, threshold=5.0, sigma=1.0)
    >>> found.read.tolist(), found.pixel.tolist(), round(float(found.amplitude[0]), 1)
    ([12], [0], 7.5)
    """

    def __init__(self, times, factors=None, walk=None, rho=0.0, slope_precision=0.0):
        n = np.size(times)
        if n < 3:
            raise ValueError(f"a step search needs at least 3 reads, got {n}")
        check_size(self.nbytes(n), f"detect_jumps: the step search over {n} reads")
        super().__init__(times, factors, walk, rho, slope_precision)
        tau, f, walk, coef, g, h = (self.tau, self.factors, self.walk, self.coef, self.gk,
                                    self.h)
        self.qq = g @ h.T  # Q[k, l] = h_k' V M h_l: q is its diagonal
        # the random walk's covariance of R: s is its diagonal (none with rho: it is in q)
        self.ss = np.zeros((n - 1, n - 1)) if rho else g @ walk @ g.T
        self.walk_top = float(np.max(np.diagonal(walk)))
        # each first difference less the line's slope over its interval: its read-noise
        # variance (in sigma**2) and shot-noise variance (per unit lambda), for `scatter`
        dd = np.diff(np.eye(n), axis=0) - np.diff(tau)[:, None] * coef[1][None, :]
        self.diff_read = np.einsum("ij,j,ij->i", dd, f, dd)
        self.diff_walk = np.einsum("ij,jk,ik->i", dd, walk, dd)
        # reads averaging several frames: a jump may fall between their frames, a step
        # into the read and another out of it (searched as a pair)
        self.partial = f < 1
        # rho bin -> StepSearch with that shot noise in its weights
        self._shot = RecentlyUsed(SHOT_CACHE_BYTES, size=lambda found: self.nbytes(n))

    def with_shot(self, rho):
        """The search of these reads weighted for shot noise ``rho`` (lambda / sigma**2,
        1/s), made once per bin of `RHO_BIN` dex."""
        key = int(np.round(np.log10(rho) / RHO_BIN))
        return self._shot.get(key, lambda: StepSearch(self.tau, self.factors, self.walk,
                                                      10.0 ** (key * RHO_BIN),
                                                      self.slope_precision))

    def scatter(self, y, sigma, gain=1.0):
        """How much the ramps ``y`` scatter about their lines, in units of the read noise
        ``sigma`` given: the variance ratio, or None when there are too few ramps.

        Each first difference of a ramp less its line's slope over the interval, ``u_i``,
        is Gaussian of variance ``sigma**2 a_i`` for white read noise of that sigma
        (``a_i`` from the read times and weights); ``u_i**2 / (sigma**2 a_i)`` is
        chi-squared with 1 degree of freedom.  Its median over the ramps, for each
        interval, against that distribution's median, then the median over the
        intervals, is the ratio of the ramps' read-noise variance to ``sigma**2``: a
        read that is off for every ramp (a first read below the line of the others, a
        frame glitch) or a step of every ramp at the same read moves one or two
        intervals, which the median over the intervals leaves out.  Each ``u_i**2``
        first loses the shot noise's expected share, ``lambda b_i`` for the ramp's own
        slope (not clipped: its noise is independent of ``u``); ramps where that share
        exceeds `SCALE_SHOT` of the read noise's, and ramps with a step of `SCALE_OUT_Z`
        sigma or more (a jump, which moves every ``u_i`` of its ramp through its slope),
        are left out.  At most `SCALE_SAMPLE` ramps x (``n - 2``) are used (every k-th
        ramp); fewer than `SCALE_DOF`: None.

        Parameters
        ----------
        y : `numpy.ndarray`
            Reads ``(n, m)`` of ``m`` ramps (data unit), every read usable.
        sigma : float or `numpy.ndarray` of shape ``(m,)``
            Read noise given (data unit, one frame).
        gain : float or `numpy.ndarray` of shape ``(m,)``
            Electrons per data unit.

        Returns
        -------
        float or None
            The ramps' read-noise variance over ``sigma**2`` (dimensionless).

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce.reduce.steps.jumps.search import StepSearch
        >>> y = np.random.default_rng(2).normal(0.0, 12.0, (20, 4000))
        >>> round(StepSearch(np.arange(20.0)).scatter(y, 10.0), 1)  # (12 / 10)**2 = 1.44
        1.4
        """
        n, m = y.shape
        k = n - 2
        every = max(1, -(-m * k // SCALE_SAMPLE))
        take = slice(0, m, every)  # a view: one copy, to float64
        if -(-m // every) * k < SCALE_DOF:
            return None
        rel = np.array(y[:, take], np.float64)
        rel -= rel[0].copy()
        with np.errstate(invalid="ignore", over="ignore"):
            best, _ = self.screen(rel, False)
            s2 = np.broadcast_to(_take(sigma, take) ** 2, rel.shape[1:])
            slope = self.coef[1] @ rel
            lam = slope / _take(gain, take)
            shot = np.abs(lam) * self.diff_walk.max()
            ok = (np.isfinite(best) & np.isfinite(slope) & (best < SCALE_OUT_Z ** 2 * s2)
                  & (shot < SCALE_SHOT * self.diff_read.min() * s2))
            if np.count_nonzero(ok) * k < SCALE_DOF:
                return None
            if not ok.all():
                rel, slope, lam, s2 = rel[:, ok], slope[ok], lam[ok], s2[ok]
            u = np.diff(rel, axis=0)
            u -= self.dtau[:, None] * slope
            u *= u
            u -= self.diff_walk[:, None] * lam
            u /= self.diff_read[:, None] * s2
        return float(np.median(np.median(u, axis=1)) / _chi2_median(1))

    # -- search ------------------------------------------------------------------
    def find(self, y, *, threshold, sigma=None, gain=1.0, max_jumps=10, prior=None):
        """The jumps of ramps ``y`` (usable reads only), at most ``max_jumps`` each.

        Parameters
        ----------
        y : `numpy.ndarray`
            Reads ``(n, m)``: ``m`` ramps of the ``n`` reads of this search, in
            the data unit; float32 or float64 (not modified).
        threshold : float
            Smallest ``max |z|`` (sigma) that is a jump.
        sigma : float or `numpy.ndarray` of shape ``(m,)``, optional
            Read noise of one frame (data unit); None: from each ramp's own
            residuals.
        gain : float or `numpy.ndarray` of shape ``(m,)``
            Electrons per data unit (shot noise).
        max_jumps : int
            Steps searched for in each ramp.
        prior : `SlopePrior`, optional
            Test each step against a line whose slope has this prior (``sigma``
            needed): a ramp whose slope is off its expected one (`OWN_SIGMA`), or bright
            enough at its expected rate for shot-noise weights, keeps the free slope.

        Returns
        -------
        `Found`
            One entry per jump: ``pixel`` (column of ``y``), ``read`` (index
            into the reads of this search: the first read after the step),
            ``amplitude`` (data unit) and ``z`` (sigma); ``unsearched``: the
            ramps with a read that is not finite (not searched).
        """
        work = np.float64 if y.dtype == np.float64 else np.float32
        n, m = y.shape
        estimate = sigma is None
        if prior is not None and estimate:
            raise ValueError("a slope prior needs the read noise (sigma)")
        if estimate and n < 5:
            return Found.empty()
        with np.errstate(over="ignore"):  # a huge threshold squares to inf: no jump
            limit = np.square(np.float64(SCREEN_MARGIN * threshold))
        picked, floors, reads, unsearched = [], [], [], []
        width = max(256, SCREEN_BYTES // (n * np.dtype(work).itemsize))
        buf = np.empty((n, min(m, width)), work)  # reused: no page faults
        scratch = np.empty_like(buf)  # the screen's
        if prior is not None:  # the reads less the expected line, for the prior's screen
            buf_prior = np.empty_like(buf)
            buf_line = np.empty(buf.shape)  # the expected line, in float64
            brights, n_bright = [], 0  # ramps bright for shot weights: the slope free
        for lo in range(0, m, width):
            part = slice(lo, min(m, lo + width))
            y0 = np.asarray(y[0, part], work)
            rel = buf[:, :y0.size]
            np.subtract(y[:, part], y0, out=rel, casting="unsafe")  # exact for a pedestal
            with np.errstate(invalid="ignore", over="ignore"):  # non-finite ramps: set aside
                best, rss = self.screen(rel, estimate, scratch)
            floor = _floor(y0, rel)
            if estimate:
                var = np.maximum((rss - best) / (n - 3), floor)
            else:
                var = np.maximum(_take(sigma, part) ** 2, floor)
            finite = np.isfinite(best)
            if estimate:
                finite &= np.isfinite(rss)
            if not finite.all():
                unsearched.append(np.flatnonzero(~finite) + lo)
            with np.errstate(over="ignore"):  # limit * var: inf for a huge threshold
                over = ~(best <= limit * var)
                if prior is not None:  # either search may flag it
                    relp = buf_prior[:, :y0.size]
                    with np.errstate(invalid="ignore", over="ignore"):  # (absurd rates)
                        expected = _take(prior.slope, part)
                        line = buf_line[:, :y0.size]
                        np.multiply(self.tau[:, None], expected, out=line)
                        np.subtract(rel, line, out=relp, casting="unsafe")
                        bestp, _ = prior.search.screen(relp, False, scratch)
                        bright = np.broadcast_to(self._bright(expected, _take(gain, part),
                                                              var), finite.shape)
                    over |= ~(bestp <= limit * var)
                    n_bright += int(np.count_nonzero(finite & bright))
                keep = np.flatnonzero(finite & over)
            if keep.size:
                picked.append(keep + lo)
                floors.append(floor[keep])
                if prior is not None:
                    brights.append(bright[keep])
                reads.append(rel[:, keep].astype(np.float64))
        skipped = np.concatenate(unsearched) if unsearched else np.zeros(0, np.int64)
        if not picked:
            found = Found.empty(skipped)
            found.free = n_bright if prior is not None else 0
            return found
        pixels = np.concatenate(picked)
        sig = None if estimate else _take(sigma, pixels)
        args = (np.concatenate(reads, axis=1), pixels, threshold, sig, _take(gain, pixels),
                np.concatenate(floors), max_jumps)
        if prior is None:
            found = self._search(*args)
        else:
            found = self._with_prior(*args, prior, np.concatenate(brights))
            found.free += n_bright  # (those off the prior, and the bright ones)
        found.unsearched = skipped
        return _keep_a_segment(found, n)

    def _bright(self, expected, gain, var):
        """Whether ramps expected at ``expected`` (data unit / s; ``gain``, read-noise
        variance ``var``) are bright enough for shot-noise weights: searched with the
        slope free (a hot pixel's rate is seldom known to the few per cent its prior
        would need: a map 10-20 % off flagged 13-44 % of such ramps where the free
        search flags ~1 %)."""
        return _expected_lambda(expected, gain) / var * self.walk_top > SHOT_WEIGHTED

    def _with_prior(self, y, pixels, threshold, sigma, gain, floor, max_jumps, prior,
                    bright):
        """The float64 search of the screened ramps ``y`` (reads less the first) with the
        prior's expected slope, but for the ramps off it or bright enough at their expected
        rate for shot-noise weights, searched with the slope free."""
        ps = prior.search
        cols = np.arange(pixels.size)
        expected = np.broadcast_to(_take(prior.slope, pixels), (pixels.size,))
        ab, big_r, _ = self.step_sums(y)
        with np.errstate(over="ignore", invalid="ignore"):  # an absurd rate: searched free
            yp = y - expected * self.tau[:, None]
            _, big_rp, _ = ps.step_sums(yp)
            kp = np.argmax(big_rp ** 2 * ps._invq[:, None], axis=0)
        # the two-segment slope (slope free) at the prior search's best step
        amp = big_r[kp, cols] * self._invq[kp]
        slope = ab[1] - self.slope_of_step[kp] * amp
        var = np.maximum(np.square(sigma), floor)
        sos = self.slope_of_step[kp]
        # the two-segment slope's variance over the line's, its read noise and its shot
        # noise at the expected rate (a warm pixel's slope scatters by both)
        wide = 1.0 + sos * sos * self._invq[kp] / self.slope_var
        with np.errstate(over="ignore", invalid="ignore"):
            lam = _expected_lambda(expected, gain)
            spread = np.sqrt(wide * (var * self.slope_var + lam * self.shot_var)
                             + prior.spread ** 2)
            own = ~(np.abs(slope - expected) <= OWN_SIGMA * spread)
        free = int(np.count_nonzero(own & ~bright))  # (the bright ones: counted by `find`)
        own |= bright  # bright enough at the expected rate for shot weights (`_bright`)
        parts = []
        for search, sel, reads, offset in ((self, own, y, 0.0),
                                           (ps, ~own, yp, expected)):
            if sel.any():
                f = search._search(reads[:, sel], pixels[sel], threshold, _take(sigma, sel),
                                   _take(gain, sel), floor[sel], max_jumps,
                                   _take(offset, sel))
                parts.append((f.pixel, f.read, f.amplitude, f.z))
        out = Found.of(parts)
        out.free = free
        return out

    def _search(self, y, pixels, threshold, sigma, gain, floor, max_jumps, slope_offset=0.0):
        """The float64 search of the screened pixels: one step more at each round, fitted
        jointly with the steps already found (generalised least squares of a line plus
        steps, from the line's ``R_k`` and the matrices ``Q`` and ``S``); ``slope_offset``
        the slope taken out of the reads (a prior's), put back for the shot noise."""
        ab, big_r, rss = self.step_sums(y)
        state = _State(big_r, rss, ab[1] + slope_offset, np.zeros((pixels.size, 0), np.int64),
                       pixels, sigma, gain, floor)
        out = []
        if self.rho == 0:
            var, lam = self._noise(state)
            rho = lam / var
            shot = rho * self.walk_top > SHOT_WEIGHTED
            if shot.any():
                keep = ~shot
                where = np.flatnonzero(shot)
                if sigma is None:  # the RSS of a bright ramp holds its shot noise: not sigma
                    var[where] = np.maximum(self._differences_variance(y[:, where],
                                                                       lam[where]),
                                            floor[where])
                    rho[where] = lam[where] / var[where]
                bins = np.round(np.log10(rho[shot]) / RHO_BIN).astype(np.int64)
                for b in np.unique(bins):
                    sel = where[bins == b]
                    other = self.with_shot(10.0 ** (b * RHO_BIN))
                    found = other._search(y[:, sel], pixels[sel], threshold, np.sqrt(var[sel]),
                                          np.inf, floor[sel], max_jumps,
                                          _take(slope_offset, sel))
                    out.append((found.pixel, found.read, found.amplitude, found.z))
                state = state.take(keep, state.steps[keep])
        self._round(state, threshold, max_jumps, out)
        return Found.of(out)

    def _differences_variance(self, y, lam):
        """Read-noise variance of ramps ``y`` with shot noise ``lam`` from their first
        differences: ``Var(dy_i) = sigma**2 (f_i + f_(i-1)) + lam (W_ii + W_(i-1)(i-1) -
        2 W_i(i-1))``, the differences' spread taken robustly (the mean of the smallest
        90 % of their squares about their median, / 0.6230 for a Gaussian), so that a
        jump or two do not inflate it."""
        d = np.diff(y, axis=0)
        d -= np.median(d, axis=0)
        d *= d
        keep = max(1, int(0.9 * d.shape[0]))
        spread = np.partition(d, keep - 1, axis=0)[:keep].mean(axis=0) / _TRIMMED_90
        f, walk = self.factors, self.walk
        a = float(np.mean(f[1:] + f[:-1]))
        b = float(np.mean(np.diagonal(walk)[1:] + np.diagonal(walk)[:-1]
                          - 2 * np.diagonal(walk, 1)))
        return (spread - lam * b) / a

    def _noise(self, st):
        """Read-noise variance and shot noise (lambda) of each ramp of ``st``, from the
        line with its best step (the first round's)."""
        cols = np.arange(st.pixels.size)
        fit = _Given(self, st.big_r, st.steps)
        rq = fit.r ** 2 * self._invq[:, None]
        kb = self._best(rq, fit.r)
        if st.sigma is None:
            var = np.maximum((st.rss - rq[kb, cols]) / (self.n - 3), st.floor)
        else:
            var = np.maximum(st.sigma ** 2, st.floor)
        best = fit.r[kb, cols] * self._invq[kb]
        return var, self._rate(st, fit, kb, best, var, self.q[kb])

    def _rate(self, st, fit, kb, best, var, qb):
        """Shot noise (lambda) of ramps ``st``: the slope less the best step (at ``kb``,
        amplitude ``best``, its ``q`` ``qb``) less `SHOT_RATE_SIGMAS` of its read-noise
        sigma (``var`` the read-noise variance), clipped at 0, over the gain.  The sigma
        is the line's and that step's (a ramp with steps found already has a slightly
        larger one: this is a margin, not an estimate).  Ramps of at most
        `LINE_RATE_READS` reads with the read noise given and no slope prior take
        the line's slope, clipped at 0, in their first round."""
        if (self.n <= LINE_RATE_READS and not self.slope_precision and st.sigma is not None
                and not st.steps.shape[1]):
            # the line's slope, independent of the step statistic when there is no jump (the
            # first round only: a step found is not a false alarm any more; and with the read
            # noise given only: estimated from 5 reads, a jump's inflated rate sent the ramp
            # to the shot-weighted search, whose differences missed 3x the jumps)
            return np.maximum(st.slope, 0.0) / st.gain
        slope = st.slope - fit.slope_change(kb, best)
        sos = self.slope_of_step[kb]
        sigma = np.sqrt(var * (self.slope_var + sos * sos / qb))
        return np.maximum(slope - SHOT_RATE_SIGMAS * sigma, 0.0) / st.gain

    def _best(self, score, r):
        """The read of each ramp's best step: the largest ``score`` (``(n - 1, m)``).  On
        three reads with the slope free a step after the first read and one after the
        second leave the same residual (the line fits two of three points): the data say
        only that the ramp bends, and a positive step (a cosmic ray) bends it one way at
        the first and the other at the second, so the step whose amplitude (the sign of
        its ``R``, ``r``) is positive is taken, as the larger of the two differences
        is by two-point detection."""
        if self.n == 3 and not self.slope_precision:
            return (r[0] <= 0).astype(np.intp)
        return np.argmax(score, axis=0)

    def _round(self, st, threshold, max_jumps, out):
        """One more step in each ramp of ``st`` (a `_State`), then the next round for the
        ramps where one was found; ``out`` collects them."""
        n, j = self.n, st.steps.shape[1]
        # (no read left to test once the line and its steps fit every read; with sigma from
        # the ramp, 2 degrees of freedom at least for it: with 1, 5 reads split 37 % of the
        # ramps whose one jump had been found a second time)
        if (not st.pixels.size or j >= max_jumps or n - 2 - j <= 0
                or (st.sigma is None and n - 3 - j < 2)):
            return
        cols = np.arange(st.pixels.size)
        fit = _Given(self, st.big_r, st.steps)
        rk, qk, sk = fit.r, fit.q, fit.s
        r2 = rk ** 2
        if j:  # the reads of the steps found are no candidates (q = 0 there)
            valid = qk > 1e-9 * self.q[:, None]
            qk = np.where(valid, qk, np.inf)
            r2[~valid] = 0.0
        rq = r2 / qk
        kb = self._best(rq, rk)
        if st.sigma is None:
            var = np.maximum((st.rss - fit.explained - rq[kb, cols]) / (n - 3 - j), st.floor)
        else:
            var = np.maximum(st.sigma ** 2, st.floor)
        best = rk[kb, cols] / qk[kb, cols]
        lam = self._rate(st, fit, kb, best, var, qk[kb, cols])
        total = var * qk
        total += lam * sk
        z2 = np.divide(r2, total, out=total)
        k = self._best(z2, rk)
        peak = z2[k, cols]
        # log p-value of the best step (two-sided normal) against the threshold's
        logp = np.log(2.0) + log_ndtr(-np.sqrt(peak))
        limit = np.log(2.0) + log_ndtr(-threshold)
        pair = np.zeros(cols.size, bool)
        if self.partial.any() and n - 1 >= 2:
            pk, pchi, chis, cq = self._pairs(fit, rk, qk, sk, var, lam)
            pair = (-0.5 * pchi < logp) & (-0.5 * pchi <= limit)
        single = ~pair & (logp <= limit)
        for hit, is_pair in ((single, False), (pair, True)):
            if not hit.any():
                continue
            c = cols[hit]
            if is_pair:
                i = pk[hit]
                amp1, amp2 = _pair_amplitudes(rk[i, c], rk[i + 1, c], qk[i, c],
                                              qk[i + 1, c], cq[i, c])
                z = np.sqrt(pchi[hit])
                out.append((st.pixels[hit], i + 1, amp1, np.sign(amp1) * z))
                out.append((st.pixels[hit], i + 2, amp2, np.sign(amp2) * z))
                # a neighbouring pair that explains the ramp almost as well (the group
                # before or after may be the mixed one): isolate it too
                for side, read in ((i + 1, i + 3), (i - 1, i)):
                    inside = (side >= 0) & (side < chis.shape[0])
                    near = inside & (chis[np.clip(side, 0, chis.shape[0] - 1), c]
                                     >= pchi[hit] - PAIR_MARGIN)
                    if near.any():
                        # (no amplitude of its own; its z carries the pair's sign, for
                        # positive_only)
                        out.append((st.pixels[hit][near], read[near] + 0, np.zeros(near.sum()),
                                    (np.sign(amp1 + amp2) * z)[near]))
                new = np.column_stack([st.steps[hit], i, i + 1])
            else:
                kk = k[hit]
                amp = rk[kk, c] / qk[kk, c]
                z = np.sign(amp) * np.sqrt(peak[hit])
                out.append((st.pixels[hit], kk + 1, amp, z))
                if self.partial.any() and n - 1 >= 2:
                    mixed = self._mixed(kk, c, chis)
                    if mixed is not None:
                        at, read = mixed
                        out.append((st.pixels[hit][at], read, np.zeros(at.size), z[at]))
                new = np.column_stack([st.steps[hit], kk])
            self._round(st.take(hit, new), threshold, max_jumps, out)

    def _mixed(self, kk, c, chis):
        """The group a single step found at ``R`` row ``kk`` (read ``kk + 1``) of ramps
        ``c`` may have fallen inside: ``(positions among them, the other read to flag)``,
        or None.

        A jump between two frames of a group puts part of the step in that group: the
        read flagged (``kk + 1``) or the one before (``kk``), whichever averages several
        frames, and of two such the one whose pair of steps fits better (``chis``, the
        chi2 of every pair from `_pairs`).  Flagging the read after it (``kk + 2``) or
        before (``kk``) too makes it a segment of its own, which ``fit_ramp`` leaves
        out (not where no segment of two reads would be left): fitted with the step whole
        or with none, it moved the slope (+0.4 to +0.9 sigma0 on the 10-30 e steps found
        in 10 groups of 8 frames)."""
        last, n = chis.shape[0] - 1, self.n  # pair i isolates read i + 1
        # (either way a segment of two reads at least is left: the ramp keeps a slope)
        after = ((kk <= last) & self.partial[np.minimum(kk + 1, n - 1)]
                 & (np.maximum(kk + 1, n - kk - 2) >= 2))
        before = (kk >= 1) & self.partial[kk] & (np.maximum(kk, n - kk - 1) >= 2)
        if not (after | before).any():
            return None
        chi_after = np.where(after, chis[np.minimum(kk, last), c], -np.inf)
        chi_before = np.where(before, chis[np.clip(kk - 1, 0, last), c], -np.inf)
        at = np.flatnonzero(after | before)
        read = np.where(chi_after >= chi_before, kk + 2, kk)[at]
        return at, read

    def _pairs(self, fit, rk, qk, sk, var, lam):
        """The best pair of steps at reads ``i + 1`` and ``i + 2`` (a jump within the group
        of frames read ``i + 1`` averages) of each ramp: ``(i, its chi2 with 2 dof, the
        chi2 of every pair, Q of every pair)``."""
        cq, cs = fit.cross()
        with np.errstate(invalid="ignore", over="ignore"):  # a found step's q is inf
            d11 = var * qk[:-1] + lam * sk[:-1]
            d22 = var * qk[1:] + lam * sk[1:]
            d12 = var * cq + lam * cs
            det = d11 * d22 - d12 ** 2
            r1, r2 = rk[:-1], rk[1:]
            ok = (np.isfinite(d11) & np.isfinite(d22) & np.isfinite(det)
                  & (det > 1e-9 * d11 * d22) & self.partial[1:-1, None])
            det = np.where(ok, det, 1.0)
            chi = np.where(ok, (r1 ** 2 * d22 - 2 * r1 * r2 * d12 + r2 ** 2 * d11) / det, 0.0)
        i = np.argmax(chi, axis=0)
        return i, chi[i, np.arange(chi.shape[1])], chi, cq


class _Given:
    """``R_k``, ``q_k`` and ``s_k`` of a step at every read given the steps already found
    in each ramp (``steps``: ``(m, j)`` rows of R), by Frisch-Waugh: the line's ``R``
    less its projection on the found steps.

    Attributes ``r``, ``q``, ``s`` (``(n - 1, m)``) and ``explained`` (``(m,)``: the
    weighted sum of squares the found steps explain).
    """

    def __init__(self, search, big_r, steps):
        m, j = steps.shape
        if j == 0:
            self.r = big_r
            self.q = np.broadcast_to(search.q[:, None], big_r.shape)
            self.s = np.broadcast_to(search.s[:, None], big_r.shape)
            self.explained = 0.0
            self.found = self.a = self.steps = None
            self.sos, self.search = search.slope_of_step, search
            return
        cols = np.arange(m)[:, None]
        qf = search.qq[steps[:, :, None], steps[:, None, :]]  # (m, j, j)
        qk = search.qq[steps]  # (m, j, n - 1)
        rf = big_r[steps, cols]  # (m, j)
        if j == 1:  # most ramps with a jump have one: no batched solve
            a = qk / qf
            found = rf / qf[:, :, 0]
        else:
            a = np.linalg.solve(qf, qk)  # (m, j, n - 1)
            found = np.linalg.solve(qf, rf[..., None])[..., 0]  # joint amplitudes, (m, j)
        sk = search.ss[steps]
        sff = search.ss[steps[:, :, None], steps[:, None, :]]
        if j == 1:
            a1 = a[:, 0].T  # (n - 1, m)
            self.r = big_r - qk[:, 0].T * found[:, 0]
            self.q = search.q[:, None] - qk[:, 0].T * a1
            self.s = search.s[:, None] - a1 * (2 * sk[:, 0].T - a1 * sff[:, 0, 0])
        else:
            self.r = big_r - np.einsum("mjk,mj->km", qk, found)
            self.q = search.q[:, None] - np.einsum("mjk,mjk->km", qk, a)
            self.s = (search.s[:, None] - 2 * np.einsum("mjk,mjk->km", a, sk)
                      + np.einsum("mjk,mji,mik->km", a, sff, a))
        self.explained = np.einsum("mj,mj->m", rf, found)
        self.found, self.a, self.steps = found, a, steps
        self.qk, self.sk, self.sff = qk, sk, sff
        self.sos, self.search = search.slope_of_step, search

    def cross(self):
        """``Q`` and ``S`` of adjacent steps (``k``, ``k + 1``) given the steps found,
        ``(n - 2, m)`` each."""
        qq, ss = self.search.qq, self.search.ss
        cq0, cs0 = np.diagonal(qq, 1)[:, None], np.diagonal(ss, 1)[:, None]
        if self.found is None:
            m = self.r.shape[1]
            return np.broadcast_to(cq0, (cq0.shape[0], m)), np.broadcast_to(cs0, (cs0.shape[0], m))
        a, qk, sk = self.a, self.qk, self.sk
        cq = cq0 - np.einsum("mjk,mjk->km", qk[:, :, :-1], a[:, :, 1:])
        cs = (cs0 - np.einsum("mjk,mjk->km", a[:, :, :-1], sk[:, :, 1:])
              - np.einsum("mjk,mjk->km", a[:, :, 1:], sk[:, :, :-1])
              + np.einsum("mjk,mji,mik->km", a[:, :, :-1], self.sff, a[:, :, 1:]))
        return cq, cs

    def slope_change(self, k, amp):
        """How much the found steps and a step ``amp`` at ``k`` change each line's slope."""
        change = amp * self.sos[k]
        if self.found is not None:
            m = np.arange(k.size)
            joint = self.found - self.a[m, :, k] * amp[:, None]
            change = change + np.einsum("mj,mj->m", joint, self.sos[self.steps])
        return change


@dataclass(frozen=True)
class _State:
    """The ramps of a round of the float64 search: their line's ``R`` (``(n - 1, m)``),
    weighted RSS and slope, the rows of R of their steps found ``(m, j)``, their pixels
    (indices of the caller's columns), read noise (or None), gain and variance floor."""

    big_r: np.ndarray
    rss: np.ndarray
    slope: np.ndarray
    steps: np.ndarray
    pixels: np.ndarray
    sigma: object
    gain: object
    floor: np.ndarray

    def take(self, hit, steps):
        """The ramps ``hit``, with ``steps``."""
        return replace(self, big_r=self.big_r[:, hit], rss=self.rss[hit],
                       slope=self.slope[hit], steps=steps, pixels=self.pixels[hit],
                       sigma=None if self.sigma is None else _take(self.sigma, hit),
                       gain=_take(self.gain, hit), floor=self.floor[hit])


def _keep_a_segment(found, n):
    """``found`` less the flags without a step of their own (amplitude 0: beside a step, to
    leave a group out, `StepSearch._mixed`, or a pair's neighbour) where they would leave a
    ramp of ``n`` reads no segment of two reads, the latest first: the ramp keeps a slope
    (each such flag is checked against its own step only, not against the ramp's others)."""
    zero = found.amplitude == 0
    if not zero.any():
        return found
    idx = np.flatnonzero(np.isin(found.pixel, found.pixel[zero]))
    idx = idx[np.lexsort((found.read[idx], found.pixel[idx]))]
    p, r = found.pixel[idx], found.read[idx]
    first = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    bounds = np.r_[first, idx.size]

    def longest(reads):  # the longest segment the flags at ``reads`` (sorted) leave
        return int(np.diff(np.r_[0, reads, n]).max())

    before = np.where(np.r_[True, p[1:] != p[:-1]], 0, np.r_[0, r[:-1]])
    after = np.r_[r[1:], n]
    after[bounds[1:] - 1] = n
    short = np.maximum.reduceat(np.maximum(r - before, after - r), first) < 2
    drop = []
    for lo, hi in zip(bounds[:-1][short], bounds[1:][short], strict=True):
        mine = idx[lo:hi]  # this ramp's flags, in read order
        left = np.ones(mine.size, bool)
        for q in range(mine.size - 1, -1, -1):
            if found.amplitude[mine[q]] != 0:
                continue
            left[q] = False
            drop.append(mine[q])
            if longest(found.read[mine[left]]) >= 2:
                break
    if not drop:
        return found
    keep = np.ones(len(found), bool)
    keep[drop] = False
    out = Found(found.pixel[keep], found.read[keep], found.amplitude[keep], found.z[keep],
                found.unsearched)
    out.free = found.free
    return out


def _expected_lambda(expected, gain):
    """The shot noise (lambda) of ramps expected at ``expected`` (data unit / s)."""
    return np.maximum(expected, 0.0) / gain


@functools.lru_cache(maxsize=64)
def _chi2_median(k):
    """The median of the chi-squared distribution of ``k`` degrees of freedom."""
    return float(chdtri(k, 0.5))  # the chi2_k median (its survival function's inverse at 1/2)


def _pair_amplitudes(r1, r2, q11, q22, q12):
    """Joint amplitudes of two steps from their ``R`` and ``Q`` (read-noise metric)."""
    det = q11 * q22 - q12 ** 2
    return (r1 * q22 - r2 * q12) / det, (r2 * q11 - r1 * q12) / det


def _floor(y0, rel):
    """Smallest read-noise variance of ramps with first reads ``y0`` and the others ``rel``
    above them: the float32 resolution of their values."""
    top = np.abs(y0).astype(np.float64) + np.abs(rel[-1])
    return (np.finfo(np.float32).eps * top) ** 2


def _take(values, index):
    """``values[index]`` for a per-pixel array, ``values`` for one number."""
    values = np.asarray(values, np.float64)
    return values if values.ndim == 0 else values[index]


class Found:
    """Jumps found: parallel arrays ``pixel``, ``read``, ``amplitude``, ``z``;
    ``unsearched``, the ramps not searched (a read not finite); and ``free``, how many
    ramps a search with a slope prior searched with the slope free instead."""

    __slots__ = ("amplitude", "free", "pixel", "read", "unsearched", "z")

    def __init__(self, pixel, read, amplitude, z, unsearched=None):
        self.pixel, self.read, self.amplitude, self.z = pixel, read, amplitude, z
        self.unsearched = np.zeros(0, np.int64) if unsearched is None else unsearched
        self.free = 0

    @classmethod
    def empty(cls, unsearched=None):
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0),
                   unsearched)

    @classmethod
    def of(cls, parts):
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate(p) for p in zip(*parts, strict=True)))

    def __len__(self):
        return self.pixel.size


def cached_search(times, factors, walk, slope_precision=0.0):
    """The `StepSearch` of reads at ``times`` (s) with read-noise ``factors``, charge
    covariance ``walk`` and ``slope_precision``, made once per process: its matrices depend
    on nothing else (``detect_jumps`` asks for one per set of usable reads and, with
    ``expected_rate``, per bin of the prior's weight)."""
    return _cached_search(np.ascontiguousarray(times, np.float64).tobytes(),
                          np.ascontiguousarray(factors, np.float64).tobytes(),
                          np.ascontiguousarray(walk, np.float64).tobytes(),
                          float(slope_precision))


@functools.lru_cache(maxsize=256)
def _cached_search(times, factors, walk, slope_precision):
    n = len(times) // 8
    return StepSearch(np.frombuffer(times), np.frombuffer(factors),
                      np.frombuffer(walk).reshape(n, n), slope_precision=slope_precision)
