"""The forecast through the ``wiener`` reference strategy: a drift estimate at every read.

The strategy (`~spherex_reduce.reduce.steps.reference.wiener.WienerReference`) subtracts
from each read of channel ``ch`` (and parity group ``g``) the estimate
``w @ y_ch + wd @ mean_ch(y)`` of the channel's drift, linear in its
observations ``y``: the value of every reference read and, when it estimates
from them, the phantom value of every read.  Its weights come from the
strategy itself (`~spherex_reduce.reduce.steps.reference.wiener.WienerReference.read_weights`:
the same code, for the strategy's own noise model); the forecast propagates
them under the scene's noise.  With ``side_columns`` the estimate also adds
``ws @ s`` (`~spherex_reduce.reduce.steps.reference.wiener.WienerReference.side_weights`),
``s`` the mean over the side channels of their side pixels at every light row's read:
one term per side channel, its column factor the sum of every channel's phases.

The correction of cell ``(k_y, k_x)`` is a sum over *terms* ``t`` (family ``w``
or ``wd``, group, observation kind)::

    C = sum_t sum_ch beta_t(ch, k_x) sum_a M_t(k_y, a) y_{ch,t}[a]

``beta_t`` the phases of the group's light columns (for ``wd`` their sum over
channels over the number of channels, the same for every channel),
``M_t(k_y, a) = sum_p exp(-i k_y p) w[r(p), a]`` (an FFT over light rows) and
``y_{ch,t}[a]`` a read functional of the stream at the observation's read slot.
``E|U - C|²`` then needs the cross terms ``E[U C*]``, sums over slot lags of
``G_t(k_y, m) = sum_{slot(p) - slot(a) = m} exp(-i k_y p) conj M_t(k_y, a)`` (FFTs
over slots) times the pixel-observation correlation, and ``E[C C*]``: the
column factor ``sum_ch beta_t conj beta_t'`` times ``sum_{a,b} M_t(a) K(slot(a) -
slot(b)) conj M_t'(b)``, ``K`` the covariance of two observations, done by FFTs
over slots (Parseval).
"""

from dataclasses import dataclass

import numpy as np
import scipy.fft

from ...core.block import Context
from ...reduce.steps.reference.strategies import group_columns
from ...reduce.steps.reference.wiener import WienerReference
from .functionals import Part, channel_sums, column_phases

__all__ = ["WienerTerms"]


@dataclass
class _Term:
    """One term of the correction: its column factor ``(nch, nkx)``, the functional of
    its observations (pixel part, phantom part or None, each ``(c + width,)``), the FFT
    over slots of ``M_t`` (``(nky, 2 slots)``) and ``G_t`` as the lag table's
    ``far_weights``."""

    key: tuple
    beta: np.ndarray
    psi: tuple
    fm: np.ndarray
    g_near: np.ndarray
    g_far: np.ndarray


class WienerTerms:
    """The terms of a ``wiener`` correction for the cells of one forecast.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    rows, cols : slice
        The light-sensitive rectangle.
    ky, kx : `numpy.ndarray`
        The cells' row and column indices (as `~spherex_reduce.analysis.forecast.rows.Cells`).
    c : int
        Phantom samples per read (the offset of pixel offset 0 in a functional).
    reduction : `~spherex_reduce.analysis.forecast.steps.Reduction`
    slots : `numpy.ndarray`
        The slot of every read.
    light_reads : `numpy.ndarray`
        The read of every light-sensitive row.
    table
        The forecast's table of slope covariances at every slot lag.
    """

    def __init__(self, schedule, rows, cols, ky, kx, c, reduction, slots, light_reads,
                 table):
        s = schedule
        g = s.geometry
        ny = rows.stop - rows.start
        strategy = WienerReference(**reduction.reference_params)
        context = Context(s, "readout", reduction.reference_ramps,
                          has_phantom=not reduction.reference_phantom)
        strategy.check_data(context)
        groups = group_columns(g, strategy.acn)
        nch, width = g.nchannels, g.channel_width
        n = 2 * (int(slots.max()) + 1)
        refs = s.reference_read_indices
        j, phase = column_phases(g, cols, kx)  # (nx, nkx)
        offsets = g.column_offsets()
        row_phase = np.exp(-2j * np.pi * np.outer(ky, np.arange(ny)) / ny)  # (nky, ny)
        light = np.zeros((len(ky), n), dtype=complex)
        light[:, slots[light_reads]] = row_phase
        f_light = scipy.fft.fft(light, axis=1, workers=-1)
        self.n, self.terms, self._pairs = n, [], {}
        for p in range(groups.shape[1]):
            w, wd, kind, phantom = strategy.read_weights(context, p)
            group_cols = groups[0, p][groups[0, p] >= 0]
            in_group = offsets[j] % 2 == p if strategy.acn else np.ones(j.size, bool)
            box = channel_sums(g, j, phase, in_group)
            ref_psi = np.zeros(c + width)
            ref_psi[c + offsets[group_cols]] = 1.0 / group_cols.size
            ref_ph = None
            if kind == "subtracted" and c:
                ref_ph = np.zeros(c + width)
                ref_ph[:c] = -1.0 / c
            kinds = [("ref", (ref_psi, ref_ph), refs, slice(0, refs.size))]
            if phantom:
                ph_psi = np.zeros(c + width)
                ph_psi[:c] = 1.0 / c
                kinds.append(("phantom", (np.zeros(c + width), ph_psi),
                              np.arange(s.n_reads), slice(refs.size, None)))
            families = [("w", w, box)]
            if wd is not None:
                families.append(("wd", wd, np.broadcast_to(box.sum(axis=0) / nch, box.shape)))
            for fam, weights, beta in families:
                v = scipy.fft.fft(weights[light_reads], axis=0, workers=-1)[np.asarray(ky)]
                for name, psi, reads, cols_of in kinds:
                    self._add((p, fam, name), beta, psi, v[:, cols_of], slots[reads], f_light,
                              table)
            if strategy.side_groups(g) is not None:
                ws, side_reads, sides = strategy.side_weights(context, p)
                # the side value is the mean over side channels of each one's side pixels'
                # mean, added to every channel alike: one term per side channel
                v = scipy.fft.fft(ws[light_reads], axis=0, workers=-1)[np.asarray(ky)]
                for ch, side_cols in sides:
                    beta = np.zeros_like(box)
                    beta[ch] = box.sum(axis=0) / len(sides)
                    psi = np.zeros(c + width)
                    psi[c + offsets[side_cols]] = 1.0 / side_cols.size
                    self._add((p, "ws", f"side{ch}"), beta, (psi, ref_ph), v,
                              slots[side_reads], f_light, table)

    def _add(self, key, beta, psi, v, obs_slots, f_light, table):
        """A term of weights ``v`` (FFT over light rows, ``(nky, nobs)``) on observations at
        slots ``obs_slots``."""
        m = np.zeros((v.shape[0], self.n), dtype=complex)
        m[:, obs_slots] = v
        fm = scipy.fft.fft(m, axis=1, workers=-1)
        gt = scipy.fft.ifft(f_light * fm.conj(), axis=1, workers=-1)
        self.terms.append(_Term(key, beta, psi, fm, *table.far_weights(gt)))

    def functional(self, term):
        """The term's observations as a functional of each channel at each ``k_x``
        (``beta`` times ``psi``: `~spherex_reduce.analysis.forecast.rows.Part`)."""
        return [Part(n == 1, amp=term.beta, profile=part)
                for n, part in enumerate(term.psi) if part is not None]

    def plane(self, table, spectra, i, comp, light, lags):
        """``-2 Re E[U C*] + E[C C*]`` of component ``i`` on the cells, ``(nky, nkx)``;
        ``lags`` keeps the spectra of the observations' covariances for other chunks."""
        out = 0.0
        for t in self.terms:
            x = spectra.correlate(("light", light), (("wiener", *t.key), self.functional(t)),
                                  comp)
            out = out - 2 * table.split_products(i, t.g_near, t.g_far, x).real
        one = {t.key: [Part(n == 1, amp=np.ones((1, 1)), profile=part)
                       for n, part in enumerate(t.psi) if part is not None]
               for t in self.terms}
        for n, t in enumerate(self.terms):
            for u in self.terms[n:]:  # the pair (u, t) is the conjugate of (t, u)
                if comp.scope == "common":
                    b = t.beta.sum(axis=0) * u.beta.sum(axis=0).conj()
                else:
                    b = np.sum(t.beta * u.beta.conj(), axis=0)
                if (i, t.key, u.key) not in lags:
                    x = spectra.correlate((("psi", *t.key), one[t.key]),
                                          (("psi", *u.key), one[u.key]), comp)
                    lags[i, t.key, u.key] = scipy.fft.fft(table.lag_values(i, x[0], self.n))
                fk = lags[i, t.key, u.key]
                if (t.key, u.key) not in self._pairs:  # the same for every component
                    self._pairs[t.key, u.key] = t.fm * u.fm.conj()
                d = self._pairs[t.key, u.key] @ fk.conj() / self.n
                out = out + (1 if u is t else 2) * (d[:, None] * b[None, :]).real
        return out
