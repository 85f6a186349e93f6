"""Telegraph pixels: steps down and back up (or up and back down), told from cosmic rays.

A pixel with random telegraph noise flips between two levels; its ramp is the
same line in both, offset while it sits in the other level.  The step search
finds each flip as a "jump"; but a cosmic ray only adds charge, and never
takes it back.  `telegraph_pixels` takes a pixel whose steps (at least two,
in read order) alternate in sign with each pair of neighbours cancelling
within ``TELEGRAPH_SIGMA`` of their amplitudes' errors as a telegraph pixel:
its steps are not jumps, and the reads it spent in its rarer level are left
out of its fit, so that its other reads lie on one line.
"""

import numpy as np

__all__ = ["TELEGRAPH_SIGMA", "telegraph_flips", "telegraph_pixels"]

#: two steps of opposite signs cancel (a flip and its return) when their sum is within
#: this many of its standard errors
TELEGRAPH_SIGMA = 3.0


def telegraph_pixels(pixel, read, amplitude, ramps, times, usable=None):
    """Which of the jumps found are a telegraph pixel's flips, and the reads to leave out.

    A pixel whose steps (at least two) alternate in sign is fitted again, by least
    squares of a line plus all its steps on its usable reads (the search's amplitudes
    are each conditional on the steps found before it): when the joint amplitudes
    alternate too and each neighbouring pair sums to zero within `TELEGRAPH_SIGMA`
    standard errors (from the fit's residuals), the pixel is a telegraph pixel.

    Parameters
    ----------
    pixel, read : array_like of int
        The pixel of each jump (a column of ``ramps``) and its read (the first
        read after the step).
    amplitude : array_like of float
        The step the search found (data unit): only its sign is used.
    ramps : `numpy.ndarray`
        Reads ``(n, m)`` of the ``m`` pixels (data unit).
    times : array_like of float
        Time of each read (s).
    usable : `numpy.ndarray` of bool, optional
        ``(n, m)``: the reads that may be fitted (default all).

    Returns
    -------
    flips : `numpy.ndarray` of bool
        Per jump: a flip of a telegraph pixel (not a jump).
    left_out : tuple of two `numpy.ndarray` of int
        ``(reads, pixels)`` the telegraph pixels spent in the level where they
        have fewer usable reads (the first level on a tie).

    Examples
    --------
    Pixel 0 drops by 40 at read 15, comes back at 25, drops at 35 and comes back at 45;
    pixel 1 has a cosmic ray at read 30:

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.jumps.telegraph import telegraph_pixels
    >>> t = np.arange(56) * 3.0
    >>> y = 100 + np.random.default_rng(0).normal(0, 5, (56, 2))
    >>> y[15:25, 0] -= 40; y[35:45, 0] -= 40; y[30:, 1] += 300
    >>> flips, (reads, pixels) = telegraph_pixels([0, 0, 0, 0, 1], [15, 25, 35, 45, 30],
    ...                                           [-1, 1, -1, 1, 1], y, t)
    >>> flips.tolist(), sorted(set(pixels.tolist())), reads.size
    ([True, True, True, True, False], [0], 20)
    """
    pixel = np.asarray(pixel, np.int64)
    read = np.asarray(read, np.int64)
    sign = np.sign(np.asarray(amplitude, np.float64))
    times = np.asarray(times, np.float64)
    nreads = times.size
    flips = np.zeros(pixel.size, bool)
    out_reads, out_pixels = [], []
    order = np.lexsort((read, pixel))
    starts = np.flatnonzero(np.r_[True, np.diff(pixel[order]) != 0])
    ends = np.r_[starts[1:], order.size]
    for lo, hi in zip(starts, ends, strict=True):
        idx = order[lo:hi]
        if idx.size < 2 or (sign[idx][1:] * sign[idx][:-1] >= 0).any():
            continue  # one step, or not alternating
        col = pixel[idx[0]]
        reads = read[idx]
        if not _flips_cancel(ramps[:, col], times, reads,
                             None if usable is None else usable[:, col]):
            continue
        flips[idx] = True
        level = np.zeros(nreads, np.int64)  # 1 while in the level the first flip leads to
        for k, r in enumerate(reads):
            level[r:] = 1 - k % 2
        counted = np.ones(nreads, bool) if usable is None else usable[:, col]
        high = int(level[counted].sum())  # usable reads in each level
        rare = np.flatnonzero(level == (1 if high < counted.sum() - high else 0))
        out_reads.append(rare)
        out_pixels.append(np.full(rare.size, col))
    if not out_reads:
        empty = np.zeros(0, np.int64)
        return flips, (empty, empty)
    return flips, (np.concatenate(out_reads), np.concatenate(out_pixels))


def _flips_cancel(y, times, reads, usable):
    """Whether the joint least-squares steps at ``reads`` of one ramp ``y`` alternate in
    sign, each neighbouring pair summing to zero within `TELEGRAPH_SIGMA` errors."""
    use = np.isfinite(y) if usable is None else usable & np.isfinite(y)
    steps = (np.arange(times.size)[:, None] >= reads[None, :]).astype(np.float64)
    x = np.column_stack([np.ones(times.size), times, steps])[use]
    dof = x.shape[0] - x.shape[1]
    if dof < 1:
        return False
    coef, _, rank, _ = np.linalg.lstsq(x, np.asarray(y, np.float64)[use], rcond=None)
    if rank < x.shape[1]:
        return False
    resid = np.asarray(y, np.float64)[use] - x @ coef
    cov = np.linalg.inv(x.T @ x) * (resid @ resid / dof)
    a = coef[2:]
    if (a[1:] * a[:-1] >= 0).any():
        return False
    c = cov[2:, 2:]
    var = np.diagonal(c)[1:] + np.diagonal(c)[:-1] + 2 * np.diagonal(c, 1)
    return bool((np.abs(a[1:] + a[:-1]) <= TELEGRAPH_SIGMA * np.sqrt(var)).all())


def telegraph_flips(pixel, read, amplitude, z, ramps, times, usable=None):
    """`telegraph_pixels` of a search's jumps, judged on their steps.

    A flag beside a step (amplitude 0: it leaves out a group of frames the step may have
    fallen in) is left out of the judgement and goes with its pixel.  A pair found
    together (a step into a group of frames and out of it: reads with no usable read
    between them, one ``|z|``) is one step, their sum, at its first read, where its two
    steps share a sign or are the ramp's only steps: judged apart, a cosmic ray's pair
    of opposite signs looked like a flip and its return, while a pixel's stay of one
    group in its other level, twice, is two pairs of opposite signs that stay apart.

    Parameters
    ----------
    pixel, read : array_like of int
        The pixel of each jump (a column of ``ramps``) and its read.
    amplitude, z : array_like of float
        The search's step (data unit; 0 for a flag beside a step) and its ``z``.
    ramps, times, usable
        As `telegraph_pixels`.

    Returns
    -------
    flips : `numpy.ndarray` of bool
        Per jump: a flip of a telegraph pixel, or a flag beside one (not a jump).
    left_out : tuple of two `numpy.ndarray` of int
        As `telegraph_pixels`.

    Examples
    --------
    Pixel 0 drops by 40 at read 15 and comes back at 25, twice; its steps each carry a
    flag beside them (amplitude 0).  Pixel 1 has a cosmic ray found as a pair of steps
    of opposite signs at reads 30 and 31, its only steps: one step up, not a flip.

    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.jumps.telegraph import telegraph_flips
    >>> t = np.arange(56) * 3.0
    >>> y = 100 + np.random.default_rng(0).normal(0, 5, (56, 2))
    >>> y[15:25, 0] -= 40; y[35:45, 0] -= 40; y[30:, 1] += 300; y[30, 1] += 20
    >>> flips, _ = telegraph_flips([0, 0, 0, 0, 0, 1, 1], [15, 25, 35, 45, 16, 30, 31],
    ...                            [-40, 40, -40, 40, 0, 320, -20],
    ...                            [-8, 8, -8, 8, -8, 30, -30], y, t)
    >>> flips.tolist()
    [True, True, True, True, True, False, False]
    """
    pix = np.asarray(pixel, np.int64)
    frames = np.asarray(read, np.int64)
    amp = np.asarray(amplitude, np.float64)
    z = np.asarray(z, np.float64)
    idx = np.flatnonzero(amp != 0)
    idx = idx[np.lexsort((frames[idx], pix[idx]))]
    p, f, a, sign = pix[idx], frames[idx], np.abs(z[idx]), np.sign(amp[idx])
    same = np.r_[False, p[1:] == p[:-1]]
    second = same & np.r_[False, a[1:] == a[:-1]] & np.r_[False, f[1:] > f[:-1]]
    for j in np.flatnonzero(second & np.r_[False, f[1:] > f[:-1] + 1]):
        # (a read between them: a pair only if that read is not usable for the pixel)
        second[j] = usable is not None and not usable[f[j - 1] + 1:f[j], p[j]].any()
    runs = np.diff(np.r_[np.flatnonzero(~same), p.size])  # each pixel's steps
    second &= np.r_[False, sign[1:] == sign[:-1]] | (np.repeat(runs, runs) == 2)
    second[1:] &= ~second[:-1]  # (a pair is two reads)
    step = amp[idx].copy()
    step[np.flatnonzero(second) - 1] += step[second]
    one = ~second
    judged, left_out = telegraph_pixels(p[one], f[one], step[one], ramps, times, usable)
    flips_idx = np.zeros(idx.size, bool)
    flips_idx[one] = judged
    flips_idx[second] = flips_idx[np.flatnonzero(second) - 1]
    flips = np.zeros(amp.size, bool)
    flips[idx] = flips_idx
    if flips.any():
        flips |= (amp == 0) & np.isin(pix, pix[flips])
    return flips, left_out
