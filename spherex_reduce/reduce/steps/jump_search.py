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
does not inflate it), ``sigma`` from the read-noise map or, when none is
given, from the pixel's own residuals about the line with the best step
(``(RSS - R_k**2 / q_k) / (n - 3)``, which a jump does not inflate either).

`StepSearch.find` first screens every pixel with float32 cumulative sums over
the reads (a loop over reads on a few thousand pixels at a time, in cache):
with read noise alone ``z`` can only be larger, so pixels whose read-noise
``max z`` is below the threshold have no jump.  The few left are searched in
float64 with the full noise model.  Each pixel's result depends on its own
reads only.
"""

import numpy as np

__all__ = ["SCREEN_MARGIN", "Found", "StepSearch"]

#: the float32 screen keeps pixels down to this fraction of the threshold, so that its
#: rounding never drops a pixel the float64 search would flag
SCREEN_MARGIN = 0.98
#: bytes of reads screened at once (in cache: larger work areas run several times slower)
SCREEN_BYTES = 3 << 18


class StepSearch:
    """The step search for ramps read at ``times``: its matrices, computed once.

    Parameters
    ----------
    times : array_like
        Times of the usable reads (s), increasing, at least 4.
    factors : array_like, optional
        Read-noise variance of each read relative to one frame's (default 1 for
        every read; a group that averages ``n`` frames has ``1/n``).

    Examples
    --------
    A dark ramp of 20 reads (read noise 1, 0.01 per second) with a step of 8 at read 12:

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.jump_search import StepSearch
    >>> t = np.arange(20.0)
    >>> y = (100 + 0.01 * t + 8.0 * (t >= 12) + np.random.default_rng(1).normal(0, 1, 20))[:, None]
    >>> found = StepSearch(t).find(y, threshold=5.0, sigma=1.0)
    >>> found.read.tolist(), found.pixel.tolist(), round(float(found.amplitude[0]), 1)
    ([12], [0], 7.5)
    """

    def __init__(self, times, factors=None):
        t = np.asarray(times, np.float64)
        n = t.size
        if n < 4:
            raise ValueError(f"a step search needs at least 4 reads, got {n}")
        tau = t - t[0]
        f = np.ones(n) if factors is None else np.asarray(factors, np.float64)
        w = 1.0 / f
        x = np.column_stack([np.ones(n), tau])
        xtw = x.T * w
        coef = np.linalg.solve(xtw @ x, xtw)  # (2, n): intercept and slope of y
        wm = np.diag(w) - xtw.T @ coef  # W M, symmetric
        h = (np.arange(n)[None, :] >= np.arange(1, n)[:, None]).astype(np.float64)
        g = h @ wm  # R_k = g[k - 1] @ y for a step at read k
        self.n, self.tau, self.w = n, tau, w
        self.coef = coef
        self.q = np.einsum("ki,ki->k", g, h)  # read-noise variance of R_k / sigma**2
        walk = np.minimum.outer(tau, tau)
        self.s = np.einsum("ki,ij,kj->k", g, walk, g)  # shot-noise variance / lambda
        self.slope_of_step = (coef @ h.T)[1]  # change of the line's slope per unit step
        self.qq = g @ h.T  # Q[k, l] = h_k' W M h_l: q is its diagonal
        self.ss = g @ walk @ g.T  # the random walk's covariance of R: s is its diagonal
        self.uniform_w = bool(np.all(w == w[0]))
        d = np.diff(tau)
        self.dtau = d
        self.uniform_dt = bool(np.all(d == d[0]))
        self._types = {}  # dtype -> (w, 1 / q, coef) in it
        self._invq = 1.0 / self.q

    # -- screen ------------------------------------------------------------------
    def _typed(self, dtype):
        """Weights and ``1 / q`` in ``dtype`` (made once per type)."""
        typed = self._types.get(dtype)
        if typed is None:
            typed = self._types[dtype] = (self.w.astype(dtype), self._invq.astype(dtype),
                                          self.coef.astype(dtype))
        return typed

    def _screen(self, y, estimate):
        """``max_k R_k**2 / q_k`` and the weighted RSS of the line (or None), in ``y``'s type."""
        n, m = y.shape
        w, invq, coef = self._typed(y.dtype)
        ab = coef @ y
        a, b = ab[0], ab[1]
        c = a.copy()
        acc = np.zeros(m, y.dtype)
        best = np.zeros(m, y.dtype)
        rss = np.zeros(m, y.dtype) if estimate else None
        r = np.empty(m, y.dtype)
        tmp = np.empty(m, y.dtype)
        step = b * y.dtype.type(self.dtau[0]) if self.uniform_dt else None
        for i in range(n):
            if i:
                if step is not None:
                    c += step
                else:
                    np.multiply(b, w.dtype.type(self.dtau[i - 1]), out=tmp)
                    c += tmp
            np.subtract(y[i], c, out=r)
            if estimate:
                np.multiply(r, r, out=tmp)
                if not self.uniform_w:
                    tmp *= w[i]
                rss += tmp
            if i == n - 1:
                break
            if not self.uniform_w:
                r *= w[i]
            acc += r
            np.multiply(acc, acc, out=tmp)
            tmp *= invq[i]
            np.maximum(best, tmp, out=best)
        return best, rss

    # -- search ------------------------------------------------------------------
    def find(self, y, *, threshold, sigma=None, gain=1.0, max_jumps=10):
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
        if estimate and n < 5:
            return Found.empty()
        limit = (SCREEN_MARGIN * threshold) ** 2
        picked, floors, reads, unsearched = [], [], [], []
        width = max(256, SCREEN_BYTES // (n * np.dtype(work).itemsize))
        buf = np.empty((n, min(m, width)), work)  # reused: no page faults
        for lo in range(0, m, width):
            part = slice(lo, min(m, lo + width))
            y0 = np.asarray(y[0, part], work)
            rel = buf[:, :y0.size]
            np.subtract(y[:, part], y0, out=rel, casting="unsafe")  # exact for a pedestal
            best, rss = self._screen(rel, estimate)
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
            keep = np.flatnonzero(finite & ~(best <= limit * var))
            if keep.size:
                picked.append(keep + lo)
                floors.append(floor[keep])
                reads.append(rel[:, keep].astype(np.float64))
        skipped = np.concatenate(unsearched) if unsearched else np.zeros(0, np.int64)
        if not picked:
            return Found.empty(skipped)
        pixels = np.concatenate(picked)
        sig = None if estimate else _take(sigma, pixels)
        found = self._search(np.concatenate(reads, axis=1), pixels, threshold, sig,
                             _take(gain, pixels), np.concatenate(floors), max_jumps)
        found.unsearched = skipped
        return found

    def _search(self, y, pixels, threshold, sigma, gain, floor, max_jumps):
        """The float64 search of the screened pixels: one step more at each round, fitted
        jointly with the steps already found (generalised least squares of a line plus
        steps, from the line's ``R_k`` and the matrices ``Q`` and ``S``)."""
        n = self.n
        ab = np.einsum("ci,im->cm", self.coef, y)
        r = y - ab[0] - ab[1] * self.tau[:, None]
        wr = r * self.w[:, None]
        big_r = np.cumsum(wr[:0:-1], axis=0)[::-1]  # (n - 1, m): R_k, tail sums
        rss = np.einsum("im,im->m", wr, r)
        slope = ab[1]
        steps = np.zeros((pixels.size, 0), np.int64)  # rows of R of the steps found
        out = []
        while pixels.size and steps.shape[1] < max_jumps:
            j = steps.shape[1]
            if sigma is None and n - 4 - j < 0:
                break
            cols = np.arange(pixels.size)
            fit = _Given(self, big_r, steps)
            rk, qk, sk = fit.r, fit.q, fit.s
            r2 = rk ** 2
            if j:  # the reads of the steps found are no candidates (q = 0 there)
                valid = qk > 1e-9 * self.q[:, None]
                qk = np.where(valid, qk, np.inf)
                r2[~valid] = 0.0
            rq = r2 / qk
            kb = np.argmax(rq, axis=0)
            if sigma is None:
                var = np.maximum((rss - fit.explained - rq[kb, cols]) / (n - 3 - j), floor)
            else:
                var = np.maximum(sigma ** 2, floor)
            best = rk[kb, cols] / qk[kb, cols]
            lam = np.maximum(slope - fit.slope_change(kb, best), 0.0) / gain
            total = var * qk
            total += lam * sk
            z2 = np.divide(r2, total, out=total)
            k = np.argmax(z2, axis=0)
            peak = z2[k, cols]
            hit = peak > threshold ** 2
            if not hit.any():
                break
            k, cols = k[hit], cols[hit]
            amp = rk[k, cols] / qk[k, cols]
            out.append((pixels[hit], k + 1, amp, np.sign(amp) * np.sqrt(peak[hit])))
            steps = np.column_stack([steps[hit], k])
            big_r, rss, slope = big_r[:, hit], rss[hit], slope[hit]
            pixels, gain, floor = pixels[hit], _take(gain, hit), floor[hit]
            sigma = None if sigma is None else _take(sigma, hit)
        return Found.of(out)


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
            self.sos = search.slope_of_step
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
        self.sos = search.slope_of_step

    def slope_change(self, k, amp):
        """How much the found steps and a step ``amp`` at ``k`` change each line's slope."""
        change = amp * self.sos[k]
        if self.found is not None:
            m = np.arange(k.size)
            joint = self.found - self.a[m, :, k] * amp[:, None]
            change = change + np.einsum("mj,mj->m", joint, self.sos[self.steps])
        return change


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
    """Jumps found: parallel arrays ``pixel``, ``read``, ``amplitude``, ``z``; and
    ``unsearched``, the ramps not searched (a read not finite)."""

    __slots__ = ("amplitude", "pixel", "read", "unsearched", "z")

    def __init__(self, pixel, read, amplitude, z, unsearched=None):
        self.pixel, self.read, self.amplitude, self.z = pixel, read, amplitude, z
        self.unsearched = np.zeros(0, np.int64) if unsearched is None else unsearched

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
