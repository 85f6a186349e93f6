"""Read-level events: a read that is off for most pixels, told from cosmic rays.

A first read that sits below the line of the others (a reset anomaly), or one
read of the middle offset for the whole array (a frame glitch), makes the step
search of ``detect_jumps`` find a "jump" in many pixels at the same read.
Cosmic rays fall on few pixels at every read alike.  `find_read_events` looks
at how the jumps of a set of pixels fall over the reads and over the array:

1. **Over the reads**: the number of pixels ``c_k`` with a jump flagged at
   read ``k`` is compared with the binomial tail of ``N`` pixels at a rate
   ``p_0 = EDGE_FACTOR * (sum of c_j over the other reads + 1) / (N (K - 1))``
   (``K`` candidate reads, the other reads' rate; reads found to be events
   are left out of it).  A read is a candidate when ``P(X >= c_k) < ALPHA /
   K`` and at least ``MIN_FRACTION`` of the pixels jumped there.
   `EDGE_FACTOR` covers the search's uneven false alarms (its first and last
   reads false-alarm up to ~2.5 times as often as the middle ones), so with
   any rates that differ by less than that over the reads a set of pixels
   holds a false event with probability below `ALPHA` (the tests check the
   rule on binomial counts).
2. **Over the array**: the pixels are cut into up to 4 x 4 cells of rows and
   columns; the jumps at the read must fall in at least half of them (a
   shower of cosmic rays is local; a read that is off is off everywhere).
3. **Their size**: steps whose median ``|z|`` is well above the search's
   threshold in fewer than a tenth of the pixels are the pixels' own: an offset
   of the whole set that large would have been found in nearly all of them.

Each excess read is then named: a pair of excess reads ``k``, ``k + 1`` with
steps of opposite signs and counts within a factor `GLITCH_BALANCE` is one read ``k``
that is off (a *frame glitch*; with unequal counts the smaller read's are the second
steps of pairs, and the larger read is named alone);
a lone excess at read 1 is the first read off (*first read*); at the last
read, the last read off (*last read*); elsewhere the whole array stepped at
``k`` (*step*).  A read that is off is left out of every pixel's fit
(``DO_NOT_USE``); a step is a ``JUMP`` at ``k`` for every pixel.
"""

from dataclasses import dataclass

import numpy as np
from astropy.utils.exceptions import AstropyUserWarning
from scipy.special import bdtrc  # scipy.stats would load scipy.optimize with reduce

__all__ = ["ALPHA", "BIG_STEP_FRACTION", "BIG_STEP_MARGIN", "EDGE_FACTOR", "GLITCH_BALANCE",
           "MIN_FRACTION", "JumpWarning", "ReadEvent", "event_message", "excess_reads",
           "find_read_events"]

#: false-alarm probability of a read event in one set of pixels (no read off)
ALPHA = 1e-6
#: the rate of the other reads is multiplied by this to be the null's: the step search's
#: first and last reads false-alarm ~2.5 times as often as its middle ones
EDGE_FACTOR = 3.0
#: a read event holds jumps in at least this fraction of the pixels
MIN_FRACTION = 0.01
#: cells of rows and of columns over which a read event's jumps must spread (half of them)
CELLS = 4
#: a read's steps whose median |z| is this far above the threshold (sigma), in fewer than
#: this fraction of the pixels, are the pixels' own (an offset of the whole set that large
#: would be found in ~98 % of them): 10-30 e cosmic rays falling in 1.2 % of the pixels at
#: one of Roman's 8-frame resultants (median z ~ 7) were taken for the array stepping.  (A
#: read off in a few outputs only, under a tenth of the pixels, is then its pixels' jumps:
#: each fitted around, not told as an event.)
BIG_STEP_MARGIN, BIG_STEP_FRACTION = 2.0, 0.1
#: a read that is off (a frame glitch) steps every pixel into it and out of it alike: the
#: counts of the two reads are within this ratio (else the smaller are the second steps of
#: pairs found about a read that groups several frames)
GLITCH_BALANCE = 0.5


class JumpWarning(AstropyUserWarning):
    """``detect_jumps`` found a read that is off for most pixels, or could not search."""


@dataclass(frozen=True)
class ReadEvent:
    """A read that is off for most pixels of a set (or where the whole array stepped).

    Attributes
    ----------
    read : int
        The read that is off (0 the first of the ramp), or the first read after
        the step (``kind`` ``'step'``).
    kind : {'first read', 'last read', 'frame glitch', 'step', 'bend'}
        ``'bend'``: on 3 reads, where a read that is off (the first low, the middle
        high or the last low, or the other way) bends every ramp alike and no read
        can be named; ``read`` is where the search placed the steps.
    jumps : int
        Pixels whose jump search flagged a jump there.
    expected : float
        Pixels expected to, from the other reads (the null's rate, `EDGE_FACTOR` in).
    pixels : int
        Pixels of the set.
    offset : float
        Median amplitude of their steps at the read (data unit; for a read that is
        off, how far it sits above the line of the others).
    """

    read: int
    kind: str
    jumps: int
    expected: float
    pixels: int
    offset: float

    @property
    def dropped(self):
        """Whether the read is left out of every fit (all but a step and a bend)."""
        return self.kind not in ("step", "bend")


def excess_reads(counts, npixels, alpha=ALPHA):
    """The reads whose count of jumps is above the binomial tail of the other reads' rate.

    Parameters
    ----------
    counts : array_like of int
        Pixels with a jump flagged at each candidate read (``K`` reads).
    npixels : int
        Pixels searched.
    alpha : float
        False-alarm probability of the set (Bonferroni over the ``K`` reads).

    Returns
    -------
    excess : `numpy.ndarray` of bool
        Per read: the count's tail probability is below ``alpha / K`` and at least
        `MIN_FRACTION` of the pixels jumped there.
    expected : `numpy.ndarray` of float
        Per read: ``N p_0``, the count the null allows for.

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.jumps.events import excess_reads
    >>> excess, expected = excess_reads([498, 3, 1, 0, 2, 1], 1600)
    >>> excess.tolist(), round(float(expected[0]), 2)
    ([True, False, False, False, False, False], 4.8)
    """
    c = np.asarray(counts, np.int64)
    k = c.size
    excess = np.zeros(k, bool)
    expected = np.zeros(k)
    if k < 2 or npixels <= 0:
        return excess, expected
    for _ in range(k):  # until no new read is found: events are left out of the rate
        base = np.where(excess, 0, c)
        others = np.maximum((~excess).sum() - (~excess).astype(np.int64), 1)
        rate = (base.sum() - base + 1.0) / (npixels * others)
        p0 = np.minimum(EDGE_FACTOR * rate, 1.0)
        expected = npixels * p0
        tail = bdtrc(c - 1, npixels, p0)  # P(X >= c), the binomial tail
        found = (tail < alpha / k) & (c >= MIN_FRACTION * npixels)
        if not (found & ~excess).any():
            break
        excess |= found
    return excess, expected


def find_read_events(reads, rows, cols, amplitudes, *, nreads, nrows, ncols,
                     alpha=ALPHA, z=None, threshold=None):
    """The read events of a set of ``nrows x ncols`` pixels from the jumps found in them.

    Parameters
    ----------
    reads : array_like of int
        The read flagged for each jump (the first read after the step).
    rows, cols : array_like of int
        Its pixel's row (0 to ``nrows - 1``) and column.
    amplitudes : array_like of float
        Its step (data unit).
    nreads : int
        Reads of the ramps.
    nrows, ncols : int
        Pixels of the set.
    alpha : float
        False-alarm probability of the set (see `excess_reads`).
    z, threshold : array_like of float and float, optional
        Each jump's ``z`` and the search's threshold (sigma): a read whose steps' median
        ``|z|`` is `BIG_STEP_MARGIN` above the threshold and that holds fewer than
        `BIG_STEP_FRACTION` of the pixels is no event (an offset of the whole set that
        large would have been found in nearly every pixel: these are the pixels' own
        steps, cosmic rays falling at that read more than at the others).

    Returns
    -------
    tuple of `ReadEvent`
        In read order.

    Examples
    --------
    Read 0 of a 40 x 40 dark 18 adu low: 500 pixels step up at read 1.

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.jumps.events import find_read_events
    >>> rng = np.random.default_rng(0)
    >>> pix = rng.choice(1600, 500, replace=False)
    >>> reads = np.r_[np.ones(500, int), [7, 30]]
    >>> rows, cols = np.r_[pix // 40, [3, 9]], np.r_[pix % 40, [5, 5]]
    >>> amp = np.r_[np.full(500, 18.0), [90.0, 400.0]]
    >>> [(e.read, e.kind, e.jumps) for e in find_read_events(
    ...     reads, rows, cols, amp, nreads=56, nrows=40, ncols=40)]
    [(0, 'first read', 500)]
    """
    if (z is None) != (threshold is None):
        raise ValueError("find_read_events: z and threshold go together")
    reads = np.asarray(reads, np.int64)
    amplitudes = np.asarray(amplitudes, np.float64)
    npix = int(nrows) * int(ncols)
    if nreads < 3 or not reads.size:
        return ()
    counts = np.zeros(nreads, np.int64)  # pixels with a jump at each read (each once)
    first = np.unique(reads * npix + np.asarray(rows) * ncols + np.asarray(cols))
    np.add.at(counts, first // npix, 1)
    excess, expected = excess_reads(counts[1:], npix, alpha)
    excess = np.r_[False, excess]
    expected = np.r_[0.0, expected]
    if not excess.any():
        return ()
    nr, nc = min(CELLS, int(nrows)), min(CELLS, int(ncols))
    cell = (np.asarray(rows) * nr // nrows) * nc + np.asarray(cols) * nc // ncols
    offsets = np.zeros(nreads)
    for k in np.flatnonzero(excess):
        at = reads == k
        if np.unique(cell[at]).size * 2 < nr * nc:  # local: a shower, not the read
            excess[k] = False
        if (z is not None and counts[k] < BIG_STEP_FRACTION * npix
                and np.median(np.abs(np.asarray(z)[at])) >= threshold + BIG_STEP_MARGIN):
            excess[k] = False  # steps too large for so few pixels: not the whole set's
        offsets[k] = np.median(amplitudes[at])
    events, skip = [], set()
    for k in np.flatnonzero(excess):
        if k in skip:
            continue
        if nreads == 3:  # two reads after the first, each step the other's bend: no read named
            read, kind, offset = k, "bend", offsets[k]
            events.append(ReadEvent(int(read), kind, int(counts[k]), float(expected[k]),
                                    npix, float(offset)))
            continue
        if k + 1 < nreads and excess[k + 1] and offsets[k] * offsets[k + 1] < 0:
            skip.add(k + 1)
            pair = counts[k:k + 2]
            if pair.min() >= GLITCH_BALANCE * pair.max():
                events.append(ReadEvent(int(k), "frame glitch", int(counts[k]),
                                        float(expected[k]), npix, float(offsets[k])))
                continue
            # one read holds most of them: the other's are its pairs' second steps (a
            # step into a group of frames and out of it), not an event of their own
            k += int(counts[k + 1] > counts[k])
        if k == 1:
            read, kind, offset = 0, "first read", -offsets[k]
        elif k == nreads - 1:
            read, kind, offset = k, "last read", offsets[k]
        else:
            read, kind, offset = k, "step", offsets[k]
        events.append(ReadEvent(int(read), kind, int(counts[k]), float(expected[k]), npix,
                                float(offset)))
    return tuple(events)


def event_message(read, kind, jumps, expected, pixels, offset, dropped_before=0):
    """The one line that tells the user of a read event (the totals over the array).

    ``dropped_before``: frames the input already left out (``NDROPRD``), so that the
    fix named for a first read counts from the file's first.

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.jumps.events import event_message
    >>> text = event_message(0, "first read", 498, 0.7, 1600, -17.9)
    >>> print(text)  # doctest: +NORMALIZE_WHITESPACE
    detect_jumps: read 0 is off in most pixels (first read: 498 of 1600 pixels step
    there, 0.7 expected from the other reads; median -17.9 from the line of the
    others): left out of every fit (DO_NOT_USE on that read), not counted as jumps;
    to leave it out from the start give input: drop_first_reads: 1
    """
    if kind == "bend":
        return (f"detect_jumps: 3 reads: the ramps of most pixels bend alike ({jumps} of "
                f"{pixels} pixels step at read {read}, {expected:.1f} expected, median "
                f"{offset:+.1f}): a read off for every pixel (the first low, the middle high "
                f"or the last low, or the other way), which 3 reads cannot name; no read left "
                f"out, not counted as jumps, each ramp fitted as its line; if the first read "
                f"is off give input: drop_first_reads: {dropped_before + 1} (the 2 reads "
                f"left are then fitted without a jump search)")
    what = (f"the array stepped at read {read}" if kind == "step"
            else f"read {read} is off in most pixels")
    how = (f"{kind}: {jumps} of {pixels} pixels step there, {expected:.1f} expected from the "
           f"other reads; median {offset:+.1f} from the line of the others")
    if kind == "step":
        done = "every pixel is fitted in two segments around it (JUMP on that read)"
    else:
        done = "left out of every fit (DO_NOT_USE on that read), not counted as jumps"
    if kind == "first read":
        fix = f"; to leave it out from the start give input: drop_first_reads: " \
              f"{dropped_before + 1}"
    elif kind == "step":
        fix = ""
    else:
        fix = "; if it recurs, flag that read DO_NOT_USE in the input's DQ"
    return f"detect_jumps: {what} ({how}): {done}{fix}"
