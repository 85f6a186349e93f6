"""Gaussian noise streams with a given PSD: Fourier synthesis and circulant embedding.

One routine, :func:`synthesize`, draws stationary streams from *spectral
weights* ``lam_k`` (``k = 0 ... M/2``): the stream of period ``M`` has the
covariance ``c(d) = (1/M) sum_k lam_k exp(2 pi i k d / M)``.  For a one-sided
PSD ``p(f)`` sampled at ``fs`` the weights are ``p(f_k) fs / 2`` (Timmer &
König 1995 with Gaussian amplitudes); for a covariance sequence they are its
FFT (circulant embedding).  ``method='random_phase'`` uses fixed amplitudes and
uniform phases instead (the paper's eq. 2-5).

Streams are synthesised longer than needed (padding) so that they are not
periodic over the samples used: a stream whose period equals the exposure
suppresses the lowest frequencies and biases ramp slopes low.
"""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft as sfft

__all__ = ["METHODS", "covariance_from_weights", "psd_weights", "rng_for", "synthesize"]

METHODS = ("gaussian", "random_phase")
_POOL = None
WORKERS = 2


def _pool():
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="sxr-sim")
    return _POOL


def rng_for(entropy, *key):
    """A `numpy.random.Generator` for one stream, from the root entropy and a key.

    Each component group, channel, parity, tier and frame block gets its own
    ``SeedSequence(entropy, spawn_key=key)``, so the numbers drawn never
    depend on how the work is chunked or how many workers run.

    Examples
    --------
    >>> from spherex_reduce.simulation.synthesis import rng_for
    >>> a = rng_for(1234, 0, 5).standard_normal()
    >>> b = rng_for(1234, 0, 5).standard_normal()
    >>> a == b
    True
    """
    ent, base = entropy if isinstance(entropy, tuple) else (entropy, ())
    ss = np.random.SeedSequence(ent, spawn_key=(*base, *key))
    return np.random.Generator(np.random.SFC64(ss))


def psd_weights(psd, m, fs):
    """Spectral weights ``p(f_k) fs / 2`` on the grid ``f_k = k fs / m`` (``k = 0 ... m/2``).

    ``psd(f)`` is called with ``f > 0`` only; the DC weight is ``psd.dc``
    if the callable has that attribute, else 0.
    """
    k = np.arange(m // 2 + 1)
    f = k * (fs / m)
    lam = np.zeros(k.size)
    lam[1:] = psd(f[1:]) * (fs / 2)
    lam[0] = getattr(psd, "dc", 0.0) * (fs / 2)
    return lam


def covariance_from_weights(lam, m):
    """Covariance ``c(d)``, ``d = 0 ... m/2``, of the period-``m`` stream with weights ``lam``."""
    return sfft.irfft(lam, n=m)[: m // 2 + 1]


def _fill(spec, rng, method, amp, nyq_real):
    """Fill complex rows ``spec`` in place with random Fourier amplitudes from one generator."""
    flat = spec.view(spec.real.dtype)
    if method == "gaussian":
        rng.standard_normal(dtype=flat.dtype, out=flat.reshape(-1))
        spec *= amp
        spec[:, 0] = spec[:, 0].real * np.sqrt(2)
        if nyq_real:
            spec[:, -1] = spec[:, -1].real * np.sqrt(2)
    else:
        phase = rng.random(spec.shape, dtype=flat.dtype) * flat.dtype.type(2 * np.pi)
        np.multiply(np.cos(phase), amp, out=flat[:, 0::2])
        np.multiply(np.sin(phase), amp, out=flat[:, 1::2])
        spec[:, 0] = amp[0]
        if nyq_real:
            spec[:, -1] = amp[-1] * np.sign(np.cos(phase[:, -1]))


def _fill_rows(spec, rngs, method, amp, nyq_real):
    for i, rng in enumerate(rngs):
        _fill(spec[i:i + 1], rng, method, amp, nyq_real)


def synthesize(lam, m, n, rngs, *, method="gaussian", dtype=np.float32, out=None,
               nstreams=None):
    """Draw ``len(rngs)`` independent streams of ``n`` samples from spectral weights.

    Parameters
    ----------
    lam : array_like, shape ``(m // 2 + 1,)``
        Spectral weights (>= 0): ``p(f_k) fs / 2`` for a PSD, or the FFT of a
        covariance sequence (circulant embedding).
    m : int
        FFT length (the period of the synthesised streams), ``>= n``.
    n : int
        Samples returned per stream (the first ``n`` of the period).
    rngs : sequence of `numpy.random.Generator`, or one Generator
        One generator per stream (drawn in parallel threads), or one
        generator for all streams (drawn row after row: for many short
        streams, where per-stream generators would cost more than the draws).
    method : {'gaussian', 'random_phase'}
        Gaussian Fourier amplitudes (default, the right statistics), or fixed
        amplitudes with uniform random phases (the paper's eq. 2-5).
    dtype : dtype
        ``float32`` (default) or ``float64``.

    Returns
    -------
    `numpy.ndarray`, shape ``(len(rngs), n)``

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.simulation.synthesis import synthesize
    >>> lam = np.full(513, 4.0)                     # white, variance 4 per sample
    >>> rngs = [np.random.default_rng(i) for i in range(200)]
    >>> x = synthesize(lam, 1024, 1000, rngs, dtype=np.float64)
    >>> x.shape, round(float(x.var()), 1)
    ((200, 1000), 4.0)
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    dtype = np.dtype(dtype)
    cdtype = np.complex64 if dtype == np.float32 else np.complex128
    lam = np.clip(np.asarray(lam, dtype=float), 0, None)
    nb = m // 2 + 1
    if lam.shape != (nb,):
        raise ValueError(f"lam must have shape ({nb},), got {lam.shape}")
    nyq_real = m % 2 == 0
    if method == "gaussian":
        amp = np.sqrt(m * lam / 2)
    else:
        amp = np.sqrt(m * lam)
    amp = amp.astype(dtype)
    shared = isinstance(rngs, np.random.Generator)
    if shared:
        if nstreams is None:
            raise ValueError("give nstreams with a shared generator")
        ns = nstreams
    else:
        ns = len(rngs)
    if out is None:
        out = np.empty((ns, n), dtype=dtype)
    chunk = max(1, min(ns, (1 << 22) // nb))
    for s0 in range(0, ns, chunk):
        s1 = min(ns, s0 + chunk)
        spec = np.empty((s1 - s0, nb), dtype=cdtype)
        if shared:
            _fill(spec, rngs, method, amp, nyq_real)
        elif s1 - s0 > 1 and nb > 4096:
            half = (s1 - s0 + 1) // 2
            futs = [_pool().submit(_fill_rows, spec[:half], rngs[s0:s0 + half], method, amp,
                                   nyq_real),
                    _pool().submit(_fill_rows, spec[half:], rngs[s0 + half:s1], method, amp,
                                   nyq_real)]
            for f in futs:
                f.result()
        else:
            _fill_rows(spec, rngs[s0:s1], method, amp, nyq_real)
        x = sfft.irfft(spec, n=m, axis=-1, workers=WORKERS, overwrite_x=True)
        out[s0:s1] = x[:, :n]
    return out
