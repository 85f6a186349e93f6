"""The fast tier of the pixels: full-rate streams per channel, per parity with ACN.

Above ``f_B/2`` (the fast tier of `~spherex_reduce.simulation.NoiseEngine`)
the pixels' noise is drawn at the full sample rate for a block of frames: one
stream per channel for the channel components without ACN, one common stream,
and for the channel components with ACN two independent realisations per
channel, the even columns' and the odd columns' (column parity in the read
direction: sample ``c + o`` of a read has parity ``o % 2``, phantom sample
``i`` parity ``(i - c) % 2``), as the slow tiers and the exact slopes route
have them.

With phantom reads, the components the pixels and the phantom reads both see
(visibility ``both``) get streams of their own, and the fast part of the
phantom means is the mean of those same streams over the ``c`` phantom
samples of each read: one realisation seen by both at every frequency, as in
the slow tiers.  The components only the pixels see get the other streams
(without phantom reads all are drawn together).
"""

import numpy as np

from .streams import STREAM_SCOPES, stream_rngs
from .synthesis import psd_weights, synthesize
from .tier_bands import fast_psds, fft_len

__all__ = ["PixelFastTier"]


class PixelFastTier:
    """Fast streams of the pixels of an engine's frames (or of its slope image).

    Parameters
    ----------
    engine : `~spherex_reduce.simulation.NoiseEngine`
        Gives the schedule's timing, the components, the tier frequencies and
        the seed.
    """

    def __init__(self, engine):
        self.engine = engine
        self._lam_cache = {}
        self._psds = None

    def psds(self):
        """Fast-band PSDs of the pixels' streams: ``{(scope, shared): BandPSD}``.

        ``scope`` is ``'channel'``, ``'acn'`` or ``'common'``; ``shared`` is
        True for the streams of the components the phantom reads also see
        (drawn apart only when there are phantom reads).
        """
        if self._psds is None:
            e = self.engine
            parts = (((False, ("pixels",)), (True, ("both",))) if e.c
                     else ((False, ("pixels", "both")),))
            self._psds = {(scope, shared): psd for shared, vis in parts
                          for scope, psd in fast_psds(e.components, vis, e.f_a, e.f_b,
                                                      split_acn=True).items()}
        return self._psds

    @property
    def half_rate(self):
        """Each column parity's pixel samples sit on one parity of sample index within a
        block of frames (even ``row_samples``, and even frames or one frame per block)."""
        e = self.engine
        return e.rs % 2 == 0 and (e.F % 2 == 0 or e.block == 1)

    def period(self, scope, m):
        """Period of the streams of ``scope`` for blocks of period ``m`` (made even for
        ACN drawn at half rate)."""
        if scope == "acn" and self.half_rate:
            return 2 * fft_len((m + 1) // 2)
        return m

    def weights(self, stream, psd, m):
        """Spectral weights of the stream ``(scope, shared)``, period ``m`` (cached)."""
        key = (stream, m)
        if key not in self._lam_cache:
            self._lam_cache[key] = psd_weights(psd, m, self.engine.fs)
        return self._lam_cache[key]

    def streams(self, n, m, scale, tier, *key):
        """``n`` samples (whole frames) of every fast stream, period ``m``, PSD times ``scale``.

        Returns
        -------
        pixels : dict
            ``{'channel': (nch, n), 'common': (1, n)}``, keys left out when
            silent; the channel stream sums the components without ACN and, at
            each sample, the ACN realisation of its column parity.
        phantom : `numpy.ndarray` or None
            ``(n // frame_samples, n_reads, nch or 1)``, float64: each read's
            mean over its ``c`` phantom samples of the shared streams (None if
            there are none).
        """
        e = self.engine
        res, phantom = {}, None
        for (scope, shared), psd in self.psds().items():
            ms = self.period(scope, m)
            lam = self.weights((scope, shared), psd, ms) * scale
            # the shared streams are keyed apart from the pixels' own (scopes 3, 4, 5)
            keys = (tier, STREAM_SCOPES[scope] + len(STREAM_SCOPES) * shared, *key)
            if scope == "acn":
                x, scope = self._acn(lam, ms, n, keys), "channel"
            else:
                ns = e.nch if scope == "channel" else 1
                x = synthesize(lam, ms, n, stream_rngs(e.entropy, ns, ms // 2 + 1, *keys),
                               method=e.method, dtype=e.dtype, nstreams=ns)
            if shared:
                means = self._phantom_means(x, n)
                phantom = means if phantom is None else phantom + means
            if scope in res:
                res[scope] += x
            else:
                res[scope] = x
        return res, phantom

    def _phantom_means(self, x, n):
        """Mean over the phantom samples of every read of streams ``x`` ``(ns, n)``:
        ``(frames, n_reads, ns)``, float64."""
        e = self.engine
        samples = e.schedule.phantom_samples()  # (n_reads, c) within a frame
        out = np.empty((n // e.F, e.n_reads, x.shape[0]))
        for j in range(out.shape[0]):
            out[j] = x[:, j * e.F + samples].mean(axis=-1, dtype=np.float64).T
        return out

    def _acn(self, lam, m, n, keys):
        """Channel streams ``(nch, n)`` of the ACN components: at sample ``c + o`` of a
        read the realisation of parity ``o % 2`` (two independent realisations of
        period ``m`` with spectral weights ``lam``).

        With `half_rate` each realisation is drawn only at its own samples: at
        half rate with the weights folded about ``m / 4`` (``x[2j + a]`` of a
        period-``m`` stream is a period-``m / 2`` stream with covariance
        ``c(2d)``), as cheap as one full-rate stream.  Otherwise both are drawn
        at full rate and each sample takes its parity's.
        """
        e = self.engine
        nch, c = e.nch, e.c
        if self.half_rate:
            mh = m // 2
            k = np.arange(mh // 2 + 1)
            lam_h = (lam[k] + lam[mh - k]) / 2
            nh = (n + 1) // 2
            y = synthesize(lam_h, mh, nh, stream_rngs(e.entropy, 2 * nch, mh // 2 + 1, *keys),
                           method=e.method, dtype=e.dtype, nstreams=2 * nch)
            y = y.reshape(nch, 2, nh)
            out = np.empty((nch, n), dtype=e.dtype)
            for p in (0, 1):  # parity p sits at sample indices of parity (c + p) % 2
                a = (c + p) % 2
                out[:, a::2] = y[:, p, :(n - a + 1) // 2]
            return out
        x = synthesize(lam, m, n, stream_rngs(e.entropy, 2 * nch, m // 2 + 1, *keys),
                       method=e.method, dtype=e.dtype, nstreams=2 * nch)
        x = x.reshape(nch, 2, n)
        odd = ((np.arange(n) % e.F) % e.rs - c) % 2 == 1
        return np.where(odd, x[:, 1], x[:, 0])
