"""Random telegraph noise of reference pixels, switching in continuous time.

A telegraph pixel has two states, 0 and ``amplitude`` electrons above it, and
switches between them at ``rate`` (Hz) per state: between two reads ``dt``
apart its state differs with probability ``(1 - exp(-2 rate dt)) / 2``.  A
reference row is read several times per frame (``r`` distributed reference
reads cycle through the reference rows), so its pixels are seen at every one
of those read times; a side reference column is read once per frame with its
row.  `ReferenceTelegraph` draws the state of every telegraph reference pixel
at each of its reads, frame after frame, touching only those pixels.
"""

import numpy as np

__all__ = ["ReferenceTelegraph", "gamma_values", "population_values", "switch_probability"]


def switch_probability(rate, dt):
    """Probability that a two-state telegraph is in the other state ``dt`` later.

    Parameters
    ----------
    rate : float
        Switching rate of each state (Hz).
    dt : array_like
        Time separations (s).

    Returns
    -------
    `numpy.ndarray`
        ``(1 - exp(-2 rate dt)) / 2``: 0 at ``dt = 0``, 1/2 for ``dt >> 1 / rate``.

    Examples
    --------
    >>> from spherex_reduce.simulation.telegraph import switch_probability
    >>> switch_probability(0.5, [0.0, 1.0, 100.0]).round(4).tolist()
    [0.0, 0.3161, 0.5]
    """
    return -np.expm1(-2.0 * np.asarray(rate, dtype=np.float64)
                     * np.asarray(dt, dtype=np.float64)) / 2.0


def gamma_values(rng, mean, spread, size):
    """Positive values of a population: gamma-distributed with ``mean`` and standard
    deviation ``spread`` (all ``mean`` when ``spread`` is 0; nothing drawn then).

    Parameters
    ----------
    rng : `numpy.random.Generator`
    mean, spread : float
        Mean (> 0 when ``spread`` > 0) and standard deviation, in any unit.
    size : int or tuple of int

    Returns
    -------
    `numpy.ndarray` (float64), in the unit of ``mean``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.simulation.telegraph import gamma_values
    >>> x = gamma_values(np.random.default_rng(1), 2.0, 0.5, 200_000)
    >>> round(float(x.mean()), 2), round(float(x.std()), 2), bool(x.min() > 0)
    (2.0, 0.5, True)
    """
    if spread <= 0 or mean <= 0:
        return np.full(size, float(mean))
    shape = (mean / spread) ** 2
    return rng.gamma(shape, spread ** 2 / mean, size)


def population_values(rng, telegraph, n):
    """Each of ``n`` telegraph pixels' step (e) and rate (Hz) for a population
    (`~spherex_reduce.simulation.Telegraph`): its ``amplitude`` and ``rate``,
    gamma-distributed with its spreads where they are above 0 (scalars, nothing
    drawn, where they are 0)."""
    amp, rate = float(telegraph.amplitude), float(telegraph.rate)
    if telegraph.amplitude_spread > 0:
        amp = gamma_values(rng, amp, telegraph.amplitude_spread, n)
    if telegraph.rate_spread > 0:
        rate = gamma_values(rng, rate, telegraph.rate_spread, n)
    return amp, rate


class ReferenceTelegraph:
    """Telegraph noise of a random fraction of a schedule's reference pixels.

    Reference pixels are those of the reference rows and of the side reference
    columns (`~spherex_reduce.DetectorGeometry.reference_column_mask`).  Call
    `frame` for frames ``0, 1, 2 ...`` in order: the states continue from one
    frame to the next.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    fraction : float
        Fraction of reference pixels with telegraph noise.
    amplitude : float
        Step between the two states (e).
    rate : float
        Switching rate of each state (Hz).
    rng : `numpy.random.Generator`
        Chooses the pixels' first states and every switch (and the pixels
        themselves without ``population``).
    population : `numpy.random.Generator`, optional
        Chooses the pixels and their amplitudes and rates (a detector's
        population, fixed whatever ``rng``); default ``rng``.
    amplitude_spread, rate_spread : float
        Standard deviations of the pixels' amplitudes (e) and rates (Hz)
        (`gamma_values`; 0: all the same).

    Attributes
    ----------
    rows, columns : `numpy.ndarray`
        Physical row and column of every telegraph reference pixel.
    index : `numpy.ndarray`
        Flat index (``read * ncols + column``, readout order) of every read of
        a telegraph pixel within a frame (its slots), grouped by pixel and in
        time order within each pixel.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.simulation.telegraph import ReferenceTelegraph
    >>> s = ReadoutSchedule(DetectorGeometry(32, 32, 2, ref_border=2), skip=4, ref_reads=8,
    ...                     phantom_reads=2, nframes=3)
    >>> rtn = ReferenceTelegraph(s, 1.0, 10.0, 0.5, np.random.default_rng(1))
    >>> rtn.rows.size == 4 * 32 + 28 * 4     # every reference pixel
    True
    >>> index, values = rtn.frame(0)
    >>> sorted(set(values.tolist())) == [0.0, 10.0]
    True
    """

    def __init__(self, schedule, fraction, amplitude, rate, rng, *, population=None,
                 amplitude_spread=0.0, rate_spread=0.0):
        s = schedule
        g = s.geometry
        ref = np.zeros((g.nrows, g.ncols), bool)
        ref[g.reference_rows] = True
        ref |= g.reference_column_mask()[None, :]
        pop = rng if population is None else population
        chosen = (pop.random(ref.shape) < fraction) & ref
        self.rows, self.columns = np.nonzero(chosen)  # sorted by row, then column
        amp = gamma_values(pop, float(amplitude), amplitude_spread, self.rows.size)
        rates = gamma_values(pop, float(rate), rate_spread, self.rows.size)
        #: each chosen pixel's step (e) and rate (Hz)
        self.amplitudes, self.rates = amp, rates
        self.amplitude = float(amplitude)  # their mean
        self._rng = rng
        # every read of every chosen pixel: reads of its row, one slot each
        per_row = np.bincount(self.rows, minlength=g.nrows)
        first = np.concatenate([[0], np.cumsum(per_row)[:-1]])
        counts = per_row[s.rows]  # chosen pixels in the row of each read
        read = np.repeat(np.arange(s.n_reads), counts)
        within = np.arange(read.size) - np.repeat(np.cumsum(counts) - counts, counts)
        pixel = first[s.rows[read]] + within
        col = self.columns[pixel]
        tau = s.pixel_samples()[read, col] / g.pixel_rate  # s within the frame
        order = np.lexsort((tau, pixel))
        pixel, read, col, tau = pixel[order], read[order], col[order], tau[order]
        self.index = read * g.ncols + col
        # the gap before each slot: from the pixel's previous read (the first slot's from
        # the pixel's last read of the frame before)
        starts = np.flatnonzero(np.diff(pixel, prepend=-1) != 0)
        ends = np.append(starts[1:], pixel.size)[:starts.size] - 1
        tframe = s.frame_samples / g.pixel_rate
        dt = np.diff(tau, prepend=0.0)
        dt[starts] = tau[starts] + tframe - tau[ends]
        self._p = switch_probability(rates[pixel], dt)
        self._amp = amp[pixel]
        self._starts, self._ends = starts, ends
        self._state = rng.random(starts.size) < 0.5  # the stationary distribution
        self._next = 0

    def frame(self, k):
        """States at the reads of frame ``k`` (the next frame): ``(index, values)``.

        ``values`` (e, float64) are to be added at the flat positions ``index``
        of the frame ``(n_reads, ncols)``.
        """
        if k != self._next:
            raise ValueError(f"frames must come in order: expected frame {self._next}, got {k}")
        self._next += 1
        flips = (self._rng.random(self._p.size) < self._p).astype(np.int64)
        if k == 0:
            flips[self._starts] = 0  # the first read sees the initial state
        count = np.cumsum(flips)
        before = count[self._starts] - flips[self._starts]  # flips before each pixel's slots
        npix = np.diff(np.r_[self._starts, self._p.size])
        state = (np.repeat(self._state, npix) ^ ((count - np.repeat(before, npix)) % 2 == 1))
        self._state = state[self._ends]
        return self.index, self._amp * state
