"""How the noise engine draws a slope image: the choice of route, and the exact route.

`SlopeRoutes.slopes` draws the image by the route `SlopeRoutes.slope_route`
names: ``'tiered'`` (the synthesised tiers of `spherex_reduce.simulation.engine`)
or ``'exact'``.

Small scenes take another route in slope mode (``slope_route='exact'``, chosen
by cost): the slopes of a stream at the samples a frame reads form a Gaussian
vector whose covariance is known exactly from the structure function
(`~spherex_reduce.simulation.slope_covariance`), so only the pixels and
phantom means asked for are drawn, exactly, by a block Durbin-Levinson
recursion over the reads (one per scope, shared by every channel's stream).
Its cost follows the pixels per channel read, not the samples of the frame
with its overheads, and its statistics are the analytic, aperiodic ones (no
tiers, no padding).
"""

import collections
import math
import threading

import numpy as np
import scipy.fft as sfft

from ..core import limits
from ..noise.variance import slope_covariance
from .streams import _SCOPE, TIER_EXACT
from .synthesis import rng_for

__all__ = ["SlopeRoutes"]

#: Factors of the exact slope route, by scene timing and components (least recent first):
#: ``key -> (factors, nbytes)``, at most `SlopeRoutes.EXACT_CACHE_BYTES` in all.
_EXACT_FACTORS = collections.OrderedDict()
_EXACT_LOCK = threading.Lock()


class SlopeRoutes:
    """The slope routes of `~spherex_reduce.simulation.NoiseEngine`.

    A mixin: it uses the engine's layout and tiers.

    `slope_route` chooses between the routes by their costs (``_exact_cost``,
    ``_tiered_cost``) and the exact route's memory (``_exact_memory``);
    `slopes` draws by the route chosen: ``_exact_slopes`` here, or the
    engine's ``_tiered_slopes``.
    """

    #: The exact route draws at most this many values per stream jointly (its predictors
    #: hold half this number squared float64 values).
    EXACT_MAX = 6144

    SLOPE_ROUTES = ("exact", "tiered")

    def _tiered_cost(self):
        """Rough operation count of the tiered route in slope mode (FFT synthesis)."""
        def fft(m, ns=1):
            return ns * m * (5 * math.log2(max(m, 2)) + 30)

        _, ma, _, mb = self._slow_sizes()
        ops = sum(fft(ma, gr.nstreams) + fft(mb, gr.nstreams) for gr in self.slow_groups)
        nfast = sum(self.nch if scope == "channel" else 1 for scope in self._fast_psds("pixels"))
        if self.block == 1:  # one frame-length stream (the frames' fast tiers are independent)
            ops += fft(self._block_fft_len(), nfast)
        else:  # the ramps' blocks, fitted
            ops += math.ceil(self.N / self.block) * fft(self._block_fft_len(), nfast)
            ops += 4.0 * self.N * self.n_reads * self.ncols
        if self.c:
            g_lag = math.ceil(2 * self.l_corr / self.rs) + 2
            m = sfft.next_fast_len(max(4 * (g_lag * self.rs + self.c), 8 * self.l_corr, 1024))
            ops += 2 * len(self._fast_psds("phantom")) * fft(m)
            ops += fft(self.exposure // self.rs + 2 * g_lag, self.nch + 1)
        return ops

    @property
    def slope_route(self):
        """``'exact'`` or ``'tiered'``: how `slopes` draws the image.

        By default the route with the smaller operation count (``_exact_cost``
        against ``_tiered_cost``): the exact route for few pixels per channel
        (its cost grows as ``reads² × (width + 1)³``), the tiered one for large
        arrays (its cost grows with the samples of a frame, overheads included),
        but never the exact route if its memory (``_exact_memory``, mostly its
        predictors: ``(reads × (width + 1))² / 2`` float64 values per scope)
        exceeds `~spherex_reduce.core.limits.memory_budget`.  The
        random-phase method and paddings below the default keep the tiered
        synthesis, whose periodicity they are there to reproduce.
        """
        if self._slope_route is not None:
            return self._slope_route
        if self.method != "gaussian" or self.padding < 16 or self.N < 2:
            return "tiered"
        cost, biggest = self._exact_cost()
        if biggest > self.EXACT_MAX or cost >= self._tiered_cost():
            return "tiered"
        # never a route this process cannot hold (a dask worker's memory limit, say)
        return "exact" if self._exact_memory() <= limits.memory_budget() else "tiered"

    # -- slopes ----------------------------------------------------------------------------
    def slopes(self):
        """Slope image ``(n_reads, ncols)`` (e/s) and phantom slopes ``(n_reads, nch)``.

        Drawn by the route `slope_route` names; both have the statistics of
        the least-squares fit of the frames (the exact route exactly, the
        tiered one up to the approximations `expected_slope_variance` measures).
        """
        route = self.slope_route
        if route == "exact":
            biggest = self._exact_cost()[1]
            if biggest > self.EXACT_MAX:
                raise ValueError(f"slope_route='exact' would draw {biggest} samples per stream "
                                 f"jointly (at most {self.EXACT_MAX}); use the tiered route")
            limits.check_size(self._exact_memory(), "the exact slope route's factors")
            return self._exact_slopes()
        return self._tiered_slopes()

    def _exact_points(self, scope):
        """Positions (samples after a read's first pixel) that the streams of ``scope`` must
        give: ``(pixel positions, phantom positions)``, each empty if no component of that
        scope is seen there.

        Pixels at ``0 ... width - 1`` (the offset of their column in the read), phantom
        samples at ``-c ... -1``.
        """
        comps = [c for c in self.components if c.scope == scope]
        pix = np.arange(self.width if any(c.seen_by_pixels for c in comps) else 0)
        ph = np.arange(-self.c if any(c.seen_by_phantom for c in comps) else 0, 0)
        return pix, ph

    def _exact_cost(self):
        """Rough operation count of the exact route, and its largest joint draw."""
        nr, span = self.n_reads, self.c + self.width
        nbasis = len({key for c in self.components for key, coef in
                      (("alpha", c.alpha), ("beta", c.beta), (c.exponent, c.gamma)) if coef})
        ops = 100.0 * nbasis * nr * (2 * span - 1) * (2 * self.N - 1)
        biggest = 0
        for scope in ("channel", "common"):
            pix, ph = self._exact_points(scope)
            ns = self.nch if scope == "channel" else 1
            k = pix.size + (1 if ph.size else 0)
            biggest = max(biggest, nr * k)
            # Levinson recursion and draws (k x k blocks), covariance tables, per-step overhead
            # (numpy loops over small blocks: ~10 operations' time per multiply-add)
            ops += (10.0 * nr * nr * (k**3 + k * k * ns) + 2e5 * nr * (k > 0)
                    + 2.0 * nr * (pix.size + ph.size) ** 2 * len(self.components))
        return ops, biggest

    def _exact_memory(self):
        """Bytes the exact route allocates at its peak (an upper estimate).

        Its predictors hold ``k² R (R + 1) / 2`` float64 values per scope
        (``R`` reads of ``k`` values: about ``(R k)² / 2``, 151 MB at
        `EXACT_MAX`), kept while the scene is cached; making them takes the
        covariance tables of every lag (the structure functions of ``2 N - 1``
        frame lags at ``R (2 span - 1)`` sample lags, with their temporaries)
        and the ``R`` blocks of covariance of each scope's samples.
        """
        nr, span = self.n_reads, self.c + self.width
        tables = 20 * (2 * self.N - 1) * nr * (2 * span - 1)
        total = (len(self.components) + 1) * nr * (2 * span - 1)
        for scope in ("channel", "common"):
            pix, ph = self._exact_points(scope)
            q = pix.size + ph.size
            k = pix.size + (1 if ph.size else 0)
            ns = self.nch if scope == "channel" else 1
            total += k * k * (nr * (nr + 1) // 2 + 4 * nr) + 3 * nr * q * q + 3 * nr * k * ns
        return 8 * (total + tables)

    # -- slopes: exact route ---------------------------------------------------------------
    def _exact_factors(self):
        """``{scope: (_BlockLevinson, pixel positions, phantom positions)}`` of the exact route.

        Every stream of a scope (one per channel, or the common one) is drawn
        as one Gaussian vector: the slopes at its pixel positions of every
        read and the phantom mean of every read, a stationary sequence over
        the reads.  Its covariance sums the
        components of that scope: each seen only by the samples its
        visibility names, and with ACN only between samples of the same
        parity (independent even and odd realisations: column parity, and
        ``(i - c) % 2`` for phantom sample ``i``, as in the tiers).  Cached
        by the schedule's timing and the components (at most
        `EXACT_CACHE_BYTES` in all, least recently used dropped first), so
        further realisations of a scene only draw.
        """
        key = (self.N, self.F, self.fs, self.rs, self.n_reads, self.c, self.width,
               tuple(self.components))
        with _EXACT_LOCK:
            if key in _EXACT_FACTORS:
                _EXACT_FACTORS.move_to_end(key)
                return _EXACT_FACTORS[key][0]
        nr, c, w = self.n_reads, self.c, self.width
        span = c + w
        # slope covariance of one stream at lags dr * row_samples + dq (dr >= 0)
        lags = np.abs(np.arange(nr)[:, None] * self.rs + np.arange(-(span - 1), span)[None, :])
        cov = slope_covariance(self.components, self.schedule, lags)
        factors = {}
        for scope in ("channel", "common"):
            pix, phq = self._exact_points(scope)
            q = np.concatenate([pix, phq])
            if q.size == 0:
                continue
            is_pix = np.arange(q.size) < pix.size
            same_parity = (q[:, None] % 2) == (q[None, :] % 2)
            # covariance of the samples of read r + h with those of read r: (nr, k, k)
            index = (np.arange(nr)[:, None, None], (q[:, None] - q[None, :])[None] + span - 1)
            t = np.zeros((nr, q.size, q.size))
            for i, comp in enumerate(self.components):
                if comp.scope != scope:
                    continue
                seen = is_pix if comp.visibility == "pixels" else (
                    ~is_pix if comp.visibility == "phantom" else np.ones(q.size, bool))
                mask = seen[:, None] & seen[None, :]
                if comp.acn:
                    mask &= same_parity
                t += cov[i][index] * mask
            # variables of one read: its pixels, then the mean of its phantom samples
            wmat = np.eye(pix.size, q.size)
            if phq.size:
                wmat = np.vstack([wmat, np.r_[np.zeros(pix.size), np.full(phq.size, 1 / c)]])
            factors[scope] = (_BlockLevinson(wmat @ t @ wmat.T), pix, phq)
        nbytes = sum(plan.nbytes + pix.nbytes + phq.nbytes
                     for plan, pix, phq in factors.values())
        bound = self.EXACT_CACHE_BYTES
        with _EXACT_LOCK:
            _EXACT_FACTORS.pop(key, None)
            if nbytes <= bound:  # a larger entry is used, not kept
                _EXACT_FACTORS[key] = (factors, nbytes)
                while sum(n for _, n in _EXACT_FACTORS.values()) > bound:
                    _EXACT_FACTORS.popitem(last=False)
        return factors

    #: Bytes of exact-route factors kept for further realisations, all scenes together.  A
    #: scene's predictors hold about ``(reads × k)² / 2`` float64 values per scope (two
    #: scopes): 1.6 MB for 64 × 64 pixels in 16 channels, 79 MB for 1024 rows of 2 columns
    #: per channel, up to 151 MB per scope at `EXACT_MAX`.  A scene needing more is drawn but
    #: not kept.
    EXACT_CACHE_BYTES = 256 * 2**20

    def _exact_slopes(self):
        """Slopes of every stream drawn at the samples read, from their exact covariance."""
        nr, nch = self.n_reads, self.nch
        out = np.zeros((nr, self.ncols), dtype=self.dtype)
        ph = np.zeros((nr, nch)) if self.c else None
        for scope, (plan, pix, phq) in self._exact_factors().items():
            ns = nch if scope == "channel" else 1
            rng = rng_for(self.entropy, TIER_EXACT, _SCOPE[scope])
            v = plan.draw(rng.standard_normal((nr, plan.k, ns)))
            if pix.size:
                st = self.col_chan if ns > 1 else np.zeros(self.ncols, dtype=int)
                out += v[:, self.col_off, st].astype(self.dtype)
            if phq.size:
                ph += v[:, -1, :]
        return out, ph


class _BlockLevinson:
    """Exact draws of a stationary sequence of vectors ``v_0 ... v_{R-1}`` (``k`` values each).

    ``gam[h] = Cov(v_{r+h}, v_r)``, ``h = 0 ... R - 1``, shape ``(R, k, k)``.  The
    multivariate Durbin-Levinson recursion (Whittle 1963; Brockwell & Davis,
    *Time Series: Theory and Methods*, Prop. 11.4.1) gives the best linear
    predictor ``sum_j Phi_{n,j} v_{n-j}`` of each vector from the ones before and
    the covariance ``V_n`` of its error, so ``v_n = prediction + chol(V_n) z_n``
    has exactly the covariance asked for.  It costs ``R^2 k^3`` in small ``k x k``
    products (never a large matrix: no threaded BLAS calls, which stall on a
    busy machine), against ``R^3 k^3 / 3`` for the Cholesky factor of the whole.
    """

    def __init__(self, gam):
        gam = np.asarray(gam, dtype=float)
        nr, k, _ = gam.shape
        self.k = k
        fwd = bwd = gam[0]
        phi = psi = np.zeros((0, k, k))
        self.pred = [np.zeros((k, 0))]  # [Phi_{n,1} ... Phi_{n,n}] as (k, n k)
        self.innov = [_small_factor(fwd)]
        for n in range(1, nr):
            # delta = gam[n] - sum_j Phi_{n-1,j} gam[n-j]
            delta = gam[n] - self.pred[-1] @ gam[n - 1:0:-1].reshape((n - 1) * k, k)
            a = np.linalg.solve(bwd.T, delta.T).T  # Phi_{n,n} = delta U^-1
            b = np.linalg.solve(fwd.T, delta).T  # Psi_{n,n} = delta^T V^-1
            phi, psi = (np.concatenate([phi - a @ psi[::-1], a[None]]),
                        np.concatenate([psi - b @ phi[::-1], b[None]]))
            fwd, bwd = fwd - a @ delta.T, bwd - b @ delta
            self.pred.append(phi.transpose(1, 0, 2).reshape(k, n * k))
            self.innov.append(_small_factor(fwd))

    @property
    def nbytes(self):
        """Bytes held by the predictors and innovation factors."""
        return sum(a.nbytes for a in self.pred) + sum(a.nbytes for a in self.innov)

    def draw(self, z):
        """The sequence ``(R, k, ns)`` from standard normals ``z`` of that shape."""
        v = np.empty_like(z, dtype=float)
        for n, (pred, innov) in enumerate(zip(self.pred, self.innov, strict=True)):
            v[n] = innov @ z[n]
            if n:
                v[n] += pred @ v[n - 1::-1].reshape(n * self.k, -1)
        return v


def _small_factor(cov):
    """``L`` with ``L @ L.T = cov``: Cholesky, or eigenvectors if ``cov`` is singular."""
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        val, vec = np.linalg.eigh((cov + cov.T) / 2)
        return vec * np.sqrt(np.clip(val, 0, None))
