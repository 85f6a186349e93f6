"""The exact slope route: slopes drawn at the samples read, from their exact covariance.

The slopes of a stream at the samples a frame reads form a Gaussian vector
whose covariance is known exactly from the structure function
(`~spherex_reduce.simulation.slope_covariance`), so only the pixels and
phantom means asked for are drawn, exactly, by a block Durbin-Levinson
recursion over the reads (one per scope, shared by every channel's stream).
Its cost follows the pixels per channel read, not the samples of the frame
with its overheads, and its statistics are the analytic, aperiodic ones (no
tiers, no padding).  `~spherex_reduce.simulation.NoiseEngine` takes this
route for small scenes (see its ``slope_route``).
"""

import collections
import threading

import numpy as np

from ..core import limits
from ..noise.variance import slope_covariance
from .streams import STREAM_SCOPES, TIER_EXACT
from .synthesis import rng_for

__all__ = ["ExactSlopes"]

#: Factors of the exact slope route, by scene timing and components (least recent first):
#: ``key -> (factors, nbytes)``, at most `ExactSlopes.CACHE_BYTES` in all.
_EXACT_FACTORS = collections.OrderedDict()
_EXACT_LOCK = threading.Lock()


class ExactSlopes:
    """The slope image of a schedule's noise, drawn exactly at the samples read.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    components : sequence of `~spherex_reduce.simulation.NoiseComponent`
        The non-zero components (phantom-only ones dropped when ``c = 0``).
    entropy : tuple
        ``(entropy, spawn_key)`` of the simulation's seed.
    dtype : numpy dtype
        dtype of the slope image.

    `cost` and `memory` say what `draw` would take; `factors` are the
    predictors of each scope, cached for further realisations.

    Examples
    --------
    >>> from spherex_reduce.io.examples import tiny_schedule
    >>> from spherex_reduce.simulation import NoiseComponent
    >>> from spherex_reduce.simulation.exact_slopes import ExactSlopes
    >>> exact = ExactSlopes(tiny_schedule(), [NoiseComponent("w", alpha=2e-3)], (1, ()),
    ...                     "float32")
    >>> image, phantom = exact.draw()
    >>> image.shape, phantom.shape
    ((64, 64), (64, 4))
    """

    #: At most this many values per stream are drawn jointly (the predictors hold half this
    #: number squared float64 values).
    MAX_VALUES = 6144

    #: Bytes of factors kept for further realisations, all scenes together.  A scene's
    #: predictors hold about ``(reads × k)² / 2`` float64 values per scope (two scopes):
    #: 1.6 MB for 64 × 64 pixels in 16 channels, 79 MB for 1024 rows of 2 columns per
    #: channel, up to 151 MB per scope at `MAX_VALUES`.  A scene needing more is drawn but
    #: not kept.
    CACHE_BYTES = 256 * 2**20

    def __init__(self, schedule, components, entropy, dtype):
        self.schedule = s = schedule
        g = s.geometry
        self.components = tuple(components)
        self.entropy = entropy
        self.dtype = np.dtype(dtype)
        self.fs, self.nch, self.ncols = g.pixel_rate, g.nchannels, g.ncols
        self.width = g.channel_width
        self.c, self.rs, self.n_reads = s.phantom_reads, s.row_samples, s.n_reads
        self.F, self.N = s.frame_samples, s.nframes
        self.col_off = g.column_offsets()
        self.col_chan = g.channel_of_column()

    def points(self, scope):
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

    def cost(self):
        """Rough operation count of the exact route, and its largest joint draw."""
        nr, span = self.n_reads, self.c + self.width
        nbasis = len({key for c in self.components for key, coef in
                      (("alpha", c.alpha), ("beta", c.beta), (c.exponent, c.gamma)) if coef})
        ops = 100.0 * nbasis * nr * (2 * span - 1) * (2 * self.N - 1)
        biggest = 0
        for scope in ("channel", "common"):
            pix, ph = self.points(scope)
            ns = self.nch if scope == "channel" else 1
            k = pix.size + (1 if ph.size else 0)
            biggest = max(biggest, nr * k)
            # Levinson recursion and draws (k x k blocks), covariance tables, per-step overhead
            # (numpy loops over small blocks: ~10 operations' time per multiply-add)
            ops += (10.0 * nr * nr * (k**3 + k * k * ns) + 2e5 * nr * (k > 0)
                    + 2.0 * nr * (pix.size + ph.size) ** 2 * len(self.components))
        return ops, biggest

    def memory(self):
        """Bytes the exact route allocates at its peak (an upper estimate).

        Its predictors hold ``k² R (R + 1) / 2`` float64 values per scope
        (``R`` reads of ``k`` values: about ``(R k)² / 2``, 151 MB at
        `MAX_VALUES`), kept while the scene is cached; making them takes the
        covariance tables of every lag (the structure functions of ``2 N - 1``
        frame lags at ``R (2 span - 1)`` sample lags, with their temporaries)
        and the ``R`` blocks of covariance of each scope's samples.
        """
        nr, span = self.n_reads, self.c + self.width
        tables = 20 * (2 * self.N - 1) * nr * (2 * span - 1)
        total = (len(self.components) + 1) * nr * (2 * span - 1)
        for scope in ("channel", "common"):
            pix, ph = self.points(scope)
            q = pix.size + ph.size
            k = pix.size + (1 if ph.size else 0)
            ns = self.nch if scope == "channel" else 1
            total += k * k * (nr * (nr + 1) // 2 + 4 * nr) + 3 * nr * q * q + 3 * nr * k * ns
        return 8 * (total + tables)

    def factors(self):
        """``{scope: (_BlockLevinson, pixel positions, phantom positions)}``.

        Every stream of a scope (one per channel, or the common one) is drawn
        as one Gaussian vector: the slopes at its pixel positions of every
        read and the phantom mean of every read, a stationary sequence over
        the reads.  Its covariance sums the
        components of that scope: each seen only by the samples its
        visibility names, and with ACN only between samples of the same
        parity (independent even and odd realisations: column parity, and
        ``(i - c) % 2`` for phantom sample ``i``, as in the tiers).  Cached
        by the schedule's timing and the components (at most
        `CACHE_BYTES` in all, least recently used dropped first), so
        further realisations of a scene only draw.
        """
        key = (self.N, self.F, self.fs, self.rs, self.n_reads, self.c, self.width,
               tuple(self.components))
        with _EXACT_LOCK:
            if key in _EXACT_FACTORS:
                _EXACT_FACTORS.move_to_end(key)
                return _EXACT_FACTORS[key][0]
        factors = self._make_factors()
        nbytes = sum(plan.nbytes + pix.nbytes + phq.nbytes
                     for plan, pix, phq in factors.values())
        bound = self.CACHE_BYTES
        with _EXACT_LOCK:
            _EXACT_FACTORS.pop(key, None)
            if nbytes <= bound:  # a larger entry is used, not kept
                _EXACT_FACTORS[key] = (factors, nbytes)
                while sum(n for _, n in _EXACT_FACTORS.values()) > bound:
                    _EXACT_FACTORS.popitem(last=False)
        return factors

    def _make_factors(self):
        nr, c, w = self.n_reads, self.c, self.width
        span = c + w
        # slope covariance of one stream at lags dr * row_samples + dq (dr >= 0)
        lags = np.abs(np.arange(nr)[:, None] * self.rs + np.arange(-(span - 1), span)[None, :])
        cov = slope_covariance(self.components, self.schedule, lags)
        factors = {}
        for scope in ("channel", "common"):
            pix, phq = self.points(scope)
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
        return factors

    def draw(self):
        """Slope image ``(n_reads, ncols)`` (e/s) and phantom slopes ``(n_reads, nch)``.

        Raises
        ------
        ValueError
            More than `MAX_VALUES` values per stream would be drawn jointly.
        ResourceError
            The factors (`memory`) do not fit in this process.
        """
        biggest = self.cost()[1]
        if biggest > self.MAX_VALUES:
            raise ValueError(f"slope_route='exact' would draw {biggest} samples per stream "
                             f"jointly (at most {self.MAX_VALUES}); use the tiered route")
        limits.check_size(self.memory(), "the exact slope route's factors")
        nr, nch = self.n_reads, self.nch
        out = np.zeros((nr, self.ncols), dtype=self.dtype)
        ph = np.zeros((nr, nch)) if self.c else None
        for scope, (plan, pix, phq) in self.factors().items():
            ns = nch if scope == "channel" else 1
            rng = rng_for(self.entropy, TIER_EXACT, STREAM_SCOPES[scope])
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
