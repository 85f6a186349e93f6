"""Functionals of the samples of one read, and their correlations over offsets.

A functional ``f(k_x, s)`` weighs, for each channel and column wave number, the
samples of one read by their offset ``s``; it is a list of `Part`: dense (the
pixels' phases) or separable (an amplitude per channel and ``k_x`` times a
profile over offsets: a phantom value, a mean of reference pixels, a drift
estimate's observation).  `Correlations` computes ``X(k_x, d) = sum_s f_a(k_x,
s + d) conj f_b(k_x, s)`` for the noise components of the forecast
(`spherex_reduce.analysis.forecast.rows`).
"""

from dataclasses import dataclass

import numpy as np
import scipy.fft

from ...core.recently_used import RecentlyUsed

__all__ = ["Correlations", "Part", "channel_sums", "column_phases"]


#: Phase tables `column_phases` keeps (a search forecasts the same columns and cells for
#: every readout it tries; a full-size band's table is ~3 MB, a whole plane's ~34 MB).
PHASE_TABLES = 2
_phases = RecentlyUsed(PHASE_TABLES)


def column_phases(geometry, cols, kx):
    """The light columns ``j`` and their phases ``exp(-i k_x (j - j0))`` ``(nx, nkx)``,
    ``k_x = 2 pi kx / nx`` for the rfft column indices ``kx`` of the rectangle ``cols``
    (read-only arrays: the last `PHASE_TABLES` are kept and shared)."""
    kx = np.asarray(kx)
    key = (cols.start, cols.stop, kx.dtype.str, kx.tobytes())
    return _phases.get(key, lambda: _phases_of(cols, kx))


def _phases_of(cols, kx):
    j = np.arange(cols.start, cols.stop)
    k = 2 * np.pi * kx / j.size
    out = j, np.exp(-1j * np.outer(j - cols.start, k))
    for a in out:
        a.setflags(write=False)
    return out


def channel_sums(geometry, j, phase, used):
    """Per channel, the sum of the phases of the light columns ``j[used]``: ``(nch, nkx)``."""
    box = np.zeros((geometry.nchannels, phase.shape[1]), dtype=complex)
    np.add.at(box, geometry.channel_of_column()[j][used], phase[used])
    return box


@dataclass(frozen=True)
class Part:
    """One part of a functional, seen by the pixels or by the phantom samples: separable,
    ``amp[ch, k_x] * profile[s]``, or ``dense[ch, k_x, s]``."""

    phantom: bool
    amp: np.ndarray | None = None
    profile: np.ndarray | None = None
    dense: np.ndarray | None = None

    def seen(self, comp):
        """Whether component ``comp`` is in the samples of this part."""
        return comp.seen_by_phantom if self.phantom else comp.seen_by_pixels


class Correlations:
    """Correlations ``X`` of functionals, from the FFTs over offsets of their parts, each
    taken once: a dense part costs a pass over its ``(nch, nkx, 2 n)`` spectrum per other
    part, a separable one a product of its amplitudes and its profile's spectrum."""

    def __init__(self):
        self._ffts, self._products, self._x = {}, {}, {}

    def fork(self):
        """A `Correlations` that starts with the spectra computed so far and keeps those it
        computes to itself (functionals of the same key must be the same in both)."""
        out = Correlations()
        out._ffts, out._products, out._x = dict(self._ffts), dict(self._products), dict(self._x)
        return out

    def _fft(self, key, i, part, common):
        """``('dense', F)`` or ``('sep', amp, P)`` of part ``i`` of functional ``key``
        (summed over channels for ``common``)."""
        if (key, i, common) not in self._ffts:
            n = part.profile.size if part.dense is None else part.dense.shape[-1]
            if part.dense is not None:
                f = (self._fft(key, i, part, False)[1].sum(axis=0, keepdims=True) if common
                     else scipy.fft.fft(part.dense, 2 * n, axis=-1, workers=-1))
                out = ("dense", f)
            else:
                amp = part.amp.sum(axis=0, keepdims=True) if common else part.amp
                out = ("sep", amp, scipy.fft.fft(part.profile, 2 * n))
            self._ffts[key, i, common] = out
        return self._ffts[key, i, common]

    def _product(self, a, i, b, j, common):
        """``sum_ch F_a,i conj F_b,j`` ``(nkx, 2 n)`` (of the channel sums for ``common``)."""
        key = (a[0], i, b[0], j, common)
        if key not in self._products:
            fa = self._fft(a[0], i, a[1][i], common)
            fb = self._fft(b[0], j, b[1][j], common)
            if fa[0] == "dense" and fb[0] == "dense":
                p = ((fa[1].real**2 + fa[1].imag**2).sum(axis=0) if (a[0], i) == (b[0], j)
                     else (fa[1] * fb[1].conj()).sum(axis=0))
            elif fa[0] == "dense":
                p = np.einsum("ckq,ck->kq", fa[1], fb[1].conj()) * fb[2].conj()
            elif fb[0] == "dense":
                p = np.einsum("ck,ckq->kq", fa[1].conj(), fb[1]).conj() * fa[2]
            else:
                p = np.outer((fa[1] * fb[1].conj()).sum(axis=0), fa[2] * fb[2].conj())
            self._products[key] = p
        return self._products[key]

    def correlate(self, a, b, comp):
        """``X(k_x, d) = sum_s f_a(k_x, s + d) conj f_b(k_x, s)``, ``d = -(n - 1) ...
        n - 1``, for the functionals ``a`` and ``b`` (``(key, parts)``), of what ``comp``
        sees, summed over channels (channel scope) or of the sums over channels (common
        scope); with ACN only offsets of one parity correlate."""
        common = comp.scope == "common"
        use_a = [i for i, part in enumerate(a[1]) if part.seen(comp)]
        use_b = [j for j, part in enumerate(b[1]) if part.seen(comp)]
        key = (a[0], b[0], tuple(use_a), tuple(use_b), common)
        if key not in self._x:
            first = a[1][0]
            n = first.profile.size if first.dense is None else first.dense.shape[-1]
            nkx = (first.amp if first.dense is None else first.dense).shape[1]
            if use_a and use_b:
                total = sum(self._product(a, i, b, j, common) for i in use_a for j in use_b)
                x = scipy.fft.ifft(total, axis=-1, workers=-1)
                x = x[:, np.arange(-(n - 1), n) % (2 * n)]
            else:
                x = np.zeros((nkx, 2 * n - 1), dtype=complex)
            self._x[key] = x
        x = self._x[key]
        if comp.acn:
            n = (x.shape[1] + 1) // 2
            x = np.where(np.arange(-(n - 1), n) % 2 == 0, x, 0.0)
        return x
