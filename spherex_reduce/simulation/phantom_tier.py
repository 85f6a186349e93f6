"""The fast part of the phantom-only noise of the phantom means: one sequence over reads per scope.

The phantom value of a read is the mean of its ``c`` samples.  The part above
``f_B/2`` (the fast tier of `~spherex_reduce.simulation.NoiseEngine`) of the
components only the phantom reads see (visibility ``phantom``) is drawn on a
grid of reads, one value per row read, with the exact covariance of that
mean: the fast-tier autocovariance summed over the pairs of samples of two
reads, and with ACN only over pairs of the same parity (the same realisation).
The fast part of the components the pixels see too (``both``) is not here:
it is the mean of the pixels' own fast streams over the phantom samples
(`~spherex_reduce.simulation.pixel_fast_tier`), so pixels and phantom reads
see one realisation.
Long or large exposures make the sequence window by window (a `KernelStream`),
so memory does not grow with the exposure.
"""

import math

import numpy as np
import scipy.fft as sfft

from .streams import STREAM_SCOPES, TIER_PHANTOM, KernelStream, frame_chunks, stream_rngs
from .synthesis import covariance_from_weights, psd_weights, synthesize
from .tier_bands import BandPSD, fast_psds

__all__ = ["PhantomTier"]


class PhantomTier:
    """The fast part of the phantom-only noise of the phantom means of an engine's frames.

    Parameters
    ----------
    engine : `~spherex_reduce.simulation.NoiseEngine`
        Gives the schedule's timing, the components, the tier frequencies, the
        seed and whether to stream.
    """

    def __init__(self, engine):
        self.engine = engine
        self._sequences = None
        self._windows = {}

    def _fast_covariance(self, psd, max_lag):
        """Autocovariance of a fast-tier stream at lags 0 ... max_lag (samples)."""
        e = self.engine
        m = sfft.next_fast_len(max(4 * max_lag, 8 * e.l_corr, 1024))
        lam = psd_weights(psd, m, e.fs)
        return covariance_from_weights(lam, m)[: max_lag + 1]

    def psds(self):
        """Fast-band PSDs of the phantom-only components by scope (none without phantom reads)."""
        e = self.engine
        return fast_psds(e.components, ("phantom",), e.f_a, e.f_b) if e.c else {}

    def sequences(self):
        """The sequences on the grid of reads: ``{scope: stream}``.

        Each stream is an array ``(ns, J)`` or, when streaming, a ``KernelStream``.
        """
        if self._sequences is not None:
            return self._sequences
        e = self.engine
        res = {}
        if e.c:
            g_lag = math.ceil(2 * e.l_corr / e.rs) + 2
            jp = e.exposure // e.rs + 2
            mp = sfft.next_fast_len(max(jp + g_lag, 2 * g_lag + 2))
            if e.streaming:
                mp = sfft.next_fast_len(8 * g_lag + 2)
            i = np.arange(e.c)
            dd = (i[:, None] - i[None, :]).ravel()
            same = (((i - e.c) % 2)[:, None] == ((i - e.c) % 2)[None, :]).ravel()
            lags = np.abs(np.arange(g_lag + 1)[:, None] * e.rs + dd[None, :])
            for scope in self.psds():
                # covariance of the mean of the c samples; with ACN only samples of the
                # same parity (the same realisation) are correlated
                r = np.zeros(g_lag + 1)
                for acn in (False, True):
                    comps = [c for c in e.components if c.scope == scope and
                             c.visibility == "phantom" and c.acn == acn]
                    psd = BandPSD(comps, "fast", e.f_a, e.f_b, white=True)
                    if not comps or psd.empty:
                        continue
                    cf = self._fast_covariance(psd, g_lag * e.rs + e.c)
                    pairs = cf[lags] * (same if acn else 1.0)
                    r += pairs.sum(axis=1) / e.c**2
                emb = np.zeros(mp)
                emb[: g_lag + 1] = r
                emb[mp - g_lag:] = r[1:][::-1]
                lam = sfft.rfft(emb).real
                ns = e.nch if scope == "channel" else 1
                if e.streaming:
                    res[scope] = KernelStream(lam, mp, ns, e.entropy,
                                               (TIER_PHANTOM, STREAM_SCOPES[scope]), np.float32,
                                               total=jp, window=e.CHUNK * e.F // e.rs)
                    continue
                rngs = stream_rngs(e.entropy, ns, mp // 2 + 1, TIER_PHANTOM, STREAM_SCOPES[scope])
                res[scope] = synthesize(lam, mp, jp, rngs, method=e.method,
                                        dtype=np.float32, nstreams=ns)
        self._sequences = res
        return res

    def _index(self, k):
        """Positions on the grid of the reads of frame ``k``."""
        e = self.engine
        return (k * e.F) // e.rs + np.arange(e.n_reads)

    def values(self, ks, weights=None):
        """Sum over frames ``ks`` (weighted by ``weights``) of the phantom means' fast part.

        Returns ``(n_reads, nch)``.
        """
        e = self.engine
        out = np.zeros((e.n_reads, e.nch))
        for scope, x in self.sequences().items():
            acc = np.zeros((e.n_reads, e.nch if scope == "channel" else 1))
            for kc, wc in frame_chunks(ks, weights, e.CHUNK):
                if isinstance(x, KernelStream):
                    cache_ks = kc
                    if len(kc) == 1:
                        q = kc[0] // e.CHUNK
                        cache_ks = range(q * e.CHUNK, min(e.N, (q + 1) * e.CHUNK))
                    j0 = self._index(min(cache_ks))[0]
                    j1 = self._index(max(cache_ks))[-1] + 1
                    cached = self._windows.get(scope)
                    if cached is None or cached[0] != (j0, j1):
                        cached = self._windows[scope] = ((j0, j1), x.window(j0, j1))
                    win = cached[1]
                    for k, wk in zip(kc, wc, strict=True):
                        acc += wk * win[self._index(k) - j0]
                else:
                    for k, wk in zip(kc, wc, strict=True):
                        acc += wk * x[:, self._index(k)].T
            out += acc  # (n_reads, ns) broadcasts for common
        return out
