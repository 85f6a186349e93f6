"""Readout noise placed at every sample time of a schedule, in three frequency tiers.

A full-rate FFT of every stream over the whole exposure is far too slow for a
2048² array, so each PSD is split with smooth (cos²) crossovers into

``slow A``  f < f_A, on a grid of ``16 d_B`` samples spanning the exposure
            ``padding`` times over (no wrap-around bias);
``slow B``  f_A/2 < f < f_B, on a grid of ``d_B = 2 row_samples`` samples (two
            row reads) spanning the exposure plus a gap of ``4 / f_A``;
``fast``    f > f_B/2 plus all white noise, at the full sample rate, per block of
            frames (one frame at full size) — for pixels one stream per channel
            (and one common stream) with all pixel-visible components summed,
            and with ACN two per channel, one per column parity.

with ``f_B = fs / (16 d_B)`` (43 Hz at full size) and ``f_A = f_B / 16``
(2.7 Hz), so each slow grid oversamples its band 8 to 16 times.  The slow
tiers are interpolated linearly to the first and last sample of every row
read and linearly in between (a read lasts ``1/32`` of the shortest slow
period).  The phantom value of a read is the mean of its ``c`` samples: a
component seen by the pixels and the phantom reads (visibility ``both``) is
one realisation for both in every tier (the slow tiers interpolated at the
phantom samples, the fast tier's own full-rate streams averaged over them);
the fast part of the phantom-only components is a sequence over reads with
the exact covariance of that mean.  For long or large exposures the slow-B
tier and the phantom sequences are made window by window (``KernelStream``:
white noise in seeded blocks convolved with a truncated kernel), so memory
does not grow with the exposure.

What is approximated (measured in ``benchmarks/README_simulate.md``):
fast-tier blocks are independent (their correlation time is < 1/32 of a
block) and periodic within a block.

In slope mode the slow tiers and the phantom sequences are the same streams
(same seeds) weighted with the least-squares weights ``w_k``.  When a block is
one frame (full size) the frames' fast tiers are independent, so the fast
part of the slope image is one frame-length stream with the fast PSD times
``sum w_k²``; with shorter frames the fast blocks of the ramps are fitted.

Small scenes take another route in slope mode (`NoiseEngine.slope_route`,
chosen by cost): the slopes drawn exactly at the samples read
(`spherex_reduce.simulation.exact_slopes`).  The pixels' fast tier is in
`spherex_reduce.simulation.pixel_fast_tier`, the phantom means' in
`spherex_reduce.simulation.phantom_tier`; the bands of the tiers are in
`spherex_reduce.simulation.tier_bands`, their streams (kernel streams, stream
groups, generators) in `spherex_reduce.simulation.streams`.
"""

import math

import numpy as np
import scipy.fft as sfft
from scipy import sparse

from ..core import limits
from ..noise.variance import ls_weights
from .exact_slopes import ExactSlopes
from .phantom_tier import PhantomTier
from .pixel_fast_tier import PixelFastTier
from .streams import (
    TIER_A,
    TIER_B,
    TIER_FAST,
    TIER_SLOPE_FAST,
    KernelStream,
    StreamGroup,
    frame_chunks,
    periodic_functional_variance,
    stream_rngs,
)
from .synthesis import covariance_from_weights, psd_weights, synthesize
from .tier_bands import BandPSD, fft_len

__all__ = ["NoiseEngine"]


class NoiseEngine:
    """The noise of a schedule's samples for a set of components.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    components : sequence of `NoiseComponent`
        Zero components are dropped; phantom-only ones too when ``c = 0``.
    seed : int or `numpy.random.SeedSequence`
    method : {'gaussian', 'random_phase'}
    padding : float
        Length of the slow-A synthesis relative to the exposure (>= 1).
        ``1`` makes the stream periodic over the exposure (the paper's method
        and its low bias).
    dtype : numpy dtype
        ``float32`` (default) or ``float64`` for the full-rate arrays.
    oversample : int
        Ratio of the slow-B grid rate to ``f_B`` (16 by default).
    b_reads : int
        Row reads per step of the slow-B grid (2 by default).
    streaming : bool, optional
        Make the slow-B tier and the phantom sequences window by window from
        a truncated convolution kernel, so memory does not grow with the
        exposure; by default when they would hold more than 4 M values.
    slope_route : {'exact', 'tiered'}, optional
        How `slopes` draws the image: ``'exact'`` from the covariance of the
        samples read (small scenes), ``'tiered'`` from the synthesised tiers.
        By default the cheaper one that fits in memory (see `slope_route`;
        ``'exact'`` given for a scene whose factors do not fit raises
        `~spherex_reduce.core.errors.ResourceError`); ``'exact'`` is only
        chosen by default for Gaussian amplitudes with at least the default
        padding, since it is aperiodic whatever the padding.

    Examples
    --------
    >>> from spherex_reduce.io.examples import tiny_schedule
    >>> from spherex_reduce.simulation import NoiseComponent
    >>> from spherex_reduce.simulation.engine import NoiseEngine
    >>> eng = NoiseEngine(tiny_schedule(), [NoiseComponent("w", alpha=2e-3)], seed=1)
    >>> frames = list(eng.frames())
    >>> frames[0][0].shape, frames[0][1].shape       # pixels, phantom of frame 0
    ((64, 64), (64, 4))
    """

    def __init__(self, schedule, components, seed=0, *, method="gaussian", padding=16.0,
                 dtype=np.float32, oversample=16, b_reads=2, streaming=None,
                 slope_route=None):
        self.schedule = s = schedule
        g = s.geometry
        if g.window is not None:  # its reads are not every row_samples: not modelled
            raise ValueError("the simulator does not simulate a window of a larger array; "
                             "simulate the full array and cut the window from it")
        self.fs = g.pixel_rate
        self.nch, self.width, self.ncols = g.nchannels, g.channel_width, g.ncols
        self.c, self.rs, self.n_reads = s.phantom_reads, s.row_samples, s.n_reads
        self.F, self.N = s.frame_samples, s.nframes
        self.method, self.dtype = method, np.dtype(dtype)
        self.padding = float(padding)
        self.slow_dtype = np.float64 if self.dtype == np.float64 else np.float32
        self.gap_factor = 4
        if isinstance(seed, np.random.SeedSequence):
            self.entropy = (seed.entropy, tuple(seed.spawn_key))
        else:
            self.entropy = (seed, ())
        comps = [c for c in components if not c.is_zero]
        if self.c == 0:
            comps = [c for c in comps if c.seen_by_pixels]
        self.components = comps
        keys = {}
        for c in comps:
            keys.setdefault((c.scope, c.visibility, c.acn), []).append(c)
        self.groups = [StreamGroup(k, v, self.nch) for k, v in keys.items()]
        self.slow_groups = [gr for gr in self.groups if gr.colored]
        # tiers
        self.d_b = self.rs * b_reads
        self.f_b = self.fs / (oversample * self.d_b)
        self.d_a = 16 * self.d_b
        self.f_a = self.f_b / 16
        self.exposure = self.N * self.F
        self.l_corr = int(32 * self.fs / self.f_b)
        self.block = max(1, math.ceil(self.l_corr / self.F))
        self._column_maps()
        self._slow = None
        self._bcache = {}
        self._streaming = streaming
        self.phantom_tier = PhantomTier(self)
        self.fast_tier = PixelFastTier(self)
        self.exact = ExactSlopes(s, comps, self.entropy, self.dtype)
        if slope_route not in (None, "auto", *self.SLOPE_ROUTES):
            raise ValueError(f"slope_route must be one of {self.SLOPE_ROUTES} or None, "
                             f"got {slope_route!r}")
        self._slope_route = None if slope_route == "auto" else slope_route

    # -- layout ----------------------------------------------------------------
    def _column_maps(self):
        g = self.schedule.geometry
        off = g.column_offsets()
        self.col_off = off
        self.col_parity = off % 2
        self.col_chan = g.channel_of_column()
        span = max(self.c + self.width - 1, 1)
        self.span = span
        self.col_frac = ((self.c + off) / span).astype(self.dtype)
        self.reverse = g.scan_directions < 0
        # (nch, 4, width): weights of [K0 even, K0 odd, K1 even, K1 odd] for each column
        pat = np.zeros((self.nch, 4, self.width))
        frac = self.col_frac.astype(float).reshape(self.nch, self.width)
        par = self.col_parity.reshape(self.nch, self.width)
        for p in (0, 1):
            pat[:, p] = np.where(par == p, 1 - frac, 0)
            pat[:, 2 + p] = np.where(par == p, frac, 0)
        self.knot_pattern = pat.astype(self.dtype)
        # phantom sample i (0..c-1) sits at position i of the read, parity (i - c) % 2
        i = np.arange(self.c)
        par = (i - self.c) % 2
        fr = i / span
        self.ph_a = np.array([np.sum((1 - fr)[par == p]) for p in (0, 1)]) / max(self.c, 1)
        self.ph_b = np.array([np.sum(fr[par == p]) for p in (0, 1)]) / max(self.c, 1)

    # -- slow tiers ------------------------------------------------------------
    def _slow_sizes(self):
        """Samples used and FFT lengths of the slow grids: ``(ja, ma, jb, mb)``."""
        jb = self.exposure // self.d_b + 3
        gap = math.ceil(self.gap_factor * self.fs / self.f_a / self.d_b)
        mb = fft_len(jb + gap)
        ja = self.exposure // self.d_a + 3
        ma = fft_len(max(ja, math.ceil(self.padding * ja)))
        if self.padding <= 1:
            ma, mb = ja, jb
        return ja, ma, jb, mb

    #: Stream the slow-B tier and phantom sequences when they would hold more values
    STREAM_ABOVE = 1 << 22

    @property
    def streaming(self):
        """Slow B and phantom sequences made window by window, in memory that does not grow
        with the exposure (Gaussian method with padding only; automatic for long or large
        exposures, fixed by the scene so results never depend on it changing)."""
        if self.method != "gaussian" or self.padding <= 1:
            return False
        if self._streaming is not None:
            return bool(self._streaming)
        ns = sum(gr.nstreams for gr in self.slow_groups) + self.nch + 1
        return (self.exposure // self.d_b) * ns > self.STREAM_ABOVE

    def slow_streams(self):
        """Slow tiers of every group: ``{gid: (A grid (J_A, ns), B)}``.

        B is a grid ``(J_B, ns)``, or a ``KernelStream`` when streaming.
        """
        if self._slow is not None:
            return self._slow
        out = {}
        ja, ma, jb, mb = self._slow_sizes()
        for gr in self.slow_groups:
            rng_a = stream_rngs(self.entropy, gr.nstreams, ma // 2 + 1, TIER_A, gr.gid)
            psd_b = BandPSD(gr.comps, "B", self.f_a, self.f_b)
            psd_a = BandPSD(gr.comps, "A", self.f_a, self.f_b)
            # stored (samples, streams) so that the sparse interpolation needs no copies
            xa = np.empty((ja, gr.nstreams), dtype=self.slow_dtype)
            synthesize(psd_weights(psd_a, ma, self.fs / self.d_a), ma, ja, rng_a,
                       method=self.method, dtype=self.slow_dtype, nstreams=gr.nstreams,
                       out=xa.T)
            lam_b = psd_weights(psd_b, mb, self.fs / self.d_b)
            if self.streaming:
                xb = KernelStream(lam_b, mb, gr.nstreams, self.entropy, (TIER_B, gr.gid),
                                   self.slow_dtype, total=jb,
                                   window=self.CHUNK * self.F // self.d_b)
            else:
                rng_b = stream_rngs(self.entropy, gr.nstreams, mb // 2 + 1, TIER_B, gr.gid)
                xb = np.empty((jb, gr.nstreams), dtype=self.slow_dtype)
                synthesize(lam_b, mb, jb, rng_b, method=self.method, dtype=self.slow_dtype,
                           nstreams=gr.nstreams, out=xb.T)
            out[gr.gid] = (xa, xb)
        self._slow = out
        return out

    def _interp_matrix(self, ks, weights, step, size, offset=0):
        """Sparse ``(2 n_reads, size)``: linear interpolation at the knots, weighted by frame.

        Column ``j`` is grid point ``offset + j``.
        """
        s0 = np.arange(self.n_reads, dtype=np.int64) * self.rs
        base = np.concatenate([s0, s0 + self.span])
        ks = np.asarray(list(ks))
        wts = np.ones(ks.size) if weights is None else np.asarray(weights, dtype=float)
        pos = (base[:, None] + ks[None, :] * self.F) / step  # (knots, frames)
        i0 = np.floor(pos).astype(np.int64)
        fr = pos - i0
        i0 -= offset
        idx = np.stack([i0, i0 + 1], axis=-1).reshape(base.size, -1)
        val = np.stack([(1 - fr) * wts, fr * wts], axis=-1).reshape(base.size, -1)
        indptr = np.arange(base.size + 1) * idx.shape[1]
        return sparse.csr_matrix((val.ravel().astype(self.slow_dtype), idx.ravel(), indptr),
                                 shape=(base.size, size))

    CHUNK = 16  # frames per window of the streamed slow-B tier and phantom sequences

    def _b_range(self, ks):
        """Grid points of the slow-B tier that the knots of frames ``ks`` use."""
        first = (min(ks) * self.F) // self.d_b
        last = (max(ks) * self.F + (self.n_reads - 1) * self.rs + self.span) // self.d_b + 2
        return first, last

    def _b_window(self, gid, xb, ks):
        if not isinstance(xb, KernelStream):
            return 0, xb
        j0, j1 = self._b_range(ks)
        cached = self._bcache.get(gid)
        if cached is None or cached[0] != (j0, j1):
            cached = self._bcache[gid] = ((j0, j1), xb.window(j0, j1))
        return j0, cached[1]

    def _slow_knots(self, ks, weights=None):
        """Knot values ``{gid: (nstreams, 2, n_reads)}`` of frames ``ks`` (weighted sum)."""
        slow = self.slow_streams()
        out = {}
        for gid, (xa, xb) in slow.items():
            mat_a = self._interp_matrix(ks, weights, self.d_a, xa.shape[0])
            v = np.asarray(mat_a @ xa, dtype=np.float64)
            for kc, wc in frame_chunks(ks, weights, self.CHUNK):
                cache_ks = kc
                if len(kc) == 1:  # ramps: one window serves a chunk of frames
                    q = kc[0] // self.CHUNK
                    cache_ks = range(q * self.CHUNK, min(self.N, (q + 1) * self.CHUNK))
                j0, win = self._b_window(gid, xb, cache_ks)
                v += self._interp_matrix(kc, wc, self.d_b, win.shape[0], offset=j0) @ win
            out[gid] = v.T.reshape(xa.shape[1], 2, self.n_reads)
        return out

    def _combine_slow(self, knots):
        """Pixel knots (2, n_reads, nch*2) and phantom values (n_reads, nch)."""
        nch = self.nch
        pix = np.zeros((2, self.n_reads, nch, 2))
        ph = np.zeros((self.n_reads, nch))
        for gr in self.slow_groups:
            v = knots[gr.gid]  # (nstreams, 2, n_reads)
            if gr.scope == "channel":
                v = v.reshape(nch, 2 if gr.acn else 1, 2, self.n_reads)
            else:
                v = v.reshape(1, 1, 2, self.n_reads)
            vt = v.transpose(2, 3, 0, 1)  # (knot, read, ch, parity)
            if gr.visibility in ("pixels", "both"):
                pix += vt
            if gr.visibility in ("phantom", "both") and self.c:
                a, b = self.ph_a, self.ph_b
                if v.shape[1] == 1:
                    a, b = a.sum(keepdims=True), b.sum(keepdims=True)
                ph += np.einsum("krcp,p->rc", vt[:1], a) + np.einsum("krcp,p->rc", vt[1:], b)
        return pix.reshape(2, self.n_reads, nch * 2), ph

    def _pixels_from_knots(self, pix, out, assign=False):
        """Add (or assign) the slow tiers, linear between the knots of each read.

        One small batched matrix product per read and channel:
        ``[K0 even, K0 odd, K1 even, K1 odd] @ pattern`` with the pattern
        holding ``1 - frac`` and ``frac`` of each column at its parity.
        """
        nr, nch, w = self.n_reads, self.nch, self.width
        x = pix.reshape(2, nr, nch, 2).transpose(1, 2, 0, 3).reshape(nr, nch, 1, 4)
        x = x.astype(self.dtype)
        if assign:
            np.matmul(x, self.knot_pattern, out=out.reshape(nr, nch, 1, w))
        else:
            out += np.matmul(x, self.knot_pattern).reshape(nr, nch * w)

    # -- fast tier (pixels) ----------------------------------------------------------
    def _block_fft_len(self):
        if self.block == 1:
            return fft_len(self.F)
        return fft_len(self.block * self.F + self.l_corr)

    def _fast_block(self, b, nframes):
        """Full-rate fast streams of frame block ``b`` and their phantom means
        (`PixelFastTier.streams`)."""
        return self.fast_tier.streams(nframes * self.F, self._block_fft_len(), 1.0,
                                      TIER_FAST, b)

    def _pixels_from_stream(self, ch_stream, common_stream, k_in_block, out, assign=False):
        """Add (or assign) the samples of frame ``k_in_block`` of the fast streams to ``out``."""
        lo = k_in_block * self.F
        nr, rs, c, w = self.n_reads, self.rs, self.c, self.width
        o3 = out.reshape(nr, self.nch, w)
        fwd = ~self.reverse
        if ch_stream is not None:
            seg = ch_stream[:, lo:lo + nr * rs].reshape(self.nch, nr, rs)[:, :, c:c + w]
            if fwd.all():
                if assign:
                    np.copyto(o3, seg.transpose(1, 0, 2))
                else:
                    o3 += seg.transpose(1, 0, 2)
            else:
                if assign:
                    out[...] = 0
                o3[:, fwd] += seg[fwd].transpose(1, 0, 2)
                o3[:, ~fwd] += seg[~fwd][:, :, ::-1].transpose(1, 0, 2)
            assign = False
        if common_stream is not None:
            part = common_stream[0, lo:lo + nr * rs].reshape(nr, rs)[:, c:c + w]
            if assign:
                out[...] = 0
            if fwd.all():
                o3 += part[:, None, :]
            else:
                o3[:, fwd] += part[:, None, :]
                o3[:, ~fwd] += part[:, None, ::-1]

    # -- ramps -------------------------------------------------------------------------
    def frames(self):
        """Yield ``(pixels, phantom)`` of each frame: ``(n_reads, ncols)``, ``(n_reads, nch)``.

        Pixels in the engine's dtype, phantom in float64 (or None when c = 0).
        Memory does not grow with the number of frames beyond the slow-tier
        grids (about 1.2 MB per frame at full size).
        """
        self.slow_streams()
        self.phantom_tier.sequences()
        for b0 in range(0, self.N, self.block):
            nb = min(self.block, self.N - b0)
            fast, fast_ph = self._fast_block(b0 // self.block, nb)
            for j in range(nb):
                k = b0 + j
                out = np.empty((self.n_reads, self.ncols), dtype=self.dtype)
                pix, ph = self._combine_slow(self._slow_knots([k]))
                self._pixels_from_knots(pix, out, assign=True)
                self._pixels_from_stream(fast.get("channel"), fast.get("common"), j, out)
                phantom = None
                if self.c:
                    phantom = ph + self.phantom_tier.values([k])
                    if fast_ph is not None:
                        phantom += fast_ph[j]
                yield out, phantom

    # -- slopes --------------------------------------------------------------------------
    SLOPE_ROUTES = ("exact", "tiered")

    @property
    def slope_route(self):
        """``'exact'`` or ``'tiered'``: how `slopes` draws the image.

        By default the route with the smaller operation count (`exact`'s
        ``cost`` against ``_tiered_cost``): the exact route for few pixels per
        channel (its cost grows as ``reads² × (width + 1)³``), the tiered one
        for large arrays (its cost grows with the samples of a frame, overheads
        included), but never the exact route if its memory (`exact`'s
        ``memory``, mostly its predictors: ``(reads × (width + 1))² / 2``
        float64 values per scope) exceeds
        `~spherex_reduce.core.limits.memory_budget`.  The random-phase method
        and paddings below the default keep the tiered synthesis, whose
        periodicity they are there to reproduce.
        """
        if self._slope_route is not None:
            return self._slope_route
        if self.method != "gaussian" or self.padding < 16 or self.N < 2:
            return "tiered"
        cost, biggest = self.exact.cost()
        if biggest > self.exact.MAX_VALUES or cost >= self._tiered_cost():
            return "tiered"
        # never a route this process cannot hold (a dask worker's memory limit, say)
        return "exact" if self.exact.memory() <= limits.memory_budget() else "tiered"

    def slopes(self):
        """Slope image ``(n_reads, ncols)`` (e/s) and phantom slopes ``(n_reads, nch)``.

        Drawn by the route `slope_route` names: ``'exact'`` by `exact` (an
        `~spherex_reduce.simulation.exact_slopes.ExactSlopes`), ``'tiered'``
        from the synthesised tiers.  Both have the statistics of the
        least-squares fit of the frames (the exact route exactly, the tiered
        one up to the approximations `expected_slope_variance` measures).
        """
        if self.slope_route == "exact":
            return self.exact.draw()
        return self._tiered_slopes()

    def _tiered_cost(self):
        """Rough operation count of the tiered route in slope mode (FFT synthesis)."""
        def fft(m, ns=1):
            return ns * m * (5 * math.log2(max(m, 2)) + 30)

        _, ma, _, mb = self._slow_sizes()
        ops = sum(fft(ma, gr.nstreams) + fft(mb, gr.nstreams) for gr in self.slow_groups)
        nfast = sum(1 if scope == "common" else self.nch for scope, _ in self.fast_tier.psds())
        if self.block == 1:  # one frame-length stream (the frames' fast tiers are independent)
            ops += fft(self._block_fft_len(), nfast)
        else:  # the ramps' blocks, fitted
            ops += math.ceil(self.N / self.block) * fft(self._block_fft_len(), nfast)
            ops += 4.0 * self.N * self.n_reads * self.ncols
        phantom_only = self.phantom_tier.psds()
        if phantom_only:
            g_lag = math.ceil(2 * self.l_corr / self.rs) + 2
            m = sfft.next_fast_len(max(4 * (g_lag * self.rs + self.c), 8 * self.l_corr, 1024))
            ops += 2 * len(phantom_only) * fft(m)
            ops += fft(self.exposure // self.rs + 2 * g_lag, self.nch + 1)
        return ops

    def expected_slope_variance(self, read=0, column=0):
        """Exact variance (e²/s²) of this engine's simulated slope of one pixel.

        Computed from the spectral weights of every tier and the linear map
        from the streams to the slope (interpolation, least-squares weights):
        what an infinite ensemble of this engine gives, including its
        approximations (finite padding, tier crossovers, interpolation).
        The same in ramp mode and in slope mode on the tiered route (the
        exact route of `slopes` has the analytic variance itself).  Compare
        with the aperiodic `~spherex_reduce.expected_slope_variance` to
        measure the bias.
        """
        w = self.frame_weights()
        ja, ma, jb, mb = self._slow_sizes()
        frac = float(self.col_frac[column])
        total = 0.0
        for gr in self.slow_groups:
            if gr.visibility == "phantom":
                continue
            for band, step, j, m in (("A", self.d_a, ja, ma), ("B", self.d_b, jb, mb)):
                mat = self._interp_matrix(range(self.N), w, step, j).astype(float)
                a = ((1 - frac) * mat[read].toarray()[0]
                     + frac * mat[self.n_reads + read].toarray()[0])
                lam = psd_weights(BandPSD(gr.comps, band, self.f_a, self.f_b), m, self.fs / step)
                if band == "B" and self.streaming:
                    total += KernelStream(lam, m, 1, self.entropy, (), np.float64
                                           ).functional_variance(a)
                else:
                    total += periodic_functional_variance(a, lam, m)
        for (scope, shared), psd in self.fast_tier.psds().items():
            m = self.fast_tier.period(scope, self._block_fft_len())
            cov = covariance_from_weights(self.fast_tier.weights((scope, shared), psd, m), m)
            for b0 in range(0, self.N, self.block):
                ks = np.arange(b0, min(self.N, b0 + self.block))
                lag = np.abs(ks[:, None] - ks[None, :]) * self.F
                lag = np.minimum(lag, m - lag)
                total += float(np.sum(w[ks, None] * w[None, ks] * cov[lag]))
        return total

    def frame_weights(self):
        """Least-squares slope weights (1/s) of the frames."""
        return ls_weights(np.arange(self.N) * self.F / self.fs)

    def _tiered_slopes(self):
        w = self.frame_weights()
        ks = range(self.N)
        out = np.zeros((self.n_reads, self.ncols), dtype=self.dtype)
        if self.block == 1:
            # frames' fast tiers are independent: the slope is sqrt(sum w^2) times one
            # frame-length stream with the fast PSD (its phantom means likewise)
            scale = float(np.sum(w * w))
            fast, fast_ph = self.fast_tier.streams(self.F, self._block_fft_len(), scale,
                                                   TIER_SLOPE_FAST)
            self._pixels_from_stream(fast.get("channel"), fast.get("common"), 0, out)
            ph_fast = None if fast_ph is None else fast_ph[0]
        else:
            # short frames: the fast tier is correlated across frames; fit the same
            # blocks the ramps use
            ph_fast = None
            for b0 in range(0, self.N, self.block):
                nb = min(self.block, self.N - b0)
                fast, fast_ph = self._fast_block(b0 // self.block, nb)
                for j in range(nb):
                    tmp = np.zeros_like(out)
                    self._pixels_from_stream(fast.get("channel"), fast.get("common"), j, tmp)
                    out += w[b0 + j] * tmp
                    if fast_ph is not None:
                        part = w[b0 + j] * fast_ph[j]
                        ph_fast = part if ph_fast is None else ph_fast + part
        pix, ph = self._combine_slow(self._slow_knots(ks, w))
        self._pixels_from_knots(pix, out)
        phantom = None
        if self.c:
            phantom = ph + self.phantom_tier.values(ks, w)
            if ph_fast is not None:
                phantom += ph_fast
        return out, phantom
