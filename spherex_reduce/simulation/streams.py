"""The streams of the noise tiers: kernel streams, stream groups, their generators.

`~spherex_reduce.simulation.engine.NoiseEngine` makes long slow-B tiers and
phantom sequences window by window with `KernelStream`, and draws one set of
slow streams per `StreamGroup` of components, each from generators of
`stream_rngs`.  The tier numbers (``TIER_*``) and `STREAM_SCOPES` seed the
generators (`~spherex_reduce.simulation.synthesis.rng_for`), so they must not
change.
"""

import math

import numpy as np
import scipy.fft as sfft
from scipy import signal

from .synthesis import rng_for

__all__ = ["SHARED_BELOW", "STREAM_SCOPES", "TIER_A", "TIER_B", "TIER_EXACT", "TIER_FAST",
           "TIER_PHANTOM", "TIER_SLOPE_FAST", "KernelStream", "StreamGroup", "frame_chunks",
           "periodic_functional_variance", "stream_rngs"]

#: Stream keys: the scopes, and ``acn`` for the pixels' fast tier of channel components with
#: ACN (two realisations per channel, one per column parity)
STREAM_SCOPES = {"channel": 0, "common": 1, "acn": 2}
_VIS = {"pixels": 0, "phantom": 1, "both": 2}
TIER_A, TIER_B, TIER_FAST, TIER_PHANTOM, TIER_SLOPE_FAST, TIER_EXACT = range(6)


def frame_chunks(ks, weights, size):
    """The frames ``ks`` and their weights in chunks of ``size`` frames.

    Parameters
    ----------
    ks : iterable of int
        Frame indices.
    weights : array_like or None
        One weight per frame (all 1 if None).
    size : int
        Frames per chunk.

    Yields
    ------
    frames : list of int
    weights : `numpy.ndarray`

    Examples
    --------
    >>> from spherex_reduce.simulation.streams import frame_chunks
    >>> [(k, w.tolist()) for k, w in frame_chunks(range(5), None, 2)]
    [([0, 1], [1.0, 1.0]), ([2, 3], [1.0, 1.0]), ([4], [1.0])]
    """
    ks = list(ks)
    wts = np.ones(len(ks)) if weights is None else np.asarray(weights, dtype=float)
    for i in range(0, len(ks), size):
        yield ks[i:i + size], wts[i:i + size]


def periodic_functional_variance(a, lam, m):
    """Variance of ``sum_n a_n x_n`` for the period-``m`` stream with spectral weights ``lam``.

    Parameters
    ----------
    a : array_like
        Coefficients of the samples (at most ``m``).
    lam : array_like
        Spectral weights of the stream, ``m // 2 + 1`` of them (the variance
        of the stream is ``(lam[0] + 2 lam[1:] ... ) / m``, the Nyquist bin once).
    m : int
        Period of the stream.

    Returns
    -------
    float

    Examples
    --------
    White noise of unit variance (``lam = 1``): the variance is ``sum a_n²``.

    >>> import numpy as np
    >>> from spherex_reduce.simulation.streams import periodic_functional_variance
    >>> round(periodic_functional_variance(np.array([1.0, -2.0, 0.5]), np.ones(5), 8), 12)
    5.25
    """
    spec = np.abs(sfft.rfft(a, n=m)) ** 2
    wgt = np.full(spec.size, 2.0)
    wgt[0] = 1.0
    if m % 2 == 0:
        wgt[-1] = 1.0
    return float(np.sum(wgt * lam * spec) / m)


class KernelStream:
    """Stationary Gaussian streams ``x = h * xi``, made window by window in bounded memory.

    ``h = irfft(sqrt(lam))`` is the kernel whose circular convolution with
    white noise gives the period-``m`` stream with spectral weights ``lam``;
    truncated where it holds all but ``tol`` of its energy and applied as a
    *linear* convolution, it gives an aperiodic stream with (almost) the same
    covariance, computable for any range of samples from white noise drawn in
    fixed blocks (each block its own seed), so memory does not grow with the
    exposure and the numbers do not depend on the windows asked for.

    Parameters
    ----------
    lam : array_like
        Spectral weights, ``m // 2 + 1`` of them.
    m : int
        Period of the stream the kernel is cut from.
    ns : int
        Number of independent streams.
    entropy : int
        Seed entropy of the simulation.
    key : tuple of int
        The streams' key (tier and scope numbers) in the seeds.
    dtype : numpy dtype
        Of the samples.
    tol : float
        Energy of the kernel left out.
    total : int, optional
        Samples of the whole stream (bounds the white-noise blocks).
    window : int
        Typical length of the windows asked for.

    Examples
    --------
    The windows of a stream agree wherever they overlap:

    >>> import numpy as np
    >>> from spherex_reduce.simulation.streams import KernelStream
    >>> lam = 1 / (1 + np.arange(33.0))
    >>> ks = KernelStream(lam, 64, 2, entropy=1, key=(7,), dtype=np.float64)
    >>> x, y = ks.window(0, 100), ks.window(40, 60)
    >>> x.shape, bool(np.allclose(x[40:60], y))
    ((100, 2), True)
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


class StreamGroup:
    """Components sharing scope, visibility and ACN: one set of slow streams.

    Parameters
    ----------
    key : tuple
        ``(scope, visibility, acn)`` of the components.
    comps : list of `~spherex_reduce.noise.NoiseComponent`
    nch : int
        Readout channels.

    Attributes
    ----------
    gid : int
        The group's number in the seeds.
    nstreams : int
        Streams drawn: one per channel (two with ACN) or one common stream.
    colored : bool
        Whether any component has a ``1/f`` or power-law term.

    Examples
    --------
    >>> from spherex_reduce.noise import NoiseComponent
    >>> from spherex_reduce.simulation.streams import StreamGroup
    >>> c = NoiseComponent("x", alpha=1.0, beta=0.5, gamma=0.0, exponent=1.3,
    ...                    scope="channel", visibility="both", acn=True)
    >>> g = StreamGroup(("channel", "both", True), [c], nch=4)
    >>> g.gid, g.nstreams, g.colored
    (5, 8, True)
    """

    def __init__(self, key, comps, nch):
        self.scope, self.visibility, self.acn = key
        self.comps = comps
        self.gid = STREAM_SCOPES[self.scope] * 6 + _VIS[self.visibility] * 2 + int(self.acn)
        per = 2 if self.acn else 1
        self.nstreams = nch * per if self.scope == "channel" else 1
        self.colored = any(c.beta or c.gamma for c in comps)


#: Streams whose spectra have at most this many bins share one generator per call.
SHARED_BELOW = 16384


def stream_rngs(entropy, ns, nbins, *key):
    """Per-stream generators for long streams, one shared generator for short ones.

    Parameters
    ----------
    entropy : int
        Seed entropy of the simulation.
    ns : int
        Number of streams.
    nbins : int
        Bins of their spectra: above `SHARED_BELOW`, one generator per stream.
    *key : int
        The streams' key (tier and group numbers) in the seeds.

    Returns
    -------
    `numpy.random.Generator` or list of them

    Examples
    --------
    >>> from spherex_reduce.simulation.streams import stream_rngs
    >>> type(stream_rngs(0, 3, 100, 1, 2)).__name__
    'Generator'
    >>> len(stream_rngs(0, 3, 100_000, 1, 2))
    3
    """
    if nbins <= SHARED_BELOW:
        return rng_for(entropy, *key, 1 << 30)
    return [rng_for(entropy, *key, i) for i in range(ns)]
