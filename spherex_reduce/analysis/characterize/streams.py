"""The per-channel noise streams of a raw dark, one value per row read, in time order.

Every stream is detrended across frames at each position
(`~spherex_reduce.analysis.timestreams.detrend_frames`): the straight line in
time of each pixel (its bias and dark current) is removed, so what is left is
the readout noise the simulator's components model.  Per channel and row read:

- ``sum``: the mean of the channel's light-sensitive columns (in the reads of
  reference rows, the reference pixels of those same columns, so that the
  stream is evenly sampled);
- ``diff``: half the difference of the means of its even and odd columns (by
  offset in the row read; equal numbers of each), where alternating column
  noise (ACN) alone leaves correlated power;
- ``phantom``: the phantom value (the mean of the ``c`` phantom samples);
- ``reference``: the reference-row reads' pixels, even and odd columns apart
  (bursts at half the pixel rate: alternating column noise makes the two
  parities independent streams), and the side reference columns' mean per
  read for the channels that have side columns.

Columns holding a value that is not finite in any read of any frame are left
out of the means.  Pixels whose noise the per-pixel terms hold (``leave_out``:
a telegraph's steps, a hot pixel's shot noise) are left out of every stream, so
that the model holds them once: a row read's mean is over its other pixels (and
the white level of a mean of fewer pixels is larger: `Box.white` is the factor,
so the fits report the white level of one sample), and a reference-row burst
holding one is left out whole.

A dark is read band by band of reads (`dark_streams`, from any
`~spherex_reduce.io.sources.Source`: a raw file with ``pread``), never whole:
each band is reduced to the channels' sums and the few values the reference
and phantom streams need (`~spherex_reduce.analysis.timestreams.StreamPixels`).
"""

from typing import NamedTuple

import numpy as np

from ...core.dq import read_usable
from ...core.errors import SpherexReduceError
from ...io.sources import MemorySource
from ...reduce.options import default_threads, in_threads
from ..timestreams import (
    StreamPixels,
    detrend_frames,
    keep_some,
    left_out_samples,
    phantom_timestream,
    reference_row_reads,
    reference_timestream,
)

__all__ = ["BAND_READS", "STREAM_THREADS", "Box", "ChannelStreams", "channel_streams",
           "dark_streams", "pooled_boxes", "shot_white"]

#: Fewest frames a dark (or a segment of one) needs: a straight line is removed across them.
MIN_FRAMES = 3
#: Narrowest channel whose reference-row reads give a spectrum: a parity's burst of 16
#: samples has the 5 Welch frequencies a fit of the white level uses.
MIN_BURST = 32
#: Reads of every frame `dark_streams` reads at a time (a full-size dark's 74 frames: 39 MB of
#: float32, where the dark is 1.27 GB).
BAND_READS = 64
#: Bands of reads `dark_streams` sums at once, in threads, while the next is read (each
#: holds its band and ~2 bands of work).
STREAM_THREADS = 2


class Box(NamedTuple):
    """Which samples of a row read a stream averages: ``n`` samples ``stride`` apart whose
    centre is ``centre`` samples after the read's first sample."""

    n: int
    stride: int
    centre: float
    #: how many of the samples sit at even offsets (alternating column noise's even stream)
    even: int = 0
    #: the centre in each channel, where channels average other offsets
    centres: tuple = ()
    #: per channel, the mean over reads of the white level of the average relative to one of
    #: ``n`` samples (pixels left out of some reads average fewer); empty: 1
    whites: tuple = ()

    @property
    def white(self):
        """The factor of the white level of the average, the mean over channels of
        `whites` (1 without).

        Examples
        --------
        >>> from spherex_reduce.analysis.characterize.streams import Box
        >>> Box(4, 1, 1.5).white, Box(4, 1, 1.5, whites=(1.0, 1.5)).white
        (1.0, 1.25)
        """
        return float(np.mean(self.whites)) if self.whites else 1.0

    @property
    def acn_factor(self):
        """The fraction of an ACN component's power the average keeps: ``(e² + o²)/n²``
        for ``e`` even and ``o`` odd samples (1/2 for as many of each).

        Examples
        --------
        >>> from spherex_reduce.analysis.characterize.streams import Box
        >>> Box(4, 1, 1.5, even=2).acn_factor, Box(3, 1, 1.0, even=2).acn_factor
        (0.5, 0.5555555555555556)
        """
        odd = self.n - self.even
        return (self.even**2 + odd**2) / self.n**2


class ChannelStreams(NamedTuple):
    """The streams of one dark (`channel_streams`), each ``(nchannels, nframes, nreads)``
    (``reference_rows``: ``(nchannels, nframes, n_ref_reads, width)``), None where the dark
    has none."""

    sum: np.ndarray
    diff: np.ndarray | None
    phantom: np.ndarray | None
    #: ``(nchannels, 2, nframes, n_ref_reads, width / 2)``: even and odd columns apart
    reference_rows: np.ndarray | None
    #: ``{channel: (nframes, nreads)}``: the side reference columns' mean per read
    reference_sides: dict
    #: the averages: ``sum``, ``diff`` (one parity), ``phantom``, ``sides``
    boxes: dict
    #: ``(nchannels, 2, n_ref_reads)``: the reference-row bursts kept (none left out); None:
    #: all
    reference_kept: np.ndarray | None = None


def _active_columns(g, usable):
    """Per channel: the light-sensitive columns of ``usable`` (bool ``(ncols,)``: finite and
    unmasked in every read), in scan order, and their offsets in the row read."""
    light = ~g.reference_column_mask() & usable
    offs, chan = g.column_offsets(), g.channel_of_column()
    out = []
    for c in range(g.nchannels):
        cols = np.flatnonzero(light & (chan == c))
        cols = cols[np.argsort(offs[cols])]
        if cols.size == 0:
            raise SpherexReduceError(f"channel {c} has no light-sensitive column with finite "
                                     "values in every read: nothing to characterise")
        out.append(cols)
    return out, offs


class _Plan(NamedTuple):
    """What the light-sensitive streams of a run of frames average: per channel, its
    columns (the first ``n``, every channel as many) in three groups (the two parities'
    first ``k``, then the rest), the samples left out of each group (``(reads, columns)``
    or None) and how many each group sums per read."""

    columns: list
    offs: np.ndarray
    n: int
    parts: list
    lefts: list
    counts: list

    @property
    def key(self):
        return tuple(tuple(cols[:self.n].tolist()) for cols in self.columns)


def _plan(g, n_reads, usable, drop):
    """The `_Plan` of the columns ``usable`` (``(ncols,)``), ``drop`` left out."""
    columns, offs = _active_columns(g, usable)
    n = min(cols.size for cols in columns)
    parts, lefts, counts = [], [], []
    for cols in columns:
        cols = cols[:n]  # every channel averages the same number of columns
        even = cols[offs[cols] % 2 == 0]
        odd = cols[offs[cols] % 2 == 1]
        k = min(even.size, odd.size)
        # one pass over the pixels: the sums of each parity's first k columns, then the rest
        part = [even[:k], odd[:k], np.concatenate([even[k:], odd[k:]])]
        left = _left_out_parts(drop, part)
        parts.append(part)
        lefts.append(left)
        counts.append([np.full(n_reads, float(c.size)) if m is None or c.size == 0
                       else (c.size - m.sum(axis=1)).astype(float)
                       for c, m in zip(part, left, strict=True)])
    return _Plan(columns, offs, n, parts, lefts, counts)


def channel_streams(exposure, frames=None, leave_out=None):
    """The detrended per-channel streams of one raw dark.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Raw ramps in readout order (frames × reads × columns).
    frames : slice, optional
        The frames used (a segment of the dark); default all.
    leave_out : array_like of bool, optional
        ``(nrows, ncols)`` in physical order: pixels left out of every stream
        (`~spherex_reduce.analysis.pixel_terms.PixelSums.add`'s: those whose noise
        the per-pixel terms hold).  A read's mean is over its other pixels (all
        of the channel's where every one would be left out; a parity's where
        all of its would, for the even/odd stream); `Box.whites` says by how
        much that raises the white level.

    Returns
    -------
    `ChannelStreams`

    Raises
    ------
    SpherexReduceError
        Not raw ramps in readout order, fewer than `MIN_FRAMES` frames, or a channel
        without a usable light-sensitive column.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize.streams import channel_streams
    >>> st = channel_streams(example_raw_exposure())
    >>> st.sum.shape == st.phantom.shape, st.boxes["phantom"].n
    (True, 2)
    """
    return dark_streams(MemorySource(exposure), [slice(None) if frames is None else frames],
                        leave_out)[0]


def dark_streams(source, cuts, leave_out=None, band_reads=BAND_READS):
    """The detrended per-channel streams of one raw dark read band by band of reads: for
    each run of frames of ``cuts``, what `channel_streams` gives of it.

    The dark is never held whole: ``band_reads`` reads of every frame at a time
    are reduced to the channels' sums and the reference pixels' and phantom
    values the streams need (`~spherex_reduce.analysis.timestreams.StreamPixels`),
    up to `STREAM_THREADS` bands at once in threads while the next is read (so
    up to `STREAM_THREADS` + 1 bands are held).
    Which columns are averaged (those finite and unmasked in every read of a
    run) is known once every band is read: a dark where some column is not is
    read a second time.

    Parameters
    ----------
    source : `~spherex_reduce.io.sources.Source`
        The dark (`~spherex_reduce.io.sources.open_input`'s: a raw file read in
        bands, or an exposure in memory).
    cuts : sequence of slice
        Runs of frames, each detrended alone.
    leave_out : array_like of bool, optional
        As `channel_streams`.
    band_reads : int
        Reads of every frame in a band.

    Returns
    -------
    list of `ChannelStreams`
        One per run of ``cuts``.

    Raises
    ------
    SpherexReduceError
        As `channel_streams`.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.io.sources import MemorySource
    >>> from spherex_reduce.analysis.characterize.streams import channel_streams, dark_streams
    >>> e = example_raw_exposure()
    >>> st = dark_streams(MemorySource(e), [slice(0, 3), slice(3, 6)], band_reads=5)
    >>> bool(np.array_equal(st[1].sum, channel_streams(e, frames=slice(3, 6)).sum))
    True
    """
    ctx = source.context
    if not ctx.ramp or ctx.order != "readout":
        raise SpherexReduceError(
            "characterize takes raw darks: ramps in readout order (the files reduce reads), "
            "not reduced images nor single reads (a dark stored one 2-D file per read is one "
            "input: --reads 'DIR/read_*.fits', in Python the list of its files)")
    s = ctx.schedule
    g = s.geometry
    frames = [range(s.nframes)[cut] for cut in cuts]
    for f in frames:
        if len(f) < MIN_FRAMES:
            raise SpherexReduceError(f"a dark of {len(f)} reads: every term needs at least "
                                     f"{MIN_FRAMES} (a straight line is removed across them)")
    drop = left_out_samples(leave_out, s)  # (reads, columns), or None
    # every column taken as usable until the bands are read
    guess = _plan(g, s.n_reads, np.ones(g.ncols, bool), drop)
    plans = {guess.key: guess}
    sums, usable, pixels = _read_bands(source, list(plans.values()), drop, band_reads)
    found = [_plan(g, s.n_reads, usable[f].all(axis=0), drop) for f in frames]
    if any(p.key != guess.key for p in found):  # not every column
        plans = {p.key: p for p in found}
        sums, usable, pixels = _read_bands(source, list(plans.values()), drop, band_reads)
    keys = list(plans)
    return [_streams(found[i], *sums[keys.index(found[i].key)], cut, len(frames[i]), pixels,
                     leave_out) for i, cut in enumerate(cuts)]


def _read_bands(source, plans, drop, band_reads):
    """Read ``source`` band by band of reads: per plan, the channels' mean and half the
    even-odd difference of their light-sensitive columns ``(nchannels, nframes, n_reads)``
    (float64), the columns finite and unmasked in every read of each frame ``(nframes,
    ncols)``, and the `~spherex_reduce.analysis.timestreams.StreamPixels`.

    The bands are read here, in order (a source need not be thread-safe), and up to
    `STREAM_THREADS` of them are summed at once in threads while the next is read: each
    writes its own reads of the outputs, so the numbers do not depend on the threads."""
    s = source.context.schedule
    g = s.geometry
    shape = (g.nchannels, s.nframes, s.n_reads)
    sums = [(np.empty(shape), np.empty(shape) if all(p[0].size for p in plan.parts) else None)
            for plan in plans]
    usable = np.ones((s.nframes, g.ncols), bool)
    columns = np.flatnonzero(g.reference_column_mask())
    reads = reference_row_reads(s)
    out = {}
    step = max(int(band_reads), 1)

    def read(band):  # here, in order; the outputs' types are the first band's
        block = source.read(*band)
        if not out:
            dtype = np.asarray(block.data).dtype
            out["columns"] = np.empty((s.nframes, s.n_reads, columns.size), dtype)
            out["reads"] = np.empty((s.nframes, reads.size, g.ncols), dtype)
            out["phantom"] = (None if block.phantom is None else
                              np.empty((s.nframes, s.n_reads, g.nchannels), block.phantom.dtype))
        return block

    def one(band, block):  # one band: its reads of every output, and its usable columns
        lo, hi = band
        data = np.asarray(block.data)
        ok = np.all(np.isfinite(data), axis=1)
        if block.dq is not None:
            ok &= np.all(read_usable(np.asarray(block.dq)), axis=1)
        out["columns"][:, lo:hi] = data[:, :, columns]
        here = (reads >= lo) & (reads < hi)
        out["reads"][:, here] = data[:, reads[here] - lo]
        if out["phantom"] is not None:
            out["phantom"][:, lo:hi] = block.phantom
        for plan, (mean, diff) in zip(plans, sums, strict=True):
            for c in range(g.nchannels):
                se, so, rest = (_kept_sum(data, part, None if left is None else left[lo:hi])
                                for part, left in zip(plan.parts[c], plan.lefts[c], strict=True))
                ne, no, nrest = (count[lo:hi] for count in plan.counts[c])
                mean[c, :, lo:hi] = (se + so + rest) / (ne + no + nrest)
                if diff is not None:
                    diff[c, :, lo:hi] = 0.5 * (se / ne - so / no)
        return ok

    bands = [(lo, min(lo + step, s.n_reads)) for lo in range(0, s.n_reads, step)]
    nthreads = max(1, min(STREAM_THREADS, default_threads(), len(bands)))
    for ok in in_threads(bands, one, nthreads, read=read, name="spherex-reduce-streams"):
        usable &= ok
    pixels = StreamPixels(s, columns, out.get("columns"), reads, out.get("reads"),
                          out.get("phantom"))
    return sums, usable, pixels


def _streams(plan, mean, diff, cut, nframes, pixels, leave_out):
    """The `ChannelStreams` of the run of ``nframes`` frames ``cut`` (a slice) of one dark,
    whose light-sensitive streams of ``plan`` are ``mean`` and ``diff`` (every frame)."""
    s = pixels.schedule.replace(nframes=nframes)
    g = s.geometry
    pixels = pixels._replace(
        schedule=s, column_values=pixels.column_values[cut], read_values=pixels.read_values[cut],
        phantom=None if pixels.phantom is None else pixels.phantom[cut])
    offs, n, c = plan.offs, plan.n, s.phantom_reads
    whites, dwhites = [], []
    for (ne, no, nrest), parts in zip(plan.counts, plan.parts, strict=True):
        whites.append(float(np.mean(n / (ne + no + nrest))))
        k = parts[0].size  # the parities' columns of each
        if k:
            dwhites.append(float(np.mean(0.5 * (k / ne + k / no))))
    first = offs[plan.columns[0][:n]]
    centres = tuple(c + float(np.mean(offs[cols[:n]])) for cols in plan.columns)
    kept = leave_out is not None
    boxes = {"sum": Box(n, 1, float(np.mean(centres)), int(np.sum(first % 2 == 0)), centres,
                        tuple(whites) if kept else ())}
    if diff is not None:
        half = min(int(np.sum(offs[cols[:n]] % 2 == p)) for cols in plan.columns for p in (0, 1))
        diff = detrend_frames(diff[:, cut])
        boxes["diff"] = Box(half, 2, boxes["sum"].centre, whites=tuple(dwhites) if kept else ())
    phantom = None
    if pixels.phantom is not None and c:
        phantom = phantom_timestream(pixels).values
        # phantom sample i has the parity (i - c) % 2 (the simulator's convention)
        boxes["phantom"] = Box(c, 1, (c - 1) / 2, int(np.sum((np.arange(c) - c) % 2 == 0)))
    rows = bursts = None
    if pixels.reads.size and g.channel_width >= MIN_BURST:
        rows = np.stack([reference_timestream(pixels, "rows", p, leave_out).values
                         for p in ("even", "odd")], axis=1)
        if kept:  # a burst holding a pixel left out is left out whole
            # a channel keeps its bursts if none is
            bursts = keep_some(~np.any(np.isnan(rows), axis=(2, 4)), axis=(1, 2))
            rows = np.nan_to_num(rows)  # bursts with values left out: kept apart by bursts
    sides = {}
    mask = g.reference_column_mask()
    if mask.any():
        side = reference_timestream(pixels, "columns", leave_out=leave_out)
        cols = np.flatnonzero(mask)
        chan = g.channel_of_column()[cols]
        runs = np.flatnonzero((np.diff(cols) != 1) | (np.diff(chan) != 0)) + 1
        owners = [int(chan[i]) for i in np.concatenate([[0], runs])]
        for owner, values in zip(owners, side.values, strict=True):
            sides[owner] = values
        white = dict(zip(owners, side.white, strict=True)) if side.white else {}
        boxes["sides"] = Box(side.nbox, side.stride, 0.0, whites=tuple(
            white.get(o, 1.0) for o in range(g.nchannels)) if white else ())
    return ChannelStreams(detrend_frames(mean[:, cut]), diff, phantom, rows, sides, boxes,
                          bursts)


def pooled_boxes(boxes):
    """The averages of several darks' streams (`ChannelStreams.boxes`) whose spectra are
    pooled (`~spherex_reduce.analysis.characterize.spectra.pool`, each dark alike): the
    first's, with the white factors (`Box.whites`) averaged over the darks.

    Examples
    --------
    >>> from spherex_reduce.analysis.characterize.streams import Box, pooled_boxes
    >>> a, b = {"sum": Box(4, 1, 1.5, whites=(1.0, 1.5))}, {"sum": Box(4, 1, 1.5)}
    >>> pooled_boxes([a, b])["sum"].whites
    (1.0, 1.25)
    """
    out = {}
    for key, box in boxes[0].items():
        if not any(b[key].whites for b in boxes):
            out[key] = box
            continue
        nch = max(len(b[key].whites) for b in boxes)
        whites = np.mean([b[key].whites or (1.0,) * nch for b in boxes], axis=0)
        out[key] = box._replace(whites=tuple(float(w) for w in whites))
    return out


def shot_white(rate, times, sample_rate):
    """The white level a shot noise adds to a detrended stream of pixels, as the fits
    report white levels (``alpha`` of one sample).

    A current's shot noise is a random walk of each pixel across frames: the
    straight line `~spherex_reduce.analysis.timestreams.detrend_frames` removes
    leaves a residual of variance ``rate · κ`` per value (``κ`` the mean over
    frames of the diagonal of ``P W P · N / (N − 2)``, ``W = min(t_i, t_j)``,
    ``P`` the projector off the line), independent between pixels, so white along
    a stream: ``alpha = 2 rate κ / sample_rate``.

    Parameters
    ----------
    rate : float
        The shot noise's variance per unit time (unit²/s: a current over the gain).
    times : array_like
        The ``N`` frame start times (s) of the stream.
    sample_rate : float
        The pixel rate (Hz).

    Returns
    -------
    float
        unit²/Hz.

    Examples
    --------
    Four frames 1 s apart: ``κ`` = 0.4 s.

    >>> from spherex_reduce.analysis.characterize.streams import shot_white
    >>> shot_white(2.0, [0.0, 1.0, 2.0, 3.0], 1e5)
    1.6e-05
    """
    t = np.asarray(times, dtype=np.float64)
    t = t - t[0]
    n = t.size
    x = np.arange(n) - (n - 1) / 2  # detrend_frames' line: in frame index
    proj = np.eye(n) - 1.0 / n - np.outer(x, x) / np.sum(x * x)
    kappa = np.mean(np.diag(proj @ np.minimum.outer(t, t) @ proj)) * n / (n - 2)
    return float(2 * rate * kappa / sample_rate)


def _left_out_parts(drop, parts):
    """The samples left out of each of a channel's column groups ``parts`` (the two
    parities' first ``k`` columns, then the rest), ``drop`` ``(reads, columns)`` (None:
    none): a read whose every column would be left out keeps them all, and a parity
    group keeps its columns at a read where all of them would be left out (its mean is
    the even/odd stream's)."""
    if drop is None:
        return [None] * len(parts)
    left = [drop[:, part] for part in parts]
    every = np.all(np.concatenate(left, axis=1), axis=1)
    for i in range(len(parts)):
        keep = every | (np.all(left[i], axis=1) if i < 2 else False)
        left[i] = left[i] & ~keep[:, None]
    return left


def _columns_view(data, cols):
    """``data[:, :, cols]`` (``cols`` integers): a view when they are evenly spaced (a
    channel's even or odd columns), which is summed without the copy a list of columns
    takes.  Not for 8-byte data (float64 in either byte order), whose sum over a view is not
    bit for bit that of the copy (float32 ones go through numpy's buffer in float64 alike)."""
    if cols.size > 1 and data.dtype.itemsize < 8 and cols[0] >= 0:
        step = int(cols[1] - cols[0])
        if step > 0 and np.all(np.diff(cols) == step):
            return data[:, :, int(cols[0]):int(cols[-1]) + 1:step]
    return data[:, :, cols]


def _kept_sum(data, cols, drop):
    """Per frame and read, the sum over ``cols`` of the values not dropped (``drop``:
    ``(reads, cols)``, None: none)."""
    total = np.sum(_columns_view(data, cols), axis=-1, dtype=np.float64)
    if drop is None or cols.size == 0:
        return total
    r, j = np.nonzero(drop)
    if r.size:  # few: their values taken back out of the sums
        np.subtract.at(total, (slice(None), r), data[:, r, cols[j]])
    return total
