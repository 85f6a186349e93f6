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
out of the means.
"""

from typing import NamedTuple

import numpy as np

from ...core.errors import SpherexReduceError
from ..timestreams import (
    detrend_frames,
    phantom_timestream,
    reference_row_reads,
    reference_timestream,
)

__all__ = ["Box", "ChannelStreams", "channel_streams"]

#: Fewest frames a dark (or a segment of one) needs: a straight line is removed across them.
MIN_FRAMES = 3
#: Narrowest channel whose reference-row reads give a spectrum: a parity's burst of 16
#: samples has the 5 Welch frequencies a fit of the white level uses.
MIN_BURST = 32


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


def _active_columns(exposure):
    """Per channel: the light-sensitive columns with finite values, in scan order, and
    their offsets in the row read."""
    g = exposure.geometry
    data = np.asarray(exposure.data.data)
    finite = np.ones(data.shape[-1], bool)
    for frame in data:  # a frame at a time: no cube-sized temporary
        finite &= np.all(np.isfinite(frame), axis=0)
    if exposure.data.mask is not None:
        for frame in np.asarray(exposure.data.mask):
            finite &= ~np.any(frame, axis=0)
    light = ~g.reference_column_mask() & finite
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


def channel_streams(exposure, frames=None):
    """The detrended per-channel streams of one raw dark.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Raw ramps in readout order (frames × reads × columns).
    frames : slice, optional
        The frames used (a segment of the dark); default all.

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
    if not exposure.is_ramp or exposure.order != "readout":
        raise SpherexReduceError(
            "characterize takes raw darks: ramps in readout order (the files reduce reads), "
            "not reduced images nor single reads (a dark stored one 2-D file per read is one "
            "input: --reads 'DIR/read_*.fits', in Python the list of its files)")
    if frames is not None:
        exposure = _frames_of(exposure, frames)
    s, g = exposure.schedule, exposure.geometry
    if s.nframes < MIN_FRAMES:
        raise SpherexReduceError(f"a dark of {s.nframes} reads: every term needs at least "
                                 f"{MIN_FRAMES} (a straight line is removed across them)")
    data = np.asarray(exposure.data.data)
    columns, offs = _active_columns(exposure)
    c = s.phantom_reads
    n = min(cols.size for cols in columns)
    sums, diffs = [], []
    for cols in columns:
        cols = cols[:n]  # every channel averages the same number of columns
        even = cols[offs[cols] % 2 == 0]
        odd = cols[offs[cols] % 2 == 1]
        k = min(even.size, odd.size)
        # one pass over the pixels: the sums of each parity's first k columns, then the rest
        se = np.sum(data[:, :, even[:k]], axis=-1, dtype=np.float64)
        so = np.sum(data[:, :, odd[:k]], axis=-1, dtype=np.float64)
        rest = np.concatenate([even[k:], odd[k:]])
        total = se + so
        if rest.size:
            total += np.sum(data[:, :, rest], axis=-1, dtype=np.float64)
        sums.append(total / n)
        if k:
            diffs.append(0.5 * (se - so) / k)
    sums = np.stack(sums)  # the channels' arrays released
    first = offs[columns[0][:n]]
    centres = tuple(c + float(np.mean(offs[cols[:n]])) for cols in columns)
    boxes = {"sum": Box(n, 1, float(np.mean(centres)), int(np.sum(first % 2 == 0)), centres)}
    diff = None
    if len(diffs) == g.nchannels:
        half = min(int(np.sum(offs[cols[:n]] % 2 == p)) for cols in columns for p in (0, 1))
        diffs = np.stack(diffs)
        diff = detrend_frames(diffs)
        boxes["diff"] = Box(half, 2, boxes["sum"].centre)
    del diffs
    phantom = None
    if exposure.phantom is not None and c:
        phantom = phantom_timestream(exposure).values
        # phantom sample i has the parity (i - c) % 2 (the simulator's convention)
        boxes["phantom"] = Box(c, 1, (c - 1) / 2, int(np.sum((np.arange(c) - c) % 2 == 0)))
    rows = None
    if reference_row_reads(s).size and g.channel_width >= MIN_BURST:
        rows = np.stack([reference_timestream(exposure, "rows", p).values
                         for p in ("even", "odd")], axis=1)
    sides = {}
    mask = g.reference_column_mask()
    if mask.any():
        side = reference_timestream(exposure, "columns")
        cols = np.flatnonzero(mask)
        chan = g.channel_of_column()[cols]
        runs = np.flatnonzero((np.diff(cols) != 1) | (np.diff(chan) != 0)) + 1
        owners = [int(chan[i]) for i in np.concatenate([[0], runs])]
        for owner, values in zip(owners, side.values, strict=True):
            sides[owner] = values
        boxes["sides"] = Box(side.nbox, side.stride, 0.0)
    return ChannelStreams(detrend_frames(sums), diff, phantom, rows, sides, boxes)


def _frames_of(exposure, frames):
    """The exposure restricted to ``frames`` (a slice of its frames)."""
    from ...core.exposure import Exposure

    s = exposure.schedule
    keep = range(s.nframes)[frames]
    schedule = s.replace(nframes=len(keep))
    data = np.asarray(exposure.data.data)[frames]
    phantom = None if exposure.phantom is None else np.asarray(exposure.phantom)[frames]
    mask = exposure.data.mask
    if mask is not None:
        mask = np.asarray(mask)
        mask = mask[frames] if mask.ndim == 3 else mask
    return Exposure.from_arrays(data, schedule, phantom=phantom, unit=exposure.unit,
                                mask=mask)
