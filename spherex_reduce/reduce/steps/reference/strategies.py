"""Reference strategies: how each channel's offset is estimated (paper §2.4, §4.3, §5.4).

A strategy is configured with its parameters when it is made and *estimates*
offsets (`Strategy.estimate`); the ``correct_reference`` step's kernel
*applies* them (`spherex_reduce.reduce.steps.reference.step`), for every strategy alike.
The built-in ones are ``mean`` (one σ-clipped mean of the reference pixels per
channel), ``acn`` (two, for even and odd samples) and ``median`` (median of
all pixels of the channel, optionally excluding sources found with
`photutils`).
"""

import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from astropy.utils.exceptions import AstropyUserWarning

from ....core import dq
from ....core.errors import SpherexReduceError
from ....core.parameters import Parameter, validate_parameters
from ....core.source_mask import source_mask
from ....io.sources import context_of, side_block
from ...noise_effect import MEASURED_SIGMA, ReferenceEffect
from ...options import RunOptions, in_threads
from ...step import Strategy
from .telegraph import TELEGRAPH_PARAMETERS, drop_telegraph, nanmedian

__all__ = [
    "ALL",
    "EVEN",
    "ODD",
    "AcnReference",
    "MeanReference",
    "MedianReference",
    "NoReferenceError",
    "NoReferenceWarning",
    "ReferenceOffsets",
    "UnequalReferenceWarning",
    "clipped_mean",
    "group_columns",
    "reference_offsets",
    "reference_pixels",
    "reference_rows",
    "side_column_values",
]

#: Parity values of the ``REFOFFS`` table: all columns, even samples, odd samples.
ALL, EVEN, ODD = -1, 0, 1

#: frames σ-clipped together (their temporaries stay in cache)
_FRAMES_PER_CLIP = 4


class NoReferenceError(SpherexReduceError):
    """The exposure has no reference rows to correct with."""


class NoReferenceWarning(AstropyUserWarning):
    """A channel had no usable reference pixels and was left uncorrected."""


class UnequalReferenceWarning(AstropyUserWarning):
    """``side_columns`` adds side reference columns to some channels only."""


def _warn_unequal(geometry):
    """One line when only some channels have side reference columns (``side_columns``)."""
    has = np.unique(geometry.channel_of_column()[geometry.reference_column_mask()])
    if 0 < has.size < geometry.nchannels:
        warnings.warn(
            f"correct_reference: side_columns: only channel(s) {has.tolist()} of "
            f"{geometry.nchannels} have side reference columns, so the channels are corrected "
            "unequally (with them an offset averages the drift over every row of the frame, "
            "without it only at the reference rows' reads) and the offsets between outputs "
            "grow; set side_columns: false", UnequalReferenceWarning,
            stacklevel=2)


@dataclass
class ReferenceOffsets:
    """What a strategy estimates: offsets per (frame, channel, parity group).

    Attributes
    ----------
    offsets, n_used, n_clipped : `numpy.ndarray`
        Shape ``(L, nchannels, P)``: ``L`` frames (1 for an image), ``P``
        groups of columns per channel; an offset is NaN where the group had
        no usable pixel (the channel is then left uncorrected and flagged).
    parity : list of int
        The parity of each of the ``P`` groups: `ALL`, or `EVEN` and `ODD`.
    """

    offsets: np.ndarray
    n_used: np.ndarray
    n_clipped: np.ndarray
    parity: list
    #: Optional ``(L, n_reads, nchannels, P)``: an offset for every read of a frame (the
    #: ``wiener`` strategy's drift estimate), subtracted row by row instead of ``offsets``;
    #: NaN where the group has none.
    rows: np.ndarray | None = None
    #: More tables for the output (name -> `~astropy.table.Table`), e.g. ``REFDRIFT``.
    tables: dict = field(default_factory=dict)
    #: The telegraph reference pixels left out (a
    #: `~spherex_reduce.reduce.steps.reference.telegraph.TelegraphSearch`), or None: not looked for.
    telegraph: object = None

    @property
    def acn(self):
        return len(self.parity) == 2


def clipped_mean(values, sigma=3.0, maxiters=5):
    """σ-clipped mean along the last axis, NaNs ignored (astropy ``sigma_clip`` rules).

    Each iteration keeps the values within ``median ± sigma * std`` of the
    values kept so far, until nothing changes or ``maxiters`` is reached;
    values are sorted once so an iteration costs one comparison per value.

    Parameters
    ----------
    values : array_like
        Shape ``(..., m)``; NaN marks values not to use.
    sigma : float
        Clip threshold in standard deviations (both sides).
    maxiters : int or None
        Iteration limit; None iterates until nothing changes.

    Returns
    -------
    mean, n_used, n_clipped : `numpy.ndarray`
        Shape ``(...)``.  ``mean`` is NaN (``n_used == 0``) where no value
        is usable.  Identical values (zero spread) are all kept.

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.reference.strategies import clipped_mean
    >>> mean, used, clipped = clipped_mean([1.0, 1.1, 0.9, 1.0, 50.0, float("nan")], sigma=2)
    >>> float(mean), int(used), int(clipped)
    (1.0, 4, 1)
    """
    _, c1, mid, lo, hi, nvalid = _clip_range(values, sigma, maxiters)
    n = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (_take(c1, hi) - _take(c1, lo)) / n + mid[..., 0]
    mean = np.where(n > 0, mean, np.nan)
    return mean, n, nvalid - n


def _take(a, i):
    return np.take_along_axis(a, i[..., None], axis=-1)[..., 0]


def _clip_range(values, sigma, maxiters):
    """`clipped_mean`'s iterations: the values sorted along the last axis (NaN last), the
    prefix sums of their departures from ``mid``, ``mid``, and the kept ``[lo, hi)`` and
    the usable count of every row."""
    v = np.asarray(values, dtype=np.float64)
    s = np.sort(np.where(np.isfinite(v), v, np.nan), axis=-1)  # unusable (NaN) sort last
    nvalid = np.isfinite(s).sum(axis=-1)
    lead = s.shape[:-1]
    lo = np.zeros(lead, dtype=np.int64)
    hi = nvalid.astype(np.int64)
    # shift by a typical value before the prefix sums: keeps float64 sums exact
    mid = np.take_along_axis(s, np.maximum((hi - 1) // 2, 0)[..., None], axis=-1)
    mid = np.where(np.isfinite(mid), mid, 0.0)
    sh = np.where(np.isfinite(s), s - mid, 0.0)
    c1 = np.concatenate([np.zeros((*lead, 1)), np.cumsum(sh, axis=-1)], axis=-1)
    c2 = np.concatenate([np.zeros((*lead, 1)), np.cumsum(sh * sh, axis=-1)], axis=-1)
    last = max(s.shape[-1] - 1, 0)
    fin = np.isfinite(s)
    it = 0
    while maxiters is None or it < maxiters:
        it += 1
        n = hi - lo
        ok = n > 0
        safe_n = np.maximum(n, 1)
        med = 0.5 * (_take(sh, np.clip(lo + (n - 1) // 2, 0, last))
                     + _take(sh, np.clip(lo + n // 2, 0, last)))
        s1 = _take(c1, hi) - _take(c1, lo)
        s2 = _take(c2, hi) - _take(c2, lo)
        var = np.maximum(s2 / safe_n - (s1 / safe_n) ** 2, 0.0)
        std = np.sqrt(var)
        lower = (med - sigma * std)[..., None]
        upper = (med + sigma * std)[..., None]
        new_lo = np.maximum(lo, ((sh < lower) & fin).sum(axis=-1))
        new_hi = np.minimum(hi, ((sh <= upper) & fin).sum(axis=-1))
        new_hi = np.where(ok, np.maximum(new_hi, new_lo), hi)
        new_lo = np.where(ok, new_lo, lo)
        if np.array_equal(new_lo, lo) and np.array_equal(new_hi, hi):
            break
        lo, hi = new_lo, new_hi
    return s, c1, mid, lo, hi, nvalid


def _read_clipped_mean(blocks, sigma, maxiters):
    """Clipped mean of the values of ``blocks``, each ``(..., r, k)``: ``r`` reads of ``k``
    values (NaN: unusable), robust to a drift that moves every value of a read together.

    A value is clipped on its departure from its read's median (what the read's values
    share: the drift at that read), pooled over every read, with `clipped_mean`'s rules;
    the mean is each read's mean of its kept values weighted by its usable values' count,
    so the drift is averaged over the reads as an unclipped mean averages it, whichever
    values the clip takes.  Returns ``mean, n_used, n_clipped`` of shape ``(...)``.
    """
    deps, lead = [], blocks[0].shape[:-2]
    for b in blocks:
        with np.errstate(invalid="ignore"):
            dep = b - nanmedian(b)[..., None]
        deps.append(np.where(np.isfinite(b) & np.isfinite(dep), dep, np.nan))
    s, _, _, lo, hi, nvalid = _clip_range(
        np.concatenate([d.reshape(*lead, -1) for d in deps], axis=-1), sigma, maxiters)
    n = hi - lo
    last = max(s.shape[-1] - 1, 0)
    lower = _take(s, np.clip(lo, 0, last))[..., None, None]
    upper = _take(s, np.clip(hi - 1, 0, last))[..., None, None]
    kept, usable, total = [], [], []
    for b, d in zip(blocks, deps, strict=True):
        with np.errstate(invalid="ignore"):
            keep = (d >= lower) & (d <= upper) & (n > 0)[..., None, None]  # NaN: False
        kept.append(keep.sum(axis=-1))
        usable.append(np.isfinite(d).sum(axis=-1))
        total.append(np.where(keep, b, 0.0).sum(axis=-1))
    kept, usable, total = (np.concatenate(x, axis=-1) for x in (kept, usable, total))
    weight = np.where(kept > 0, usable, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (weight * total / np.maximum(kept, 1)).sum(axis=-1) / weight.sum(axis=-1)
    return np.where(n > 0, mean, np.nan), n, nvalid - n


def _usable(values, mask):
    """Values as float64 with NaN where masked (`clipped_mean` ignores NaN and inf)."""
    out = np.array(values, dtype=np.float64)
    if mask is not None:
        out[~dq.read_usable(mask)] = np.nan  # JUMP, REFERENCE alone: still usable
    return out


def reference_pixels(side, schedule):
    """Reference pixels ``(L, k, ncols)`` of a side block (NaN where unusable); L = frames.

    Raises
    ------
    NoReferenceError
        The block holds no reference rows.
    """
    g = schedule.geometry
    if side.order == "readout":
        keep = schedule.is_reference[side.index]
        vals = side.data[:, keep] if not keep.all() else side.data
        m = None if side.dq is None else (side.dq[:, keep] if not keep.all() else side.dq)
    else:
        vals, m = side.data, side.dq
    if vals.shape[-2] == 0:
        raise NoReferenceError(
            "correct_reference: the exposure has no reference rows "
            f"(ref_border={g.border}, {schedule.ref_reads} reference reads in mode "
            f"{schedule.ref_mode!r}); use the 'median' strategy, or a schedule with reference reads"
        )
    return _usable(vals, m)


def reference_rows(side, schedule):
    """Physical row of every reference read of a side block (the ``k`` of `reference_pixels`)."""
    if side.order == "readout":
        reads = np.asarray(side.index)
        return schedule.rows[reads[schedule.is_reference[reads]]]
    return np.asarray(side.index)


def without_telegraph(strategy, reference, side, schedule, columns=None):
    """Reference pixels ``(L, k, ncols)`` and side columns (None, or ``(values, rows,
    columns)`` as `side_column_values` gives them) with the reads of telegraph pixels NaN when
    ``strategy.telegraph`` is ``'auto'``, and what was found (a
    `~spherex_reduce.reduce.steps.reference.telegraph.TelegraphSearch`, or None with ``'keep'``).

    The side columns are tested on their own (a row read once per frame has fewer
    samples than a reference row read several times)."""
    side_values = None if columns is None else columns[0]
    if strategy.telegraph != "auto":
        return reference, side_values, None
    g = schedule.geometry
    reference, found = drop_telegraph(reference, reference_rows(side, schedule), g,
                                      strategy.telegraph_sigma)
    if columns is not None:
        values, rows, cols = columns
        side_values, more = drop_telegraph(values, rows, g, strategy.telegraph_sigma, cols)
        found = found.combine(more)
    return reference, side_values, found


def side_column_values(exposure):
    """Side reference columns of the active rows ``(L, rows, m)`` (NaN: unusable), the
    physical row of each of those rows, and the ``m`` columns.

    Only the declared reference columns are read (a few MB of a full-size exposure):
    ``left`` of ``ref_border`` from column 0, ``right`` at the end, and in a readout
    frame of quadrants those at the start or end of every channel
    (`~spherex_reduce.DetectorGeometry.reference_column_mask`).
    """
    s = exposure.schedule
    g = s.geometry
    cols = np.flatnonzero(g.reference_column_mask())
    idx = s.active_read_indices if exposure.order == "readout" else g.active_rows
    vals = np.take(np.asarray(exposure.data.data)[..., cols], idx, axis=-2)
    m = None if exposure.dq is None else np.take(np.asarray(exposure.dq)[..., cols], idx,
                                                  axis=-2)
    vals = _usable(vals, m)
    rows = s.rows[idx] if exposure.order == "readout" else idx
    return vals.reshape(-1, *vals.shape[-2:]), rows, cols


def group_columns(geometry, acn):
    """Column indices of every (channel, parity) group, shape ``(nch, P, k)`` (-1 pads).

    Parameters
    ----------
    geometry : `~spherex_reduce.DetectorGeometry`
    acn : bool
        Whether each channel's columns are split by the parity of their sample
        in the channel's scan (``P = 2``: `EVEN`, `ODD`) or kept together (``P = 1``).

    Returns
    -------
    `numpy.ndarray` of int
        ``k`` is the largest group; a smaller group is padded with -1.

    Examples
    --------
    Two channels of three columns, the second read right to left:

    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.reduce.steps.reference.strategies import group_columns
    >>> g = DetectorGeometry(8, 6, 2, ref_border=0, scan="alternate")
    >>> group_columns(g, acn=False).tolist()
    [[[0, 1, 2]], [[3, 4, 5]]]
    >>> group_columns(g, acn=True).tolist()
    [[[0, 2], [1, -1]], [[3, 5], [4, -1]]]
    """
    width = geometry.channel_width
    offsets = geometry.column_offsets()
    groups = []
    for ch in range(geometry.nchannels):
        cols = np.arange(ch * width, (ch + 1) * width)
        if acn:
            groups.append([cols[offsets[cols] % 2 == p] for p in (EVEN, ODD)])
        else:
            groups.append([cols])
    k = max(len(c) for gr in groups for c in gr)
    out = np.full((geometry.nchannels, len(groups[0]), k), -1, dtype=int)
    for ch, gr in enumerate(groups):
        for p, cols in enumerate(gr):
            out[ch, p, : len(cols)] = cols
    return out


def _side_groups(groups, columns):
    """`group_columns` ``groups`` restricted to ``columns`` (increasing) and given as
    indices into them, ``(nch, P, k)`` with -1 pads (``k`` >= 1)."""
    parts = [[np.searchsorted(columns, c[np.isin(c, columns)]) for c in gr] for gr in groups]
    k = max(1, max(len(c) for gr in parts for c in gr))
    out = np.full((*groups.shape[:2], k), -1, dtype=int)
    for ch, gr in enumerate(parts):
        for p, c in enumerate(gr):
            out[ch, p, : len(c)] = c
    return out


def _gather(values, groups):
    """``values (L, r, ncols)`` -> ``(L, nch, P, r, k)`` by column group, NaN for pads."""
    idx = np.maximum(groups, 0)
    out = values[:, :, idx]  # (L, r, nch, P, k)
    out[:, :, groups < 0] = np.nan
    return np.moveaxis(out, 1, -2)


def reference_offsets(exposure, *, acn=False, sigma=3.0, maxiters=5, side_columns=False,
                      telegraph="auto", telegraph_sigma=5.0):
    """σ-clipped mean of the reference pixels of every channel (and parity).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps (an offset per frame) or a 2-D image; readout order (reference
        reads taken from the data) or physical order (the reads kept aside by
        `unchop`, else the physical reference rows).
    acn : bool
        Two offsets per channel, for even and odd samples of the row read
        (alternating column noise); else one.
    sigma, maxiters
        σ-clipping of the reference pixels (see `clipped_mean`).
    side_columns : bool
        Also use the side reference columns of the first and last channel
        (those of the sides ``ref_border`` declares).
    telegraph : {'auto', 'keep'}
        ``auto`` leaves out the telegraph reference pixels (found by
        `~spherex_reduce.reduce.steps.reference.telegraph.find_telegraph` with threshold
        ``telegraph_sigma``); ``keep`` uses every reference pixel.
    telegraph_sigma : float
        Threshold of the telegraph test (robust standard deviations).

    Returns
    -------
    offsets, n_used, n_clipped : `numpy.ndarray`
        Shape ``(L, nchannels, P)``, ``L`` the number of frames (1 for an
        image), ``P`` 2 with ``acn`` else 1; ``offsets`` NaN where a group
        has no usable pixel.

    Raises
    ------
    NoReferenceError
        The exposure has no reference rows at all.
    """
    strategy = (AcnReference if acn else MeanReference)(
        sigma=sigma, maxiters=maxiters, side_columns=side_columns, telegraph=telegraph,
        telegraph_sigma=telegraph_sigma)
    est = strategy.estimate(side_block(exposure), context_of(exposure), exposure)
    return est.offsets, est.n_used, est.n_clipped


def _levels(values):
    """Each pixel's own level over the frames of ``values (L, r, ncols)``: the median of
    its usable reads, NaN for a pixel never usable (and for the columns never usable)."""
    cols = np.flatnonzero(np.isfinite(values).any(axis=(0, 1)))
    level = np.full(values.shape[1:], np.nan)
    if not cols.size:
        return level
    level[:, cols] = np.median(values[..., cols], axis=0)  # NaN where a read is unusable
    gaps = np.argwhere(np.isnan(level[:, cols]))
    if gaps.size:  # nanmedian, 5x slower, for those pixels only
        r, c = gaps[:, 0], cols[gaps[:, 1]]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a pixel never usable: NaN
            level[r, c] = np.nanmedian(values[:, r, c], axis=0)
    return level


def _offsets_of(geometry, reference, side, *, acn, sigma, maxiters, threads):
    """`reference_offsets` of reference-row pixels ``(L, k, ncols)`` (NaN: unusable)
    and optionally side-column pixels: None or ``(values, columns)``, ``values``
    ``(L, rows, m)`` (NaN: unusable) of the ``m`` detector ``columns``.

    With more than one frame, each pixel is clipped on its departure from its own
    level (its median over the frames), not on its value: on raw darks the
    reference pixels' fixed bias pattern spreads their values far more than their
    noise, and a clip on the values drops a different handful of pixels, by
    their bias, in each frame (offsets 1.6-1.85x noisier than a plain mean).  A
    group's offset is then the clipped mean of its departures plus the clipped
    mean of its pixels' levels (the pixels whose level is clipped, hot ones, are
    left out of every frame and counted in ``n_clipped``).  One frame (an
    image): the values themselves.  Either is clipped on its departure from its
    read's median too, with each read weighted as in a plain mean
    (`_read_clipped_mean`): a drift common to a read (1/f common to the outputs)
    spreads the pooled reads of a frame into groups, one per read, and a clip of
    the pool took a different handful from one side in each frame (NGHXRG
    ``c_pink``: per-output offsets 1.15-1.19x a plain mean's).

    Frames are clipped a few at a time (temporaries stay in cache) on
    ``threads`` threads; each group's numbers do not depend on the others.
    """
    from astropy.stats import sigma_clip

    groups = group_columns(geometry, acn)
    if side is not None:
        side, side_cols = side
        side_groups = _side_groups(groups, side_cols)

    def gathered(ref, more, hot=None):
        """Blocks ``(F, nch, P, r, k)`` of the reference rows and side columns, the hot
        pixels NaN."""
        blocks = [_gather(ref, groups)] + ([] if more is None else [_gather(more, side_groups)])
        if hot is not None:
            for b, h in zip(blocks, hot, strict=True):
                b[np.broadcast_to(h, b.shape)] = np.nan
        return blocks

    base, dropped = 0.0, 0
    if reference.shape[0] > 1:
        ref_level = _levels(reference)
        side_level = None if side is None else _levels(side)
        levels = gathered(ref_level[None], None if side is None else side_level[None])
        flat = np.concatenate([x.reshape(*x.shape[:3], -1) for x in levels], axis=-1)
        clipped = sigma_clip(np.ma.masked_invalid(flat), sigma=sigma, maxiters=maxiters,
                             axis=-1, cenfunc="median", stdfunc="std", copy=True)
        hot = np.ma.getmaskarray(clipped) & np.isfinite(flat)  # out of every frame
        dropped = hot.sum(axis=-1)
        base = np.ma.filled(clipped.mean(axis=-1), np.nan)
        ends = np.cumsum([x[0, 0, 0].size for x in levels])[:-1]
        hot = [h.reshape(x.shape) for h, x in zip(np.split(hot, ends, axis=-1), levels,
                                                   strict=True)]
        reference = reference - ref_level
        if side is not None:
            side = side - side_level
    else:
        hot = None

    def clip(lo):
        blocks = gathered(reference[lo:lo + _FRAMES_PER_CLIP],
                          None if side is None else side[lo:lo + _FRAMES_PER_CLIP], hot)
        mean, used, out = _read_clipped_mean(blocks, sigma, maxiters)
        return mean + base, used, out + dropped

    starts = range(0, reference.shape[0], _FRAMES_PER_CLIP)
    nthreads = min(len(starts), RunOptions(threads=threads).thread_count())
    if nthreads > 1:
        with ThreadPoolExecutor(nthreads, thread_name_prefix="spherex-reduce-clip") as pool:
            parts = list(pool.map(clip, starts))
    else:
        parts = [clip(lo) for lo in starts]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))


# -- strategies ------------------------------------------------------------------------------
class MeanReference(Strategy):
    """One σ-clipped mean of the reference pixels per channel (paper §4.3 default).

    Estimates from the reference reads alone, so it streams: with
    ``side_columns`` it also needs the side reference columns of every row
    (the whole exposure).

    Parameters
    ----------
    **params
        ``sigma``, ``maxiters``, ``side_columns``, as `reference_offsets`;
        ``telegraph`` (``auto``: leave out the telegraph reference pixels
        `~spherex_reduce.reduce.steps.reference.telegraph.find_telegraph` finds in the
        reads of the exposure; ``keep``) and ``telegraph_sigma``, its threshold
        (declared, with their defaults, by :attr:`parameters`).
    """

    kind, name = "reference", "mean"
    parameters = (
        Parameter("sigma", 3.0, (float,), "clip threshold for reference pixels (standard "
                  "deviations)", minimum=0, exclusive_minimum=True),
        Parameter("maxiters", 5, (int, type(None)), "clipping iterations (null: until converged)",
                  minimum=1, maximum=1000),
        Parameter("side_columns", False, (bool,), "also use the side reference columns of the "
                  "first and last channel"),
        *TELEGRAPH_PARAMETERS,
    )
    acn = False
    #: one mean per channel, forecast unclipped (the clip's effect was measured from 3 σ up)
    noise_effect = ReferenceEffect("mean", linear={"sigma": MEASURED_SIGMA})

    def __init__(self, **params):
        params = validate_parameters(params, self.parameters, type(self).__name__)
        super().__init__(**params)
        self.sigma, self.maxiters = params["sigma"], params["maxiters"]
        self.side_columns = params["side_columns"]
        self.telegraph, self.telegraph_sigma = params["telegraph"], params["telegraph_sigma"]

    @property
    def needs_exposure(self):
        return bool(self.side_columns)

    def estimate(self, side, context, exposure=None):
        g = context.geometry
        columns = (side_column_values(exposure)
                   if self.side_columns and g.reference_column_mask().any() else None)
        if columns is not None:
            _warn_unequal(g)
        reference, values, found = without_telegraph(
            self, reference_pixels(side, context.schedule), side, context.schedule, columns)
        off, used, clipped = _offsets_of(g, reference,
                                         None if columns is None else (values, columns[2]),
                                         acn=self.acn, sigma=self.sigma,
                                         maxiters=self.maxiters, threads=context.threads)
        return ReferenceOffsets(off, used, clipped, [EVEN, ODD] if self.acn else [ALL],
                                telegraph=found)


class AcnReference(MeanReference):
    """Two σ-clipped means per channel, for even and odd samples (ACN, paper §2.4)."""

    name = "acn"
    acn = True
    #: one mean per channel and column-offset parity, forecast unclipped
    noise_effect = ReferenceEffect("acn", linear={"sigma": MEASURED_SIGMA})


class MedianReference(Strategy):
    """Median of all pixels (optical and reference) per channel (paper §5.4).

    Removes the channel offsets better than the reference pixels on measured
    darks, but on sky images every channel holds sky: the median removes the
    sky's large-scale structure along with the offsets (astrophysical
    information is lost).  ``mask_sources`` excludes sources and hot pixels
    found by `source_mask` first, which limits, but does not remove, the loss.

    Parameters
    ----------
    **params
        ``mask_sources``, ``source_sigma``, ``source_npixels``, ``box_size``
        (declared, with their defaults and meaning, by :attr:`parameters`).
    """

    kind, name = "reference", "median"
    parameters = (
        Parameter("mask_sources", False, (bool,), "exclude photutils-segmented sources "
                  "and hot pixels before the median"),
        Parameter("source_sigma", 3.0, (float,), "source detection threshold (background "
                  "rms)", minimum=0, exclusive_minimum=True),
        Parameter("source_npixels", 5, (int,), "minimum source size (pixels)", minimum=1),
        Parameter("box_size", 64, (int,), "background box size (pixels)", minimum=2),
    )

    #: the median is over every pixel of a channel: the whole exposure
    needs_exposure = True

    def __init__(self, **params):
        params = validate_parameters(params, self.parameters, type(self).__name__)
        super().__init__(**params)
        self.mask_sources, self.source_sigma = params["mask_sources"], params["source_sigma"]
        self.source_npixels, self.box_size = params["source_npixels"], params["box_size"]

    def estimate(self, side, context, exposure=None):
        mask_sources, source_sigma = self.mask_sources, self.source_sigma
        source_npixels, box_size = self.source_npixels, self.box_size
        g = exposure.geometry
        nd = exposure.data
        data = np.asarray(nd.data)
        frames = data.reshape(-1, *data.shape[-2:])
        bad = None if exposure.dq is None else (~dq.read_usable(exposure.dq)).reshape(frames.shape)
        excluded = np.zeros(data.shape[-2:], bool)
        if mask_sources:
            image = frames[-1] - frames[0] if data.ndim == 3 else frames[0]
            pix_bad = None if bad is None else bad.any(axis=0)
            excluded = source_mask(np.asarray(image, dtype=np.float64), pix_bad,
                                   nsigma=source_sigma, npixels=source_npixels,
                                   box_size=box_size, dilate=5, background="sextractor",
                                   two_sided=False, min_boxes=1)
        nch, width = g.nchannels, g.channel_width
        nrows = frames.shape[1]

        def by_channel(values):  # (rows, ncols) -> (nch, rows * width), each channel's run
            return values.reshape(nrows, nch, width).transpose(1, 0, 2)

        def channel_medians(f):
            v = np.empty((nch, nrows * width))  # the frame's one float64 copy
            v.reshape(nch, nrows, width)[...] = by_channel(frames[f])
            drop = excluded if bad is None else excluded | bad[f]
            if drop.any():
                v[by_channel(drop).reshape(nch, -1)] = np.nan
            fin = np.isfinite(v)
            n = fin.sum(axis=1)
            if fin.all():
                return np.median(v, axis=1, overwrite_input=True), n
            # only channels with a usable pixel: no warning to silence (warnings' filters
            # are the process's, not this thread's)
            med = np.full(nch, np.nan)
            some = n > 0
            if some.any():
                med[some] = np.nanmedian(v[some], axis=1, overwrite_input=True)
            return med, n

        L = frames.shape[0]
        nthreads = min(L, RunOptions(threads=context.threads).thread_count())
        medians = list(in_threads(range(L), channel_medians, nthreads,
                                  name="spherex-reduce-median"))  # frames on threads
        off = np.stack([m for m, _ in medians])[..., None]
        used = np.stack([n for _, n in medians])[..., None]
        ex = by_channel(excluded).sum(axis=(1, 2))
        clipped = np.broadcast_to(ex, (L, nch))[..., None].copy()
        return ReferenceOffsets(off, used, clipped, [ALL])
