"""The engine of the noise forecast: ``E|FFT|²`` of a reduced slope image, cell by cell.

Every correction the forecast propagates subtracts from a pixel a linear
combination of samples of the same noise streams: its read's phantom value
(the mean of the ``c`` samples just before the read) and a reference offset
(the mean of the reference pixels of the channel, themselves minus their
reads' phantom values).  A sample is taken at ``slot R + s``: the read's slot
``slot``, ``R`` samples per row read, and its offset ``s`` within the read
(``-c ... -1`` phantom, ``0 ... width - 1`` pixels).  So a row of the image
transforms, for each channel, into a *functional* ``f(k_x, s)`` of the offsets
of one read (the pixels' phases, minus the channel's phase sum over ``c`` at
the phantom offsets), the same for every light-sensitive row, and::

    E|Y(k_y, k_x)|² = sum_m A(k_y, m) sum_d X(k_x, d) S(m R + d)

with ``A`` the autocorrelation over read slots of ``exp(-i k_y p)``, ``X`` that
of ``f`` over offsets (summed over channels for channel-scope noise, of the sum
over channels for common noise, same-parity offsets only with ACN) and ``S``
the slope covariance (`~spherex_reduce.noise.variance.slope_covariance`).  A
reference offset is the same for every row of a channel, so it changes only
the ``k_y = 0`` row of the plane (the light rows' phases sum to zero at any
other ``k_y``); there the reference reads enter as a second kind of read with
their own functional, and the cross and reference-reference terms are sums of
the same form over the slot lags between a light row and a reference read
(``H_LR``) and between two reference reads (``H_RR``).

The sum over ``d`` is exact for the ``m`` near a singularity of ``S`` (``m R``
within `NEAR_READS` row reads of a multiple of the frame time); for the others
``S(m R + d)`` is smooth in ``d`` over one read and is interpolated on `NODES`
Chebyshev nodes rounded to whole offsets.  The cells can be restricted to
some ``k_y`` rows and ``k_x`` columns (`band_cells`): the cost is then that
of those cells only.
"""

from dataclasses import dataclass

import numpy as np
import scipy.fft

from ..core.errors import SpherexReduceError
from ..noise.variance import slope_covariance

__all__ = ["NEAR_READS", "NODES", "Cells", "component_planes"]

#: Row reads from a multiple of the frame time within which the sum over offsets is exact.
NEAR_READS = 4
#: Chebyshev nodes over the offsets beyond (the rule is exact for polynomials of lower degree).
NODES = 8


@dataclass(frozen=True)
class Cells:
    """Which cells of the rfft2 plane of an ``(ny, nx)`` image to compute.

    Attributes
    ----------
    ky : `numpy.ndarray`
        Row indices ``i`` (``k_y = 2 pi i / ny``, ``0 <= i < ny``), increasing.
    kx : `numpy.ndarray`
        Column indices ``i`` of the rfft (``k_x = 2 pi i / nx``, ``0 <= i <= nx // 2``).
    """

    ky: np.ndarray
    kx: np.ndarray

    @classmethod
    def full(cls, ny, nx):
        """Every cell of the rfft2 plane."""
        return cls(np.arange(ny), np.arange(nx // 2 + 1))


def component_planes(schedule, rows, cols, comps, reduction, nodes=NODES, cells=None):
    """``{name: E|FFT|²}`` of the reduced light-sensitive image for each component.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    rows, cols : slice
        The light-sensitive rectangle (`~spherex_reduce.analysis.light_sensitive`).
    comps : list of `~spherex_reduce.noise.NoiseComponent`
    reduction : `~spherex_reduce.analysis.forecast_steps.Reduction`
    nodes : int
        Chebyshev nodes of the rule over offsets.
    cells : `Cells`, optional
        The cells to compute (default: the whole rfft2 plane).

    Returns
    -------
    dict
        ``{name: ndarray (len(cells.ky), len(cells.kx))}`` in (e/s)² (the
        rfft2 layout when ``cells`` is the whole plane).
    """
    g = schedule.geometry
    ny, nx = rows.stop - rows.start, cols.stop - cols.start
    cells = Cells.full(ny, nx) if cells is None else cells
    c = schedule.phantom_reads if (reduction.phantom or reduction.reference_phantom) else 0
    table = _LagTable(schedule, comps, g.channel_width - 1 + c, nodes)
    a = _row_pairs(schedule, rows, cells.ky)  # (n_half, 2 slots), n_half rows of k_y >= 0
    light = _functionals(schedule, rows, cols, cells.kx, c, reduction)
    ref = _reference_functionals(schedule, cols, cells.kx, c, reduction, ny)
    has_zero = cells.ky.size and cells.ky[0] == 0
    if ref is not None and has_zero:
        h_lr, h_rr = _reference_pairs(schedule, rows, a.shape[1] // 2)
    half = np.minimum(cells.ky, ny - cells.ky)
    first = np.searchsorted(np.unique(half), half)  # row of a for every cell row
    negative = cells.ky > ny // 2
    parts = {}
    for i, comp in enumerate(comps):
        f_l = _pick(light, comp, reduction.phantom)
        x = _correlate(f_l, f_l, comp)
        re, im = table.real_products(i, a, x)
        parts[comp.name] = np.where(negative[:, None], re[first] + im[first],
                                    re[first] - im[first])
        if ref is not None and has_zero:
            f_r = _pick(ref, comp, reduction.reference_phantom)
            cross = table.products(i, h_lr, _correlate(f_l, f_r, comp))
            auto = table.products(i, h_rr, _correlate(f_r, f_r, comp))
            parts[comp.name][0] += 2 * cross.real + auto.real
    return parts


class _LagTable:
    """``S(m R + d)`` of each component at every read-slot lag ``m`` and offset
    difference ``d`` (``|d| <= half``): exact near a singularity, on Chebyshev nodes
    elsewhere."""

    def __init__(self, schedule, comps, half, nodes):
        s = schedule
        rs, frame = s.row_samples, s.frame_samples
        slots = _slots(s).max() + 1
        m = np.arange(-(slots - 1), slots)
        dist = np.min(np.abs(m[:, None] * rs - np.array([-frame, 0, frame])[None, :]), axis=1)
        near = dist < NEAR_READS * rs
        self.near, self.far = m[near] % (2 * slots), m[~near] % (2 * slots)
        d = np.arange(-half, half + 1)
        self.interp, dnodes = _chebyshev_rule(half, nodes)
        lags = np.concatenate([(m[near][:, None] * rs + d[None, :]).ravel(),
                               (m[~near][:, None] * rs + dnodes[None, :]).ravel()])
        lags, inverse = np.unique(np.abs(lags), return_inverse=True)  # S is even
        cov = slope_covariance(comps, s, lags)[:, inverse.ravel()] if comps else None
        nnear = near.sum() * d.size
        self.s_near = [cov[i, :nnear].reshape(near.sum(), d.size) for i in range(len(comps))]
        self.s_far = [cov[i, nnear:].reshape((~near).sum(), dnodes.size)
                      for i in range(len(comps))]

    def _q(self, i, x):
        """``sum_d X(k_x, d) S(m R + d)`` as (near ``(n_near, nkx)``, far-on-nodes
        ``(n_far, nodes)`` and the nodes' weights ``(nodes, nkx)``)."""
        return self.s_near[i] @ x.T, self.s_far[i], (x @ self.interp).T

    def real_products(self, i, w, x):
        """``Re w`` times the real and ``Im w`` times the imaginary part of ``sum_m w(m)
        sum_d X(k_x, d) S(m R + d)``, for ``w`` ``(n, 2 slots)``: with ``w(-k_y) =
        conj w(k_y)`` and ``X`` Hermitian in ``d``, ``re - im`` and ``re + im`` are the
        cells of ``k_y`` and ``-k_y``."""
        q_near, s_far, nodes = self._q(i, x)
        w_near, w_far = w[:, self.near], w[:, self.far] @ s_far
        re = w_near.real @ q_near.real + w_far.real @ nodes.real
        im = w_near.imag @ q_near.imag + w_far.imag @ nodes.imag
        return re, im

    def products(self, i, w, x):
        """``sum_m w(m) sum_d X(k_x, d) S(m R + d)`` for a weight vector ``w`` ``(2 slots,)``
        (complex result, ``(nkx,)``)."""
        q_near, s_far, nodes = self._q(i, x)
        return w[self.near] @ q_near + (w[self.far] @ s_far) @ nodes


def _slots(s):
    """The slot (row-read time over the row time) of every read of a frame."""
    return (s.starts - s.phantom_reads) // s.row_samples


def _row_pairs(schedule, rows, ky):
    """``A(k_y, m)`` for the distinct ``min(i, ny - i)`` of ``ky`` and read-slot lag ``m``
    (index ``m mod 2 slots``): the autocorrelation over read slots of ``exp(-i k_y p)``."""
    s = schedule
    slot = _slots(s)
    slots = int(slot.max()) + 1
    first = _light_reads(s, rows)
    ny = rows.stop - rows.start
    k = 2 * np.pi * np.unique(np.minimum(ky, ny - ky)) / ny
    g = np.zeros((k.size, 2 * slots), dtype=complex)
    g[:, slot[first]] = np.exp(-1j * k[:, None] * np.arange(ny)[None, :])
    f = scipy.fft.fft(g, axis=1, workers=-1)
    f = f.real**2 + f.imag**2
    return scipy.fft.ifft(f, axis=1, workers=-1)


def _light_reads(s, rows):
    """The read of every light-sensitive row (refused unless read once, as an active row)."""
    first = s.read_of_row()[rows]
    if np.any(first < 0) or np.any(s.is_reference[first]):
        raise SpherexReduceError("forecast: a light-sensitive row is not read as an active row")
    return first


def _reference_pairs(schedule, rows, slots):
    """``H_LR(m)``, the pairs (light row, reference read) whose slots differ by ``m``, and
    ``H_RR(m)``, the pairs of reference reads (index ``m mod 2 slots``)."""
    s = schedule
    slot = _slots(s)
    light = np.zeros(2 * slots)
    light[slot[_light_reads(s, rows)]] = 1.0
    ref = np.zeros(2 * slots)
    np.add.at(ref, slot[s.is_reference], 1.0)
    fl, fr = scipy.fft.rfft(light), scipy.fft.rfft(ref)
    n = 2 * slots
    return (np.rint(scipy.fft.irfft(fl * fr.conj(), n)),
            np.rint(scipy.fft.irfft(fr * fr.conj(), n)))


def _functionals(schedule, rows, cols, kx, c, reduction):
    """The light rows' functional of each channel, ``(nch, nkx, c + width)`` complex, as its
    pixel part and its phantom part (None without phantom subtraction): the pixels' phases
    ``sum_{o_j = o} exp(-i k_x j)`` at offset ``o`` (index ``c + o``) and minus the channel's
    phase sum over ``c`` at each phantom sample."""
    g = schedule.geometry
    nx = cols.stop - cols.start
    width, nch = g.channel_width, g.nchannels
    j = np.arange(cols.start, cols.stop)
    off, chan = g.column_offsets()[j], g.channel_of_column()[j]
    k = 2 * np.pi * kx / nx
    phase = np.exp(-1j * np.outer(j - cols.start, k))  # (nx, nkx)
    pix = np.zeros((nch, k.size, c + width), dtype=complex)
    np.add.at(pix, (chan, slice(None), c + off), phase)
    phantom = None
    if reduction.phantom and c:
        phantom = np.zeros_like(pix)
        phantom[:, :, :c] = -pix.sum(axis=2, keepdims=True) / c
    return pix, phantom


def _reference_functionals(schedule, cols, kx, c, reduction, ny):
    """The reference reads' functional of each channel at ``k_y = 0`` (pixel part, phantom
    part or None), as `_functionals`: minus ``ny`` times the channel's phase sum over its
    light columns times the mean over the reference pixels (each minus its read's phantom
    value when ``reduction.reference_phantom``); None without a reference correction."""
    if reduction.reference is None:
        return None
    s = schedule
    g = s.geometry
    nref = int(s.is_reference.sum())
    if nref == 0:
        raise SpherexReduceError("forecast: correct_reference needs reference reads; the "
                                 "schedule has none")
    width, nch = g.channel_width, g.nchannels
    nx = cols.stop - cols.start
    j = np.arange(cols.start, cols.stop)
    k = 2 * np.pi * kx / nx
    box = np.zeros((nch, k.size), dtype=complex)  # the channel's light phases
    np.add.at(box, g.channel_of_column()[j], np.exp(-1j * np.outer(j - cols.start, k)))
    scale = -ny * box / nref  # (nch, nkx)
    offsets = g.column_offsets()
    pix = np.zeros((nch, k.size, c + width), dtype=complex)
    for ch in range(nch):
        o = offsets[ch * width:(ch + 1) * width]
        pix[ch][:, c + o] = scale[ch][:, None] / o.size
    phantom = None
    if reduction.reference_phantom and c:
        phantom = np.zeros_like(pix)
        phantom[:, :, :c] = -scale[:, :, None] / c
    return pix, phantom


def _pick(functional, comp, phantom):
    """One component's part of a functional: what its pixels and phantom samples see."""
    pix, ph = functional
    out = pix if comp.seen_by_pixels else np.zeros_like(pix)
    if phantom and ph is not None and comp.seen_by_phantom:
        out = out + ph
    return out


def _correlate(a, b, comp):
    """``X(k_x, d) = sum_s a(k_x, s + d) conj b(k_x, s)``, ``d = -(n - 1) ... n - 1``,
    summed over channels (channel scope) or of the sums over channels (common scope); with
    ACN only offsets of one parity correlate."""
    if comp.scope == "common":
        a, b = a.sum(axis=0, keepdims=True), b.sum(axis=0, keepdims=True)
    n = a.shape[-1]
    fa = scipy.fft.fft(a, 2 * n, axis=-1)
    fb = fa if b is a else scipy.fft.fft(b, 2 * n, axis=-1)
    x = scipy.fft.ifft(fa * fb.conj(), axis=-1).sum(axis=0)
    x = x[:, np.arange(-(n - 1), n) % (2 * n)]
    if comp.acn:
        x[:, np.arange(-(n - 1), n) % 2 != 0] = 0.0
    return x


def _chebyshev_rule(half, n):
    """``(L, nodes)``: ``f(d) ≈ sum_i L[d, i] f(nodes[i])`` for ``d = -half ... half``, the
    interpolating polynomial on ``n`` Chebyshev nodes of ``[-half, half]`` rounded to whole
    offsets (a stream is only defined at whole samples: its white part is a spike there)."""
    d = np.arange(-half, half + 1)
    if int(n) >= d.size:
        return np.eye(d.size), d
    nodes = np.unique(np.rint(half * np.cos(np.pi * (np.arange(n) + 0.5) / n)).astype(int))
    cheb = np.polynomial.chebyshev.chebvander
    rule = np.linalg.solve(cheb(nodes / half, nodes.size - 1).T,
                           cheb(d / half, nodes.size - 1).T).T
    return rule, nodes
