"""The frequency bands of the noise tiers: each PSD split into slow-A, slow-B and fast.

`~spherex_reduce.simulation.engine.NoiseEngine` splits each PSD with smooth
(cos²) crossovers at ``f_A`` and ``f_B`` into three bands (`BandPSD`); the
fast band of the components of given visibilities is `fast_psds`.  The streams
of each band are drawn on FFT grids of lengths `fft_len`.
"""

import math

import numpy as np

__all__ = ["BandPSD", "fast_psds", "fft_len"]


def fft_len(n):
    """Smallest 2-3-5-smooth integer at least ``n``.

    FFTs of such lengths are faster than of lengths with factors 7, 11, ...

    Parameters
    ----------
    n : int
        Least length.

    Returns
    -------
    int

    Examples
    --------
    >>> from spherex_reduce.simulation.tier_bands import fft_len
    >>> fft_len(7), fft_len(1000), fft_len(1001)
    (8, 1000, 1024)
    """
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


class BandPSD:
    """The sum of component PSDs times the window of one band; callable on ``f > 0``.

    The windows of the three bands add up to one at every frequency: ``A`` is
    1 below ``f_a / 2`` and falls as cos² to 0 at ``f_a``; ``fast`` is
    1 above ``f_b`` and rises from 0 at ``f_b / 2``; ``B`` is the rest.

    Parameters
    ----------
    comps : list of `~spherex_reduce.noise.NoiseComponent`
        The components summed.
    band : {'A', 'B', 'fast'}
        The band.
    f_a, f_b : float
        The crossover frequencies (Hz), ``f_a < f_b``.
    white : bool
        Whether the white terms (``alpha``, whatever the band) are added:
        they belong to the fast band.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.noise import noise_components
    >>> from spherex_reduce.simulation.tier_bands import BandPSD
    >>> comps = list(noise_components().values())
    >>> f = np.array([1.0, 8.0, 60.0, 500.0])
    >>> windows = [BandPSD(comps, band, 10.0, 100.0).window(f) for band in ("A", "B", "fast")]
    >>> np.round(windows, 3).tolist()
    [[1.0, 0.345, 0.0, 0.0], [0.0, 0.655, 0.905, 0.0], [0.0, 0.0, 0.095, 1.0]]
    >>> BandPSD(comps, "A", 10.0, 100.0).empty
    False
    """

    def __init__(self, comps, band, f_a, f_b, white=False):
        self.comps, self.band, self.f_a, self.f_b = comps, band, f_a, f_b
        self.white = white
        self.dc = sum(c.alpha for c in comps) if white else 0.0

    def window(self, f):
        """The band's window at frequencies ``f`` (between 0 and 1)."""
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
        """Whether the PSD is zero at every frequency (no term it sums is non-zero)."""
        if self.white and self.dc > 0:
            return False
        return not any(c.beta or c.gamma for c in self.comps)


def fast_psds(components, visibilities, f_a, f_b, split_acn=False):
    """The fast-band PSDs of the components of the given visibilities.

    Parameters
    ----------
    components : list of `~spherex_reduce.noise.NoiseComponent`
    visibilities : tuple of {'pixels', 'phantom', 'both'}
        The visibilities of the components summed: ``('pixels', 'both')`` for
        all that the pixels see, ``('both',)`` for those the pixels and the
        phantom reads share, ``('phantom',)`` for the phantom reads' own.
    f_a, f_b : float
        The crossover frequencies (Hz).
    split_acn : bool
        Put the channel components with ACN apart, under ``'acn'`` (their
        streams are drawn per column parity).

    Returns
    -------
    dict
        `BandPSD` (white terms included) by scope: ``'channel'``, ``'acn'``,
        ``'common'``; a scope with no such component, or only silent ones, is
        left out.

    Examples
    --------
    >>> from spherex_reduce.noise import noise_components
    >>> from spherex_reduce.simulation.tier_bands import fast_psds
    >>> comps = list(noise_components().values())  # Table 2: every channel term has ACN
    >>> sorted(fast_psds(comps, ("pixels", "both"), 10.0, 100.0))
    ['channel', 'common']
    >>> sorted(fast_psds(comps, ("pixels", "both"), 10.0, 100.0, split_acn=True))
    ['acn', 'common']
    >>> [c.name for c in fast_psds(comps, ("both",), 10.0, 100.0)["common"].comps]
    ['bias_correlated']
    """
    res = {}
    groups = {"channel": lambda c: c.scope == "channel" and not (split_acn and c.acn),
              "acn": lambda c: split_acn and c.scope == "channel" and c.acn,
              "common": lambda c: c.scope == "common"}
    for key, member in groups.items():
        comps = [c for c in components if member(c) and c.visibility in visibilities]
        psd = BandPSD(comps, "fast", f_a, f_b, white=True)
        if comps and not psd.empty:
            res[key] = psd
    return res
