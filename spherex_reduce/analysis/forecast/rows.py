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
(``H_LR``) and between two reference reads (``H_RR``).  A ``wiener`` estimate
differs from read to read and changes every ``k_y``
(`spherex_reduce.analysis.forecast.wiener`).

The sum over ``d`` is exact for the ``m`` near a singularity of ``S`` (``m R``
within `NEAR_READS` row reads of a multiple of the frame time, or with uneven
``read_times`` of a difference of two of them); for the others
``S(m R + d)`` is smooth in ``d`` over one read and is interpolated on `NODES`
Chebyshev nodes rounded to whole offsets.  The cells can be restricted to
some ``k_y`` rows and ``k_x`` columns (`band_cells`): the cost is then that
of those cells only.
"""


import threading
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ...core.errors import SpherexReduceError
from ...core.limits import check_size
from ...core.readout.read_order import ORDER_REPLACES
from ...core.recently_used import RecentlyUsed
from ...noise.variance import SHIFT_CELLS, slope_covariance, slope_frames
from .functionals import Correlations, Part, channel_sums, column_phases
from .wiener import WienerTerms

__all__ = ["CHUNK_LAGS", "CHUNK_ROWS", "LAG_TABLE_BYTES", "NEAR_READS", "NODES", "Cells",
           "component_planes"]

#: Row reads from a multiple of the frame time within which the sum over offsets is exact.
NEAR_READS = 4
#: Chebyshev nodes over the offsets beyond (the rule is exact for polynomials of lower degree).
NODES = 8
#: k_y rows computed at a time (bounds the memory of the rows' read-slot arrays: ~0.1 GB,
#: ~0.3 GB for the ``wiener`` correction, at the paper's full size).
CHUNK_ROWS = 256
#: Lags whose slope covariance is computed at a time (it holds ``(2 frames - 1, lags)``
#: arrays).
CHUNK_LAGS = 16384


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

    def __post_init__(self):
        if np.any(np.diff(self.ky) <= 0):
            raise ValueError("Cells: the row indices ky must increase")

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
    reduction : `~spherex_reduce.analysis.forecast.steps.Reduction`
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
    wiener = reduction.reference == "wiener"
    if reduction.reference is not None and not schedule.is_reference.any():
        raise SpherexReduceError("forecast: correct_reference needs reference reads; the "
                                 "schedule has none")
    c = schedule.phantom_reads if (reduction.phantom or reduction.reference_phantom
                                   or wiener) else 0
    half = np.minimum(cells.ky, ny - cells.ky)
    distinct = np.unique(half)  # the rows of k_y >= 0 the cells need
    _check_memory(schedule, (ny, nx), distinct.size, cells, len(comps), c, wiener)
    table = _lag_table(schedule, comps, g.channel_width - 1 + c, nodes)
    light, light_spectra = _light(schedule, rows, cols, cells.kx, c, reduction)
    ref = ref_spectra = None
    if not wiener and reduction.reference is not None:
        ref, ref_spectra = _reference(schedule, rows, cols, cells.kx, c, reduction,
                                      light_spectra)
    has_zero = cells.ky.size and cells.ky[0] == 0
    if ref is not None and has_zero:
        light_reads = np.zeros(2 * (int(_slots(schedule).max()) + 1))
        light_reads[_slots(schedule)[_light_reads(schedule, rows)]] = 1.0
    first = np.searchsorted(distinct, half)  # row of `distinct` for every cell row
    split = int(np.searchsorted(cells.ky, ny // 2, side="right"))  # k_y < 0 from here
    re, im = (np.zeros((len(comps), distinct.size, cells.kx.size)) for _ in range(2))
    for lo in range(0, distinct.size, CHUNK_ROWS):  # (rows, 2 slots) arrays a chunk at a time
        a = _row_pairs(schedule, rows, distinct[lo:lo + CHUNK_ROWS])
        w = table.far_weights(a)  # every component's far lags summed on its nodes at once
        for i, comp in enumerate(comps):
            x = light_spectra.correlate(("light", light), ("light", light), comp)
            re[i, lo:lo + a.shape[0]], im[i, lo:lo + a.shape[0]] = table.real_products(i, w, x)
    spectra = light_spectra.fork() if wiener else None  # its terms are this schedule's
    parts = {}
    for i, comp in enumerate(comps):
        # each cell row from its distinct row: re - im, and re + im for k_y < 0 (the rows
        # after `split`: cells.ky increases)
        plane = np.empty((cells.ky.size, cells.kx.size))
        # (mode "clip": the rows are in range, and numpy's default buffers `out`)
        np.take(re[i] - im[i], first[:split], axis=0, out=plane[:split], mode="clip")
        np.take(re[i] + im[i], first[split:], axis=0, out=plane[split:], mode="clip")
        parts[comp.name] = plane
        if ref is not None and has_zero:
            for n, (ind, f) in enumerate(ref):
                x = ref_spectra.correlate(("light", light), (n, f), comp)
                cross = table.products(i, _slot_pairs(light_reads, ind), x)
                parts[comp.name][0] += 2 * cross.real
                for n2, (ind2, f2) in enumerate(ref):
                    x = ref_spectra.correlate((n, f), (n2, f2), comp)
                    auto = table.products(i, _slot_pairs(ind, ind2), x)
                    parts[comp.name][0] += auto.real
    if wiener:  # k_y rows a chunk at a time: a term holds (rows, 2 slots) arrays
        lags = {}  # the observations' covariance at every slot lag, for every chunk
        for lo in range(0, cells.ky.size, CHUNK_ROWS):
            ky = cells.ky[lo:lo + CHUNK_ROWS]
            terms = WienerTerms(schedule, rows, cols, ky, cells.kx, c, reduction,
                                _slots(schedule), _light_reads(schedule, rows), table)
            for i, comp in enumerate(comps):
                parts[comp.name][lo:lo + ky.size] += terms.plane(table, spectra, i, comp,
                                                                 light, lags)
    return parts


def _check_memory(schedule, shape, nhalf, cells, ncomp, c, wiener):
    """Refuse (`~spherex_reduce.core.errors.ResourceError`) cells whose arrays this machine
    cannot hold, before any is allocated.  The bytes, an upper estimate: the light rows'
    functional ``(nch, nkx, c + width)`` and its FFTs over offsets, a chunk of rows'
    ``(rows, 2 slots)`` arrays (with ``wiener``, its terms' and their pairs'), the lag table
    and the planes."""
    g = schedule.geometry
    ny, nx = shape
    nkx, nky = cells.kx.size, cells.ky.size
    slots = 2 * (int(_slots(schedule).max()) + 1)
    width = c + g.channel_width
    functional = 16 * nkx * width * (5 * g.nchannels + 14)
    chunk = min(nhalf, CHUNK_ROWS)
    row_arrays = 112 * chunk * slots
    if wiener:  # up to 8 terms (2 groups, 2 families, 2 kinds) and their 36 pairs
        row_arrays += 16 * min(nky, CHUNK_ROWS) * (50 * slots + ny)
    nlags = slots * NODES + 3 * (2 * NEAR_READS + 1) * (2 * width + 1)
    shifts = slope_frames(schedule)[2].size  # the slope covariance's arrays (lags, shifts)
    lag_table = 8 * (3 * ncomp * nlags + 6 * min(shifts * min(nlags, CHUNK_LAGS), SHIFT_CELLS))
    planes = 8 * (ncomp + 1) * (3 * nky + 2 * nhalf) * nkx
    check_size(functional + row_arrays + lag_table + planes,
               f"forecast: the {nky} x {nkx} cells of a {ny} x {nx} image read in {slots // 2} "
               f"slots of {g.nchannels} channel(s)")


#: Bytes of lag tables kept (`_lag_table`): a search over row orders reuses one per timing
#: (~1.5 MB each in the paper's full-size case).
LAG_TABLE_BYTES = 256 * 2**20
_lag_tables = RecentlyUsed(LAG_TABLE_BYTES, size=lambda table: table.nbytes)


def _lag_table(schedule, comps, half, nodes):
    """The `_LagTable` of a schedule's timing, computed once for every order of its rows.

    It depends on the schedule only through its timing (the slope covariance, the samples
    per row read and per frame, the number of read slots), not on which row is read in which
    slot: the schedules of a search over row orders share it.  The tables most recently
    used are kept, up to `LAG_TABLE_BYTES`, keyed by the geometry, every readout parameter
    but those of the row order (``order``, ``skip``, ``ref_reads``, ``ref_mode``), the number
    of slots, the components, ``half``, ``nodes`` and `CHUNK_LAGS` (the covariance is
    computed that many lags at a time, which can change its last bits).
    """
    timing = {k: v for k, v in schedule.to_dict().items()
              if k not in ("order", *ORDER_REPLACES)}
    key = repr((schedule.geometry, sorted(timing.items()), int(_slots(schedule).max()),
                list(comps), int(half), int(nodes), CHUNK_LAGS))
    return _lag_tables.get(key, lambda: _LagTable(schedule, comps, half, nodes))


#: Lags a `_CovarianceLine` keeps (beyond, it starts again): ~50 MB for five components.
LINE_LAGS = 2**20
_lines = RecentlyUsed(2)


def _covariance_line(schedule, comps):
    """The `_CovarianceLine` of a schedule's frames and components (the last two kept).

    The slope covariance depends on a schedule only through its frames (`slope_frames`:
    the number of frames, the samples per frame or the read times, and the pixel rate),
    so the timings of a search at one frame time (other ``c``, ``r``, placements) share
    it: each asks for the lags of its own row time and computes only those not yet known.
    """
    key = repr((schedule.nframes, schedule.frame_samples, schedule.geometry.pixel_rate,
                schedule.read_times, list(comps), CHUNK_LAGS))
    return _lines.get(key, lambda: _CovarianceLine(schedule, comps))


class _CovarianceLine:
    """`slope_covariance` of some components at the lags asked so far (sorted), computed
    `CHUNK_LAGS` at a time; thread-safe."""

    def __init__(self, schedule, comps):
        self.schedule, self.comps = schedule, comps
        self.lags = np.zeros(0, dtype=np.int64)
        self.values = np.zeros((len(comps), 0))
        self._lock = threading.Lock()

    def at(self, lags):
        """The covariance ``(ncomp, lags.size)`` at ``lags`` (whole samples, >= 0,
        increasing and distinct)."""
        lags = np.asarray(lags, dtype=np.int64)
        with self._lock:
            if self.lags.size + lags.size > LINE_LAGS:
                self.lags, self.values = self.lags[:0], self.values[:, :0]
            pos = np.minimum(np.searchsorted(self.lags, lags), max(self.lags.size - 1, 0))
            known = (self.lags[pos] == lags) if self.lags.size else np.zeros(lags.size, bool)
            new = lags[~known]
            if new.size:
                cov = np.concatenate([slope_covariance(self.comps, self.schedule,
                                                       new[lo:lo + CHUNK_LAGS])
                                      for lo in range(0, new.size, CHUNK_LAGS)], axis=1)
                merged = np.concatenate([self.lags, new])
                order = np.argsort(merged, kind="stable")
                self.lags = merged[order]
                self.values = np.concatenate([self.values, cov], axis=1)[:, order]
            return self.values[:, np.searchsorted(self.lags, lags)]


class _LagTable:
    """``S(m R + d)`` of each component at every read-slot lag ``m`` and offset
    difference ``d`` (``|d| <= half``): exact near a singularity, on Chebyshev nodes
    elsewhere."""

    def __init__(self, schedule, comps, half, nodes):
        s = schedule
        rs = s.row_samples
        slots = _slots(s).max() + 1
        m = np.arange(-(slots - 1), slots)
        near = _singular_distance(m * rs, slope_frames(s)[2]) < NEAR_READS * rs
        self.near, self.far = m[near] % (2 * slots), m[~near] % (2 * slots)
        d = np.arange(-half, half + 1)
        self.interp, dnodes = _chebyshev_rule(half, nodes)
        lags = np.concatenate([(m[near][:, None] * rs + d[None, :]).ravel(),
                               (m[~near][:, None] * rs + dnodes[None, :]).ravel()])
        lags, inverse = np.unique(np.abs(lags), return_inverse=True)  # S is even
        cov = _covariance_line(s, comps).at(lags)[:, inverse.ravel()] if comps else None
        nnear = near.sum() * d.size
        self.s_near = [cov[i, :nnear].reshape(near.sum(), d.size) for i in range(len(comps))]
        self.s_far = [cov[i, nnear:].reshape((~near).sum(), dnodes.size)
                      for i in range(len(comps))]
        self.nbytes = sum(a.nbytes for a in (*self.s_near, *self.s_far, self.interp))

    def far_weights(self, w):
        """``w(m)`` ``(n, 2 slots)`` on the exact lags ``(n, n_near)`` and, for every
        component, summed against ``S`` on the nodes of the far lags ``(n, ncomp, nodes)``:
        what `split_products` takes."""
        far = w[:, self.far]
        if not self.s_far:  # no component
            return w[:, self.near], np.zeros((w.shape[0], 0, 0))
        stacked = np.concatenate(self.s_far, axis=1)
        return w[:, self.near], (far @ stacked).reshape(w.shape[0], len(self.s_far), -1)

    def split_products(self, i, w_near, w_far, x):
        """`products` of weights given by `far_weights`."""
        q_near, _, nodes = self._q(i, x)
        return w_near @ q_near + w_far[:, i] @ nodes

    def _q(self, i, x):
        """``sum_d X(k_x, d) S(m R + d)`` as (near ``(n_near, nkx)``, far-on-nodes
        ``(n_far, nodes)`` and the nodes' weights ``(nodes, nkx)``)."""
        return self.s_near[i] @ x.T, self.s_far[i], (x @ self.interp).T

    def real_products(self, i, weights, x):
        """``Re w`` times the real and ``Im w`` times the imaginary part of ``sum_m w(m)
        sum_d X(k_x, d) S(m R + d)``, for ``w`` ``(n, 2 slots)`` given as `far_weights`
        gives it: with ``w(-k_y) = conj w(k_y)`` and ``X`` Hermitian in ``d``, ``re - im``
        and ``re + im`` are the cells of ``k_y`` and ``-k_y``."""
        q_near, _, nodes = self._q(i, x)
        w_near, w_far = weights[0], weights[1][:, i]
        re = w_near.real @ q_near.real + w_far.real @ nodes.real
        im = w_near.imag @ q_near.imag + w_far.imag @ nodes.imag
        return re, im

    def products(self, i, w, x):
        """``sum_m w(m) sum_d X(k_x, d) S(m R + d)`` for weights ``w`` ``(..., 2 slots)``
        (complex result, ``(..., nkx)``)."""
        q_near, s_far, nodes = self._q(i, x)
        return w[..., self.near] @ q_near + (w[..., self.far] @ s_far) @ nodes

    def lag_values(self, i, x, n):
        """``K(m) = sum_d X(d) S(m R + d)`` at every slot lag ``m`` (index ``m mod n``) for
        one correlation ``X`` ``(2 half + 1,)``."""
        out = np.zeros(n)
        out[self.near] = (self.s_near[i] @ x).real
        out[self.far] = (self.s_far[i] @ (x @ self.interp)).real
        return out


def _singular_distance(lags, shifts):
    """How far (samples) each lag is from the nearest of ``shifts`` (increasing): the
    slope covariance is singular at lags ``-shift``, the frames' shifts (`slope_frames`:
    multiples of the frame, or the differences of uneven read times)."""
    i = np.searchsorted(shifts, lags)
    below = shifts[np.clip(i - 1, 0, shifts.size - 1)]
    above = shifts[np.clip(i, 0, shifts.size - 1)]
    return np.minimum(np.abs(lags - below), np.abs(lags - above))


def _slots(s):
    """The slot (row-read time over the row time) of every read of a frame."""
    return (s.starts - s.phantom_reads) // s.row_samples


def _row_pairs(schedule, rows, ky):
    """``A(k_y, m)`` for the distinct ``min(i, ny - i)`` of ``ky`` and read-slot lag ``m``
    (index ``m mod 2 slots``): the autocorrelation over read slots of ``exp(-i k_y p)``.

    It depends on the rows' read slots, not on the frames or the noise: the forecasts of
    one readout at several frame counts (the slope scatter against N) share it, kept
    (`ROW_PAIRS_BYTES`) and read-only."""
    slot = _slots(schedule)
    first = _light_reads(schedule, rows)
    ky = np.asarray(ky)
    key = (slot.tobytes(), first.tobytes(), rows.start, rows.stop, ky.dtype.str, ky.tobytes())
    return _pairs.get(key, lambda: _autocorrelation(slot, first, rows, ky))


#: Bytes of `_row_pairs` kept: one full-size readout's chunks are ~70 MB.
ROW_PAIRS_BYTES = 96 * 2**20
_pairs = RecentlyUsed(ROW_PAIRS_BYTES, size=lambda a: a.nbytes)


def _autocorrelation(slot, first, rows, ky):
    """`_row_pairs` itself (read-only)."""
    slots = int(slot.max()) + 1
    ny = rows.stop - rows.start
    k = 2 * np.pi * np.unique(np.minimum(ky, ny - ky)) / ny
    n = scipy.fft.next_fast_len(2 * slots)  # the lags |m| < slots stay apart at any n >= 2 slots
    g = np.zeros((k.size, n), dtype=complex)
    g[:, slot[first]] = np.exp(-1j * k[:, None] * np.arange(ny)[None, :])
    f = scipy.fft.fft(g, axis=1, workers=-1)
    f = f.real**2 + f.imag**2
    a = scipy.fft.ifft(f, axis=1, workers=-1)
    m = np.arange(-(slots - 1), slots)
    out = np.zeros((k.size, 2 * slots), dtype=complex)
    out[:, m % (2 * slots)] = a[:, m % n]
    out.flags.writeable = False
    return out


#: Light functionals (and their correlations) kept by `_light`.
LIGHT_FUNCTIONALS = 2
_lights = RecentlyUsed(LIGHT_FUNCTIONALS)


def _light(schedule, rows, cols, kx, c, reduction):
    """`_functionals` and a `Correlations` of them, shared by the schedules of a search: the
    light rows' functional depends on the geometry, the rectangle, the cells' ``k_x``, ``c``
    and the reduction, not on the row order or the timing.  The last `LIGHT_FUNCTIONALS`
    are kept."""
    kx = np.asarray(kx)
    key = repr((schedule.geometry, rows, cols, kx.dtype.str, kx.tobytes(), int(c), reduction))
    return _lights.get(key, lambda: (_functionals(schedule, rows, cols, kx, c, reduction),
                                     Correlations()))


def _light_reads(s, rows):
    """The read of every light-sensitive row (refused unless read once, as an active row)."""
    first = s.read_of_row()[rows]
    if np.any(first < 0) or np.any(s.is_reference[first]):
        raise SpherexReduceError("forecast: a light-sensitive row is not read as an active row")
    return first


def _functionals(schedule, rows, cols, kx, c, reduction):
    """The light rows' functional (a list of `Part`, each ``(nch, nkx, c + width)``): the
    pixels' phases ``sum_{o_j = o} exp(-i k_x j)`` at offset ``o`` (index ``c + o``) and,
    with phantom subtraction, minus the channel's phase sum over ``c`` at each phantom
    sample."""
    g = schedule.geometry
    width, nch = g.channel_width, g.nchannels
    j, phase = column_phases(g, cols, kx)  # (nx, nkx)
    off, chan = g.column_offsets()[j], g.channel_of_column()[j]
    pix = np.zeros((nch, phase.shape[1], c + width), dtype=complex)
    np.add.at(pix, (chan, slice(None), c + off), phase)
    parts = [Part(False, dense=pix)]
    if reduction.phantom and c:
        profile = np.zeros(c + width)
        profile[:c] = 1.0
        parts.append(Part(True, amp=-pix.sum(axis=2) / c, profile=profile))
    return parts


#: Reference functionals (and their correlations) kept by `_reference`.
_references = RecentlyUsed(LIGHT_FUNCTIONALS)


def _reference(schedule, rows, cols, kx, c, reduction, light_spectra):
    """The reads the reference offsets average, at ``k_y = 0``: a list of (slot indicator
    ``(2 slots,)``, functional of each channel as `_functionals` gives it), one for the
    reference reads and, with side columns, one for the active reads; and the
    `Correlations` to take theirs with.

    The functionals depend on the schedule only through how many reads are reference
    reads, not on which slots they take: the schedules of a search share them and their
    correlations (the last `LIGHT_FUNCTIONALS` are kept), each with its own indicators.
    """
    s = schedule
    nref = int(s.is_reference.sum())
    kx = np.asarray(kx)
    key = repr((s.geometry, rows, cols, kx.dtype.str, kx.tobytes(), int(c), reduction, nref,
                s.n_reads))
    kinds, spectra = _references.get(key, lambda: (
        _reference_functionals(s.geometry, nref, s.n_reads - nref, cols, kx, c, reduction,
                               rows.stop - rows.start), light_spectra.fork()))
    slot = _slots(s)
    out = []
    for reads, parts in zip((s.is_reference, ~s.is_reference), kinds, strict=False):
        indicator = np.zeros(2 * (int(slot.max()) + 1))
        np.add.at(indicator, slot[reads], 1.0)
        out.append((indicator, parts))
    return out, spectra


def _reference_functionals(g, nref, nact, cols, kx, c, reduction, ny):
    """The functional of the reference reads and, with side columns, of the active reads
    (a list of `Part` lists, as `_reference` gives them), of a geometry read with ``nref``
    reference and ``nact`` active reads.

    A pixel of group ``g`` (the channel's columns, or those of one offset parity with
    ``acn``) gets the offset ``mu_g``, the mean over the ``N_g`` reference pixels of the
    group (each minus its read's phantom value when ``reduction.reference_phantom``); so
    the image's ``k_y = 0`` row loses ``ny E_g(k_x) mu_g``, ``E_g`` the phases of the
    group's light columns."""
    width, nch = g.channel_width, g.nchannels
    j, phase = column_phases(g, cols, kx)
    nkx = phase.shape[1]
    offsets, chan = g.column_offsets(), g.channel_of_column()
    parity = offsets % 2 if reduction.reference == "acn" else np.zeros(g.ncols, int)
    side = g.reference_column_mask() if reduction.side_columns else np.zeros(g.ncols, bool)
    kinds = [np.ones(g.ncols, bool)]  # the columns each kind of read gives
    if side.any():
        kinds.append(side)
    pix = [{} for _ in kinds]  # per kind: {offsets used: amp (nch, nkx)}
    phantom = [np.zeros((nch, nkx), dtype=complex) for _ in kinds]
    for group in np.unique(parity):
        box = channel_sums(g, j, phase, parity[j] == group)  # the group's light phases
        for ch in range(nch):
            used = (chan == ch) & (parity == group)
            total = nref * used.sum() + nact * (used & side).sum()  # N_g
            for n, columns in enumerate(kinds):
                o = np.sort(offsets[used & columns])
                if o.size:
                    amp = pix[n].setdefault(o.tobytes(), np.zeros((nch, nkx), complex))
                    amp[ch] -= ny * box[ch] / total
                    phantom[n][ch] += ny * box[ch] * o.size / total
    out = []
    for n in range(len(kinds)):
        parts = []
        for used, amp in pix[n].items():
            profile = np.zeros(c + width)
            profile[c + np.frombuffer(used, dtype=offsets.dtype)] = 1.0
            parts.append(Part(False, amp=amp, profile=profile))
        if reduction.reference_phantom and c:
            profile = np.zeros(c + width)
            profile[:c] = 1.0 / c
            parts.append(Part(True, amp=phantom[n], profile=profile))
        out.append(parts)
    return out


def _slot_pairs(a, b):
    """``H(m)``: the pairs of reads (one of indicator ``a``, one of ``b``) whose slots differ
    by ``m`` (index ``m mod 2 slots``)."""
    n = a.size
    return np.rint(scipy.fft.irfft(scipy.fft.rfft(a) * scipy.fft.rfft(b).conj(), n))


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
