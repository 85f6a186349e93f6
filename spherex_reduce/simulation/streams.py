"""Building blocks of the noise tiers: band-limited PSDs, kernel streams, stream groups.

`~spherex_reduce.simulation.NoiseEngine` splits each PSD into the
slow-A, slow-B and fast tiers with `_PSD` windows (`_fast_psds`: the fast tier
of the pixels or of the phantom means), makes long slow-B tiers
and phantom sequences window by window with `_KernelStream`, and draws one set
of slow streams per `_Group` of components.  The tier numbers seed the
generators (`~spherex_reduce.simulation.synthesis.rng_for`), so they must not
change.
"""

import math

import numpy as np
import scipy.fft as sfft
from scipy import signal

from .synthesis import rng_for

#: Stream keys: the scopes, and ``acn`` for the pixels' fast tier of channel components with
#: ACN (two realisations per channel, one per column parity)
_SCOPE = {"channel": 0, "common": 1, "acn": 2}
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


def _fast_psds(components, kind, f_a, f_b, split_acn=False):
    """Fast-tier PSDs ``{'channel': psd, 'common': psd}`` of the components ``kind`` sees.

    ``kind`` is ``'pixels'`` or ``'phantom'``; a scope with no such component, or
    only silent ones, is left out.  ``split_acn`` puts the channel components
    with ACN apart, under ``'acn'`` (their streams are drawn per column parity).
    """
    res = {}
    groups = {"channel": lambda c: c.scope == "channel" and not (split_acn and c.acn),
              "acn": lambda c: split_acn and c.scope == "channel" and c.acn,
              "common": lambda c: c.scope == "common"}
    for key, member in groups.items():
        comps = [c for c in components if member(c) and
                 (c.seen_by_pixels if kind == "pixels" else c.seen_by_phantom)]
        psd = _PSD(comps, "fast", f_a, f_b, white=True)
        if comps and not psd.empty:
            res[key] = psd
    return res


def _chunks(ks, weights, size):
    """``(frames, weights)`` of ``ks`` in chunks of ``size`` frames (weights 1 if None)."""
    ks = list(ks)
    wts = np.ones(len(ks)) if weights is None else np.asarray(weights, dtype=float)
    for i in range(0, len(ks), size):
        yield ks[i:i + size], wts[i:i + size]


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


#: Streams whose spectra have at most this many bins share one generator per call.
SHARED_BELOW = 16384


def _rngs(entropy, ns, nbins, *key):
    """Per-stream generators for long streams, one shared generator for short ones."""
    if nbins <= SHARED_BELOW:
        return rng_for(entropy, *key, 1 << 30)
    return [rng_for(entropy, *key, i) for i in range(ns)]
