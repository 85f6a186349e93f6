"""Readout noise placed at every sample time of a schedule, in three frequency tiers.

A full-rate FFT of every stream over the whole exposure is far too slow for a
2048² array, so each PSD is split with smooth (cos²) crossovers into

``slow A``  f < f_A, on a grid of ``16 d_B`` samples spanning the exposure
            ``padding`` times over (no wrap-around bias);
``slow B``  f_A/2 < f < f_B, on a grid of ``d_B = 2 row_samples`` samples (two
            row reads) spanning the exposure plus a gap of ``4 / f_A``;
``fast``    f > f_B/2 plus all white noise, at the full sample rate, per block of
            frames (one frame at full size) — for pixels one stream per channel
            (and one common stream) with all pixel-visible components summed.

with ``f_B = fs / (16 d_B)`` (43 Hz at full size) and ``f_A = f_B / 16``
(2.7 Hz), so each slow grid oversamples its band 8 to 16 times.  The slow
tiers are interpolated linearly to the first and last sample of every row
read and linearly in between (a read lasts ``1/32`` of the shortest slow
period).  The phantom value of a read (the mean of its ``c`` samples) gets its
fast part from a sequence over reads with the exact covariance of that mean.
For long or large exposures the slow-B tier and the phantom sequences are made
window by window (``_KernelStream``: white noise in seeded blocks convolved with
a truncated kernel), so memory does not grow with the exposure.

What is approximated (measured in ``benchmarks/README_simulate.md``):

* the fast tier of a phantom-visible component is drawn independently for
  the pixels and for the phantom means (their covariance above ``f_B/2`` is
  dropped: the per-sample residual after phantom subtraction is 1.6 % too
  large for Video8 alone, 0.04 % with all Table 2 terms);
* the fast tier of the pixels is not split into even/odd realisations (ACN
  acts on the slow tiers, which carry the even/odd offsets; the phantom means
  do use the split covariance);
* fast-tier blocks are independent (their correlation time is < 1/32 of a
  block) and periodic within a block.

In slope mode the slow tiers and the phantom sequences are the same streams
(same seeds) weighted with the least-squares weights ``w_k``.  When a block is
one frame (full size) the frames' fast tiers are independent, so the fast
part of the slope image is one frame-length stream with the fast PSD times
``sum w_k²``; with shorter frames the fast blocks of the ramps are fitted.

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
from scipy import signal, sparse

from .. import limits
from .synthesis import covariance_from_weights, psd_weights, rng_for, synthesize
from .variance import ls_weights, slope_covariance

__all__ = ["NoiseEngine"]

_SCOPE = {"channel": 0, "common": 1}
_VIS = {"pixels": 0, "phantom": 1, "both": 2}
TIER_A, TIER_B, TIER_FAST, TIER_PHANTOM, TIER_SLOPE_FAST, TIER_EXACT = range(6)



def _fft_len(n):
    """Smallest 2-3-5-smooth integer >= n (faster than lengths with factors 7, 11)."""
    best = 1 << max(0, math.ceil(math.log2(max(n, 1))))
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def _taper(f, f_hi):
    """1 below f_hi/2, cos² down to 0 at f_hi."""
    x = np.clip((f - f_hi / 2) / (f_hi / 2), 0, 1)
    return np.cos(0.5 * np.pi * x) ** 2


class _PSD:
    """Sum of component PSDs times a band window; callable on f > 0."""

    def __init__(self, comps, band, f_a, f_b, white=False):
        self.comps, self.band, self.f_a, self.f_b = comps, band, f_a, f_b
        self.white = white
        self.dc = sum(c.alpha for c in comps) if white else 0.0

    def window(self, f):
        wa = _taper(f, self.f_a)
        wb = _taper(f, self.f_b)
        return {"A": wa, "B": wb - wa, "fast": 1 - wb}[self.band]

    def __call__(self, f):
        f = np.asarray(f, dtype=float)
        colored = np.zeros_like(f)
        for c in self.comps:
            colored += c.beta / f + c.gamma * f ** (-c.exponent)
        out = colored * self.window(f)
        if self.white:
            out += self.dc
        return out

    @property
    def empty(self):
        if self.white and self.dc > 0:
            return False
        return not any(c.beta or c.gamma for c in self.comps)


def _functional_variance(a, lam, m):
    """Variance of ``sum a_n x_n`` for the period-``m`` stream with spectral weights ``lam``."""
    spec = np.abs(sfft.rfft(a, n=m)) ** 2
    wgt = np.full(spec.size, 2.0)
    wgt[0] = 1.0
    if m % 2 == 0:
        wgt[-1] = 1.0
    return float(np.sum(wgt * lam * spec) / m)


class _KernelStream:
    """Stationary Gaussian streams ``x = h * xi``, made window by window in bounded memory.

    ``h = irfft(sqrt(lam))`` is the kernel whose circular convolution with
    white noise gives the period-``m`` stream with spectral weights ``lam``;
    truncated where it holds all but ``tol`` of its energy and applied as a
    *linear* convolution, it gives an aperiodic stream with (almost) the same
    covariance, computable for any range of samples from white noise drawn in
    fixed blocks (each block its own seed), so memory does not grow with the
    exposure and the numbers do not depend on the windows asked for.
    """

    OFFSET = 1 << 40  # keeps block indices (which may be negative) non-negative

    def __init__(self, lam, m, ns, entropy, key, dtype, tol=1e-7, total=None, window=0):
        h = sfft.irfft(np.sqrt(np.clip(lam, 0, None)), n=m)
        energy = h[: m // 2 + 1] ** 2
        energy[1:] *= 2
        cum = np.cumsum(energy)
        half = int(min(m // 2 - 1, np.searchsorted(cum, (1 - tol) * cum[-1]) + 1))
        half = max(half, 1)
        self.kernel = np.concatenate([h[m - half:], h[: half + 1]]).astype(dtype)
        self.half, self.ns, self.entropy, self.key, self.dtype = half, ns, entropy, key, dtype
        # white-noise block length: fixed by the scene (total samples, window), not by calls
        need = 2 * half + max(window, 1)
        if total is not None:
            need = min(need, total + 2 * half)
        self.BLOCK = int(min(1 << 15, max(1024, 1 << math.ceil(math.log2(need)))))
        self._blocks = {}

    def _xi(self, b):
        if b not in self._blocks:
            if len(self._blocks) > 3:
                self._blocks.pop(next(iter(self._blocks)))
            rng = rng_for(self.entropy, *self.key, b + self.OFFSET)
            self._blocks[b] = rng.standard_normal((self.ns, self.BLOCK), dtype=self.dtype)
        return self._blocks[b]

    def window(self, j0, j1):
        """Samples ``j0 ... j1 - 1`` of every stream, shape ``(j1 - j0, ns)``."""
        lo, hi = j0 - self.half, j1 + self.half
        b0, b1 = lo // self.BLOCK, (hi - 1) // self.BLOCK
        xi = np.concatenate([self._xi(b) for b in range(b0, b1 + 1)], axis=1)
        xi = xi[:, lo - b0 * self.BLOCK: hi - b0 * self.BLOCK]
        x = signal.fftconvolve(xi, self.kernel[None, :], mode="valid", axes=1)
        return np.ascontiguousarray(x.T, dtype=self.dtype)

    def functional_variance(self, a):
        """Variance of ``sum_n a_n x_n``: the energy of ``a`` convolved with the kernel."""
        return float(np.sum(signal.fftconvolve(a, self.kernel.astype(float)) ** 2))


class _Group:
    """Components sharing scope, visibility and ACN: one set of slow streams."""

    def __init__(self, key, comps, nch):
        self.scope, self.visibility, self.acn = key
        self.comps = comps
        self.gid = _SCOPE[self.scope] * 6 + _VIS[self.visibility] * 2 + int(self.acn)
        per = 2 if self.acn else 1
        self.nstreams = nch * per if self.scope == "channel" else 1
        self.colored = any(c.beta or c.gamma for c in comps)


#: Factors of the exact slope route, by scene timing and components (least recent first):
#: ``key -> (factors, nbytes)``, at most `NoiseEngine.EXACT_CACHE_BYTES` in all.
_EXACT_FACTORS = collections.OrderedDict()
_EXACT_LOCK = threading.Lock()

#: Streams whose spectra have at most this many bins share one generator per call.
SHARED_BELOW = 16384


def _rngs(entropy, ns, nbins, *key):
    """Per-stream generators for long streams, one shared generator for short ones."""
    if nbins <= SHARED_BELOW:
        return rng_for(entropy, *key, 1 << 30)
    return [rng_for(entropy, *key, i) for i in range(ns)]


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
        `~spherex_reduce.errors.ResourceError`); ``'exact'`` is only
        chosen by default for Gaussian amplitudes with at least the default
        padding, since it is aperiodic whatever the padding.

    Examples
    --------
    >>> from spherex_reduce.examples import tiny_schedule
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
        self.groups = [_Group(k, v, self.nch) for k, v in keys.items()]
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
        self._phantom = None
        self._lam_cache = {}
        self._bcache = {}
        self._pcache = {}
        self._streaming = streaming
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
        mb = _fft_len(jb + gap)
        ja = self.exposure // self.d_a + 3
        ma = _fft_len(max(ja, math.ceil(self.padding * ja)))
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

        B is a grid ``(J_B, ns)``, or a ``_KernelStream`` when streaming.
        """
        if self._slow is not None:
            return self._slow
        out = {}
        ja, ma, jb, mb = self._slow_sizes()
        for gr in self.slow_groups:
            rng_a = _rngs(self.entropy, gr.nstreams, ma // 2 + 1, TIER_A, gr.gid)
            psd_b = _PSD(gr.comps, "B", self.f_a, self.f_b)
            psd_a = _PSD(gr.comps, "A", self.f_a, self.f_b)
            # stored (samples, streams) so that the sparse interpolation needs no copies
            xa = np.empty((ja, gr.nstreams), dtype=self.slow_dtype)
            synthesize(psd_weights(psd_a, ma, self.fs / self.d_a), ma, ja, rng_a,
                       method=self.method, dtype=self.slow_dtype, nstreams=gr.nstreams,
                       out=xa.T)
            lam_b = psd_weights(psd_b, mb, self.fs / self.d_b)
            if self.streaming:
                xb = _KernelStream(lam_b, mb, gr.nstreams, self.entropy, (TIER_B, gr.gid),
                                   self.slow_dtype, total=jb,
                                   window=self.CHUNK * self.F // self.d_b)
            else:
                rng_b = _rngs(self.entropy, gr.nstreams, mb // 2 + 1, TIER_B, gr.gid)
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

    def _chunks(self, ks, weights):
        ks = list(ks)
        wts = np.ones(len(ks)) if weights is None else np.asarray(weights, dtype=float)
        for i in range(0, len(ks), self.CHUNK):
            yield ks[i:i + self.CHUNK], wts[i:i + self.CHUNK]

    def _b_range(self, ks):
        """Grid points of the slow-B tier that the knots of frames ``ks`` use."""
        first = (min(ks) * self.F) // self.d_b
        last = (max(ks) * self.F + (self.n_reads - 1) * self.rs + self.span) // self.d_b + 2
        return first, last

    def _b_window(self, gid, xb, ks):
        if not isinstance(xb, _KernelStream):
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
            for kc, wc in self._chunks(ks, weights):
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
    def _fast_psds(self, kind):
        """Fast-tier PSDs ``{'channel': psd, 'common': psd}`` seen by ``kind``."""
        res = {}
        for scope in ("channel", "common"):
            comps = [c for c in self.components if c.scope == scope and
                     (c.seen_by_pixels if kind == "pixels" else c.seen_by_phantom)]
            psd = _PSD(comps, "fast", self.f_a, self.f_b, white=True)
            if comps and not psd.empty:
                res[scope] = psd
        return res

    def _block_fft_len(self):
        if self.block == 1:
            return _fft_len(self.F)
        return _fft_len(self.block * self.F + self.l_corr)

    def _fast_lam(self, scope, psd, m):
        key = (scope, m)
        if key not in self._lam_cache:
            self._lam_cache[key] = psd_weights(psd, m, self.fs)
        return self._lam_cache[key]

    def _fast_block(self, b, nframes):
        """Full-rate fast streams of frame block ``b``: channel (nch, n) and common (n,)."""
        n = nframes * self.F
        m = self._block_fft_len()
        res = {}
        for scope, psd in self._fast_psds("pixels").items():
            lam = self._fast_lam(scope, psd, m)
            ns = self.nch if scope == "channel" else 1
            rngs = _rngs(self.entropy, ns, m // 2 + 1, TIER_FAST, _SCOPE[scope], b)
            res[scope] = synthesize(lam, m, n, rngs, method=self.method, dtype=self.dtype,
                                    nstreams=ns)
        return res

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

    # -- phantom fast tier -------------------------------------------------------
    def _fast_covariance(self, psd, max_lag):
        """Autocovariance of a fast-tier stream at lags 0 ... max_lag (samples)."""
        m = sfft.next_fast_len(max(4 * max_lag, 8 * self.l_corr, 1024))
        lam = psd_weights(psd, m, self.fs)
        return covariance_from_weights(lam, m)[: max_lag + 1]

    def phantom_sequences(self):
        """Fast part of the phantom means on a grid of reads: ``{scope: stream}``.

        Each stream is an array ``(ns, J)`` or, when streaming, a ``_KernelStream``.
        """
        if self._phantom is not None:
            return self._phantom
        res = {}
        if self.c:
            g_lag = math.ceil(2 * self.l_corr / self.rs) + 2
            jp = self.exposure // self.rs + 2
            mp = sfft.next_fast_len(max(jp + g_lag, 2 * g_lag + 2))
            if self.streaming:
                mp = sfft.next_fast_len(8 * g_lag + 2)
            i = np.arange(self.c)
            dd = (i[:, None] - i[None, :]).ravel()
            same = (((i - self.c) % 2)[:, None] == ((i - self.c) % 2)[None, :]).ravel()
            lags = np.abs(np.arange(g_lag + 1)[:, None] * self.rs + dd[None, :])
            for scope in self._fast_psds("phantom"):
                # covariance of the mean of the c samples; with ACN only samples of the
                # same parity (the same realisation) are correlated
                r = np.zeros(g_lag + 1)
                for acn in (False, True):
                    comps = [c for c in self.components if c.scope == scope and
                             c.seen_by_phantom and c.acn == acn]
                    psd = _PSD(comps, "fast", self.f_a, self.f_b, white=True)
                    if not comps or psd.empty:
                        continue
                    cf = self._fast_covariance(psd, g_lag * self.rs + self.c)
                    pairs = cf[lags] * (same if acn else 1.0)
                    r += pairs.sum(axis=1) / self.c**2
                emb = np.zeros(mp)
                emb[: g_lag + 1] = r
                emb[mp - g_lag:] = r[1:][::-1]
                lam = sfft.rfft(emb).real
                ns = self.nch if scope == "channel" else 1
                if self.streaming:
                    res[scope] = _KernelStream(lam, mp, ns, self.entropy,
                                               (TIER_PHANTOM, _SCOPE[scope]), np.float32,
                                               total=jp, window=self.CHUNK * self.F // self.rs)
                    continue
                rngs = _rngs(self.entropy, ns, mp // 2 + 1, TIER_PHANTOM, _SCOPE[scope])
                res[scope] = synthesize(lam, mp, jp, rngs, method=self.method,
                                        dtype=np.float32, nstreams=ns)
        self._phantom = res
        return res

    def _phantom_index(self, k):
        return (k * self.F) // self.rs + np.arange(self.n_reads)

    def _phantom_fast(self, ks, weights=None):
        seqs = self.phantom_sequences()
        out = np.zeros((self.n_reads, self.nch))
        for scope, x in seqs.items():
            acc = np.zeros((self.n_reads, self.nch if scope == "channel" else 1))
            for kc, wc in self._chunks(ks, weights):
                if isinstance(x, _KernelStream):
                    cache_ks = kc
                    if len(kc) == 1:
                        q = kc[0] // self.CHUNK
                        cache_ks = range(q * self.CHUNK, min(self.N, (q + 1) * self.CHUNK))
                    j0 = self._phantom_index(min(cache_ks))[0]
                    j1 = self._phantom_index(max(cache_ks))[-1] + 1
                    cached = self._pcache.get(scope)
                    if cached is None or cached[0] != (j0, j1):
                        cached = self._pcache[scope] = ((j0, j1), x.window(j0, j1))
                    win = cached[1]
                    for k, wk in zip(kc, wc, strict=True):
                        acc += wk * win[self._phantom_index(k) - j0]
                else:
                    for k, wk in zip(kc, wc, strict=True):
                        acc += wk * x[:, self._phantom_index(k)].T
            out += acc  # (n_reads, ns) broadcasts for common
        return out

    # -- ramps -------------------------------------------------------------------------
    def frames(self):
        """Yield ``(pixels, phantom)`` of each frame: ``(n_reads, ncols)``, ``(n_reads, nch)``.

        Pixels in the engine's dtype, phantom in float64 (or None when c = 0).
        Memory does not grow with the number of frames beyond the slow-tier
        grids (about 1.2 MB per frame at full size).
        """
        self.slow_streams()
        self.phantom_sequences()
        for b0 in range(0, self.N, self.block):
            nb = min(self.block, self.N - b0)
            fast = self._fast_block(b0 // self.block, nb)
            for j in range(nb):
                k = b0 + j
                out = np.empty((self.n_reads, self.ncols), dtype=self.dtype)
                pix, ph = self._combine_slow(self._slow_knots([k]))
                self._pixels_from_knots(pix, out, assign=True)
                self._pixels_from_stream(fast.get("channel"), fast.get("common"), j, out)
                phantom = None
                if self.c:
                    phantom = ph + self._phantom_fast([k])
                yield out, phantom

    # -- slopes --------------------------------------------------------------------------
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
                lam = psd_weights(_PSD(gr.comps, band, self.f_a, self.f_b), m, self.fs / step)
                if band == "B" and self.streaming:
                    total += _KernelStream(lam, m, 1, self.entropy, (), np.float64
                                           ).functional_variance(a)
                else:
                    total += _functional_variance(a, lam, m)
        for _scope, psd in self._fast_psds("pixels").items():
            m = self._block_fft_len()
            cov = covariance_from_weights(psd_weights(psd, m, self.fs), m)
            for b0 in range(0, self.N, self.block):
                ks = np.arange(b0, min(self.N, b0 + self.block))
                lag = np.abs(ks[:, None] - ks[None, :]) * self.F
                lag = np.minimum(lag, m - lag)
                total += float(np.sum(w[ks, None] * w[None, ks] * cov[lag]))
        return total

    def frame_weights(self):
        """Least-squares slope weights (1/s) of the frames."""
        return ls_weights(np.arange(self.N) * self.F / self.fs)

    # -- slopes: choice of route ------------------------------------------------------------
    SLOPE_ROUTES = ("exact", "tiered")
    #: The exact route draws at most this many values per stream jointly (its predictors
    #: hold half this number squared float64 values).
    EXACT_MAX = 6144

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
        exceeds `~spherex_reduce.limits.memory_budget`.  The
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

    def _tiered_slopes(self):
        w = self.frame_weights()
        ks = range(self.N)
        out = np.zeros((self.n_reads, self.ncols), dtype=self.dtype)
        if self.block == 1:
            # frames' fast tiers are independent: the slope is sqrt(sum w^2) times one
            # frame-length stream with the fast PSD
            m = self._block_fft_len()
            scale = float(np.sum(w * w))
            fast = {}
            for scope, psd in self._fast_psds("pixels").items():
                lam = psd_weights(psd, m, self.fs) * scale
                ns = self.nch if scope == "channel" else 1
                rngs = _rngs(self.entropy, ns, m // 2 + 1, TIER_SLOPE_FAST, _SCOPE[scope])
                fast[scope] = synthesize(lam, m, self.F, rngs, method=self.method,
                                         dtype=self.dtype, nstreams=ns)
            self._pixels_from_stream(fast.get("channel"), fast.get("common"), 0, out)
        else:
            # short frames: the fast tier is correlated across frames; fit the same
            # blocks the ramps use
            for b0 in range(0, self.N, self.block):
                nb = min(self.block, self.N - b0)
                fast = self._fast_block(b0 // self.block, nb)
                for j in range(nb):
                    tmp = np.zeros_like(out)
                    self._pixels_from_stream(fast.get("channel"), fast.get("common"), j, tmp)
                    out += w[b0 + j] * tmp
        pix, ph = self._combine_slow(self._slow_knots(ks, w))
        self._pixels_from_knots(pix, out)
        phantom = None
        if self.c:
            phantom = ph + self._phantom_fast(ks, w)
        return out, phantom


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
