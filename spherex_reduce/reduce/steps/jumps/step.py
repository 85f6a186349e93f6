"""``detect_jumps``: flag the read at which a pixel's charge stepped (cosmic rays).

The step's kernel (`JumpKernel`) searches each pixel's ramp for steps
(`~spherex_reduce.reduce.steps.jumps.search.StepSearch`: a matched filter for a
step at every read, against the ramp's read and shot noise) and sets
`~spherex_reduce.core.dq.JUMP` on the first read after each step, band of rows
by band of rows, before ``fit_ramp``.  Flagging the neighbours of a jump, a
radius around a very large one, or the halo of a large event
(`~spherex_reduce.reduce.steps.jumps.showers`), needs the rows above and below,
which may lie in another band: with ``neighbours``, ``radius`` or
``large_events`` the kernel searches the whole exposure first (in memory) and
each band takes its flags from that.

Before the flags are set, the jumps of each set of rows are looked at together
(`~spherex_reduce.reduce.steps.jumps.events`): a read that is off for most
pixels is one read event (``DO_NOT_USE`` on it for every pixel, the search run
again without it), not thousands of jumps; and each pixel's own
(`~spherex_reduce.reduce.steps.jumps.telegraph`): a telegraph pixel's flips are
not jumps.
"""

import threading
import warnings

import numpy as np
from astropy import units as u

from ....core import dq
from ....core.errors import ConfigError, StepSkipped
from ....core.limits import check_size
from ....core.parameters import OPTIONAL_NUMBER, Parameter, validate_parameters
from ....io.sources import MemorySource
from ...hookspecs import hookimpl
from ...options import RunOptions, in_threads
from ...step import Kernel, Record, Step
from ..fit_ramp.segments import usable_reads
from ..pixel_maps import MAP_TYPES, PixelMap, adu_gain
from .events import JumpWarning, event_message, find_read_events
from .prior import set_priors
from .search import SCALE_DOF, SCALE_SAMPLE, Found, StepSearch, cached_search
from .showers import large_event_halos
from .telegraph import telegraph_flips

__all__ = ["DetectJumpsStep", "JumpKernel", "detect_jumps"]

#: rows of every frame searched at once when the whole exposure is searched first; the
#: read events are judged on sets of this many pixels (whole rows)
SEARCH_PIXELS = 1 << 17
#: read events looked for in a set of rows (one more in each round of the search)
MAX_EVENTS = 4
#: usable reads a ramp needs to be searched: with ``read_noise`` given, and with the read
#: noise from the ramp (2 degrees of freedom for it beside the line and a step)
LEAST_READS, LEAST_READS_ESTIMATED = 3, 5


def detect_jumps(exposure, *, threshold=4.0, read_noise=None, gain=1.0, saturation=None,
                 max_jumps=10, neighbours=False, neighbours_above=10.0, radius=0.0,
                 radius_above=1e4, large_events=False, large_event_area=5,
                 large_event_expand=2.0, large_event_reads=1, read_events=True, telegraph=True,
                 positive_only=False, scale_read_noise=True, expected_rate=None):
    """Flag `~spherex_reduce.core.dq.JUMP` on the read at which each pixel's charge stepped.

    Every pixel's usable reads are fitted with a line plus a step at each read
    in turn; the step's least-squares amplitude over its standard deviation
    under the ramp's noise (read noise, and the shot noise of the pixel's own
    slope) is ``z``.  When ``max |z|`` over the reads exceeds ``threshold``
    the read after the step is flagged, the step is subtracted and the search
    repeated (up to ``max_jumps`` times).  With read noise alone (dark ramps)
    this is the likelihood-ratio test for a step at an unknown read.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps ``(frames, rows or reads, columns)`` in readout or physical
        order, at least 3 frames (5 without ``read_noise``).  Not modified.
    threshold : float
        ``max |z|`` (sigma) above which a ramp has a jump.  A jump-free dark
        ramp of 74 reads of 1.5 s (10 e read noise, 0.01 e/s, gain 1) is
        flagged at 4 sigma with probability 2.2e-3 (``read_noise`` given) or
        5.6e-3 (estimated); the reduction guide tabulates other thresholds and
        numbers of reads.
    read_noise : float, `numpy.ndarray` or str, optional
        Read noise of one read (data unit): one number, a map ``(nrows,
        ncols)`` of the stored image (as the files hold the pixels), or a FITS
        image (its ``BUNIT`` converted as by `fit_ramp`).  None: each pixel's
        from its own residuals about a line with one step.  Given, it is
        scaled to the ramps' own scatter (``scale_read_noise``).
    gain : float, `numpy.ndarray` or str
        Electrons per data unit (the shot noise of the pixel's slope); a map
        like ``read_noise``.
    saturation : float, optional
        Reads above this level (data unit) are saturated: they and every
        later read of the ramp are not searched (as reads flagged
        `~spherex_reduce.core.dq.SATURATED`).
    max_jumps : int
        Jumps searched for in each ramp.
    neighbours : bool
        Also flag the 4 neighbours (on the stored image: across the seams of
        quadrants, whatever the channel layout) of every jump of at least
        ``neighbours_above`` sigma, at the read of the jump and at the one
        before or after it, by when the neighbour is read in the frame.
    neighbours_above : float
        Smallest ``|z|`` (sigma) of a jump whose neighbours are flagged.
    radius : float
        Flag every pixel within this distance (pixels, on the stored image) of
        a jump of at least ``radius_above``, like the neighbours (a disc of one
        size whatever the event; ``large_events`` sizes it by the event's
        core); 0: none.  A radius beyond the image flags all of it.
    radius_above : float
        Smallest amplitude (data unit) of a jump flagged with ``radius``.
    large_events : bool
        Flag the halos of large events (snowballs, showers:
        `~spherex_reduce.reduce.steps.jumps.showers.large_event_halos`): at
        least ``large_event_area`` jumps touching at one read (on the stored
        image, 8 neighbours) are a core; every pixel within
        ``large_event_expand`` times its radius is flagged at that read and the
        ``large_event_reads`` after it, as JWST's ``expand_large_events``.
    large_event_area : int
        Fewest touching jumps at one read that are a large event's core.
    large_event_expand : float
        The halo's radius over the core's.
    large_event_reads : int
        Reads after the core's read also flagged in its halo.
    read_events : bool
        Find the reads that are off for most pixels (a first read below the
        line of the others, a frame glitch, a step of the whole array) from
        how the jumps fall over the reads and over the array
        (`~spherex_reduce.reduce.steps.jumps.events.find_read_events`): such a
        read is one event, flagged `~spherex_reduce.core.dq.DO_NOT_USE` for
        every pixel (left out of every fit; a step: `~spherex_reduce.core.dq.JUMP`
        for every pixel), not counted as jumps, and told in one
        `~spherex_reduce.reduce.steps.jumps.events.JumpWarning` naming the read
        and the fix.  On 3 reads, where no read can be named, a ``'bend'``:
        nothing flagged, the ramps searched again about the set's median bend.
    telegraph : bool
        Take a pixel whose steps (two or more) alternate in sign, each pair
        coming back to the same level, as a telegraph pixel
        (`~spherex_reduce.reduce.steps.jumps.telegraph.telegraph_pixels`): its
        flips are not jumps (not flagged, not counted), and the reads it
        spent in its rarer level are flagged `~spherex_reduce.core.dq.DO_NOT_USE`
        (left out of its fit: its other reads are one line).
    positive_only : bool
        Flag only the steps up (charge added, as a cosmic ray adds); a step
        down is not flagged (the fit goes through it).  The threshold stays
        the two-sided one: the false alarms halve.
    scale_read_noise : bool
        With ``read_noise`` given: scale it, on each set of rows of 2**17
        pixels, by how much the set's ramps scatter (their first differences
        less their line's slope, against the read noise given, by medians
        over the ramps and the intervals;
        `~spherex_reduce.reduce.steps.jumps.search.StepSearch.scatter`), so
        that the false alarms stay as stated when the read noise given is off
        (at 4 sigma a read noise 20 % low would flag 18 times as many
        jump-free ramps).  Sets too small to measure it (fewer than 2**15
        ramps x (reads - 2)), or too bright (the shot noise above 10 % of the
        residuals), keep the read noise given.
    expected_rate : array, str or `~astropy.units.Quantity`, optional
        The rate each pixel is expected to hold (data unit / s; a map as
        ``read_noise``, NaN where it has no value), e.g. the master dark of the
        same detector (``combine``) when the exposures are darks.  Each step is
        then tested against a line whose slope has that prior instead of a free
        slope: a step at mid-ramp is no longer nearly degenerate with a change
        of slope (its sigma about halves), so 10-30 e steps at mid-ramp are
        found rather than left to bias the slope.  On each set of rows the
        ramps' slopes less their expected rates give the prior's offset (their
        median: a dark current that drifted) and spread (their scatter below
        the median, less the line's noise; at least a tenth of a slope's
        sigma).  A ramp whose two-segment slope is off its expected one by more
        than `~spherex_reduce.reduce.steps.jumps.search.OWN_SIGMA` of its sigmas
        (a pixel warmer than in the map, a source), or bright enough at its
        expected rate for shot-noise weights (a hot pixel's rate is seldom known
        to the few per cent its prior would need), keeps the free slope; so do
        a pixel the map holds NaN for and the ramps of a set whose rates spread
        by more than `~spherex_reduce.reduce.steps.jumps.prior.SPREAD_MAX` line
        sigmas about the map (a sky under a dark's map) or where no prior can
        be weighed (fewer than 100 with the same usable reads; rates whose
        squares overflow).  The header's
        ``NEXPRATE`` and ``NEXPFREE`` count both kinds.  The slopes ``fit_ramp``
        fits stay each pixel's own.  Needs ``read_noise``.  The prior of a set
        needs all of its rows: as with ``neighbours``, the whole exposure is
        searched first (in memory).  One number is refused: the offset would
        make it each set's median slope, the bulk's, and warm pixels 3-8 line
        sigmas warm would be flagged as steps 25-98 % of the time (an array of
        one value is taken, as asked).

    Returns
    -------
    `~spherex_reduce.Exposure`
        The input's pixels with `~spherex_reduce.core.dq.JUMP` or-ed into the
        DQ of the reads flagged; the header's ``NJUMPS`` counts the jumps
        found (reads flagged by the search) and ``NJUMPNB`` the reads flagged
        around them (each read once); ``NRDEVENT`` the read events and
        ``RDEVT1``, ``RDEVT2`` ... each one's read, kind, pixels that stepped
        there and offset (data unit); ``NTELEGR`` the telegraph pixels;
        ``RNSCALE`` the factor the read noise given was scaled by (mean over the
        sets of rows, with ``RNSCLMIN`` and ``RNSCLMAX``), when measured.

    Notes
    -----
    Reads that are masked (`~spherex_reduce.core.dq.read_usable` false), not
    finite, or saturated (flag or ``saturation``; every read after the first
    saturated one too) are not used: the search runs on the usable reads, and
    a step between two of them flags the later one.  A jump before the first
    usable read is not seen (it is part of the pedestal).

    Bands of rows are searched on several threads; each pixel's jumps
    depend on its own reads only, and the read events on sets of whole rows
    of 2**17 pixels (aligned on the row axis, the same sets whichever bands
    hold them).  With ``neighbours`` or ``radius`` the whole exposure is
    searched before its bands are flagged (it is held in memory); so it is
    with ``large_events``.

    On 3 or 4 reads without ``read_noise`` (or 2 with it) the step is skipped
    with a `~spherex_reduce.reduce.steps.jumps.events.JumpWarning` saying why
    and, for 3-4 reads, to give ``read_noise``.  On 3 reads (with it) a step
    after the first read and one after the second leave the same residual
    (the line fits two of three points): the ramp's bend is tested once, and
    the step is placed where it is positive (a cosmic ray raises the larger
    of the two differences, as two-point detection flags it), so
    ``positive_only`` changes nothing there and a step down is placed at the
    other read; its shot noise is that of the line's rate (without
    ``expected_rate``).  A read off for
    every pixel (the first low, the middle high, the last low) bends every
    ramp alike, and 3 reads cannot name it: it is said once (a ``'bend'``
    read event), no read is left out and the bend's steps are not jumps.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, detect_jumps, dq
    >>> s = ReadoutSchedule(DetectorGeometry(8, 4, 1, ref_border=1), skip=1, ref_reads=0,
    ...                     ref_mode="none", phantom_reads=0, nframes=20, frame_time=1.5)
    >>> rng = np.random.default_rng(0)
    >>> ramps = (1000 + rng.normal(0, 10, (20, 8, 4))).astype("f4")
    >>> ramps[7:, 2, 3] += 150  # a cosmic ray between reads 6 and 7
    >>> out = detect_jumps(Exposure.from_arrays(ramps, s), read_noise=10)
    >>> np.argwhere(out.dq & dq.JUMP).tolist(), out.header["NJUMPS"]
    ([[7, 2, 3]], 1)
    """
    return DetectJumpsStep()(
        exposure, threshold=threshold, read_noise=read_noise, gain=gain, saturation=saturation,
        max_jumps=max_jumps, neighbours=neighbours, neighbours_above=neighbours_above,
        radius=radius, radius_above=radius_above, large_events=large_events,
        large_event_area=large_event_area, large_event_expand=large_event_expand,
        large_event_reads=large_event_reads, read_events=read_events,
        telegraph=telegraph, positive_only=positive_only, scale_read_noise=scale_read_noise,
        expected_rate=expected_rate)


class JumpKernel(Kernel):
    """`detect_jumps` on bands of rows (the kernel of `DetectJumpsStep`).

    Parameters
    ----------
    context : `~spherex_reduce.core.block.Context`
    **params
        As `detect_jumps` (declared by `DetectJumpsStep.parameters`).
    """

    def __init__(self, context, **params):
        params = validate_parameters(params, DetectJumpsStep.parameters, DetectJumpsStep.name)
        if not context.ramp:
            raise StepSkipped("the input is already a 2-D image (slopes)")
        super().__init__(context)
        s = context.schedule
        self.estimate = params["read_noise"] is None
        prior = params["expected_rate"] is not None
        _check_expected_rate(params["expected_rate"])
        if prior and self.estimate:
            raise ConfigError("detect_jumps.expected_rate needs read_noise (the prior's "
                              "weight is the read noise's variance over the rates' spread)")
        self.least = LEAST_READS_ESTIMATED if self.estimate else LEAST_READS
        if s.nframes < self.least:
            raise StepSkipped(_too_few(s.nframes, self.estimate))
        self.params = params
        g = s.geometry
        # maps of the stored image, brought to the readout frame in the data unit
        unit = context.unit
        self.gain = PixelMap.of(params["gain"], "detect_jumps.gain", g, positive=True,
                                unit=None if unit is None else u.electron / unit)
        self.read_noise = (None if self.estimate else
                           PixelMap.of(params["read_noise"], "detect_jumps.read_noise", g,
                                       positive=True, unit=unit,
                                       gain=adu_gain(unit, context.header, g, self.gain)))
        self.expected = (None if not prior else
                         PixelMap.of(params["expected_rate"], "detect_jumps.expected_rate", g,
                                     unit=None if unit is None else unit / u.s,
                                     gain=adu_gain(unit, context.header, g, self.gain),
                                     allow_nan=True))
        # each stored read's time (a group's mean), read-noise variance relative to one
        # frame's (1 / frames averaged) and charge covariance per unit rate
        check_size(StepSearch.nbytes(s.nframes),  # before the first nframes**2 matrix
                   f"detect_jumps: the step search over {s.nframes} reads")
        self.times = s.frame_starts.to_value(u.s)
        self.factors = s.read_noise_factors
        self.walk = s.shot_covariance()
        self._whole = self._search(np.ones(s.nframes, bool))  # every read usable
        # (the prior of a set of rows needs the whole set, whichever bands hold it)
        self.needs_exposure = bool(params["neighbours"] or params["radius"] > 0
                                   or params["large_events"] or prior)
        self._lock = threading.Lock()
        self._found = 0  # reads flagged by the search, over the bands (streamed route)
        # read events are decided on sets of rows aligned on the row axis, the same sets
        # whichever bands hold them (a band from a file is one, in memory two)
        self.event_rows = max(1, SEARCH_PIXELS // g.ncols)
        self._events = {}  # (read, kind) -> [jumps, expected, pixels, offset * pixels]
        self._telegraph = 0  # telegraph pixels, over the bands
        self.rescale = not self.estimate and params["scale_read_noise"]
        self._scales = {}  # set of rows -> (factor the read noise given is scaled by, pixels)
        # expected_rate: ramps searched against it and with the slope free, per band (its
        # last search: a read event searches it again), and this thread's count so far
        self._prior_counts = {}
        self._tally = threading.local()

    # -- the search of one band -------------------------------------------------------
    def _search(self, usable):
        """The `StepSearch` of the reads ``usable`` (bool per frame)."""
        idx = np.flatnonzero(usable)
        return cached_search(self.times[idx], self.factors[idx], self.walk[np.ix_(idx, idx)])

    def _maps(self, block):
        """Read noise (or None) and gain of the band: numbers, or flat arrays of its pixels."""
        out = []
        for m in (self.read_noise, self.gain):
            v = None if m is None else m.rows(block.index, self.context.order,
                                                self.context.schedule)
            out.append(v if v is None or np.ndim(v) == 0 else np.ravel(v))
        return out

    def find(self, block):
        """The jumps of a band: ``(frames, flat pixel indices, amplitudes, z)``, the flags
        of its read events (uint32 ``(frames, rows, 1)``, or None: see `_with_events`) and
        the reads its telegraph pixels are left out at, ``(frames, flat pixel indices)``
        (their flips are not jumps), with ``positive_only`` only the steps up."""
        found, flags = self._with_events(block)
        frames, pix, amp, z = found
        left_out = None
        if self.params["telegraph"] and frames.size:
            nf = block.nframes
            usable = None
            if block.dq is not None or flags is not None:
                usable = np.ones(block.data.shape, bool)
                if block.dq is not None:
                    usable &= dq.read_usable(block.dq)
                if flags is not None:
                    usable &= (flags & np.uint32(dq.DO_NOT_USE)) == 0
                usable = usable.reshape(nf, -1)
            flips, left_out = telegraph_flips(pix, frames, amp, z,
                                              block.data.reshape(nf, -1), self.times, usable)
            if flips.any():
                keep = ~flips
                frames, pix, amp, z = frames[keep], pix[keep], amp[keep], z[keep]
                with self._lock:
                    self._telegraph += np.unique(left_out[1]).size
        if self.params["positive_only"]:
            # (a flag beside a step, of no amplitude, carries the step's sign in its z)
            keep = np.where(amp != 0, amp, z) >= 0
            frames, pix, amp, z = frames[keep], pix[keep], amp[keep], z[keep]
        return (frames, pix, amp, z), flags, left_out

    def _with_events(self, block):
        """The jumps of a band and its read events: ``(frames, flat pixel indices,
        amplitudes, z)`` and the flags of the events (uint32 ``(frames, rows, 1)``, or
        None): ``DO_NOT_USE`` on a read that is off, for every pixel of the rows of the
        set where it was found, ``JUMP`` where the whole set stepped.

        Events are found one per set of rows at a time, the strongest first, and the
        band searched again without the read: the jumps a read that is off leaves at
        the reads next to it are then gone too."""
        found = self._jumps(block)
        if not self.params["read_events"]:
            self._count_prior(block)
            return found, None
        flags, events = None, []
        for _ in range(MAX_EVENTS):
            new = self._read_events(block, found, flags)
            if not new:
                break
            events += new
            bent = [rows for rows, e in events if e.kind == "bend"]
            if bent:  # (3 reads: no read to leave out; search again about the set's bend)
                found = self._jumps(_without_bends(block, bent, self.times))
                continue
            if flags is None:
                flags = np.zeros((block.nframes, block.data.shape[1], 1), np.uint32)
            for rows, e in new:
                flags[e.read, rows] |= np.uint32(dq.DO_NOT_USE if e.dropped else dq.JUMP)
            # search again without the reads that are off and the array's steps
            found = self._jumps(_without_events(block, flags, self.times))
        self._count_prior(block)
        with self._lock:
            for rows, e in events:
                offset = (_read_offset(block, rows, flags, e.read, self.times) if e.dropped
                          else e.offset)
                total = self._events.setdefault((e.read, e.kind), [0, 0.0, 0, 0.0])
                total[0] += e.jumps
                total[1] += e.expected
                total[2] += e.pixels
                total[3] += offset * e.pixels
        if flags is None:
            return found, None
        frames, pix, amp, z = found
        stepped = (flags[frames, pix // block.data.shape[-1], 0] & np.uint32(dq.JUMP)) != 0
        keep = ~stepped  # the array's step is an event, not the pixels' jumps
        return (frames[keep], pix[keep], amp[keep], z[keep]), flags

    def _count_prior(self, block):
        """Keep the band's last search's counts of ramps searched against their expected
        rate and with the slope free (``expected_rate``)."""
        if self.expected is not None:
            with self._lock:
                self._prior_counts[int(np.asarray(block.index)[0])] = tuple(self._tally.counts)

    def _read_events(self, block, found, flags):
        """The strongest new read event of each set of `event_rows` rows of a band, judged
        on its own jumps (`find_read_events`): ``[(rows of the band, ReadEvent)]``; the
        jumps at a read where the set already stepped (``flags``) are not counted."""
        frames, pix, amp, z = found
        nf, ncols = block.nframes, block.data.shape[-1]
        # (a read flagged beside a step to leave out the group it may have fallen in has
        # no amplitude of its own: the step is counted once, at its read)
        keep = amp != 0
        if flags is not None:
            keep &= (flags[frames, pix // ncols, 0] & np.uint32(dq.JUMP)) == 0
        frames, pix, amp, z = frames[keep], pix[keep], amp[keep], z[keep]
        sets = np.asarray(block.index) // self.event_rows
        out = []
        for one in np.unique(sets):
            rows = np.flatnonzero(sets == one)
            at = np.isin(pix // ncols, rows)
            local = np.searchsorted(rows, pix[at] // ncols)
            events = find_read_events(frames[at], local, pix[at] % ncols, amp[at], nreads=nf,
                                      nrows=rows.size, ncols=ncols, z=z[at],
                                      threshold=self.params["threshold"])
            if events:
                out.append((rows, max(events, key=lambda e: e.jumps)))
        return out

    def _jumps(self, block):
        """The jumps of a band found by the search: ``(frames, flat pixel indices,
        amplitudes, z)``."""
        p = self.params
        nf = block.nframes
        y = block.data.reshape(nf, -1)
        self._tally.counts = [0, 0]  # this search's ramps: against the expected rate, free
        bad = np.zeros(y.shape[1], bool)  # pixels with a read flagged or above saturation
        if block.dq is not None:
            bad |= (~dq.read_usable(block.dq.reshape(nf, -1))).any(axis=0)
        if p["saturation"] is not None:
            bad |= (y > p["saturation"]).any(axis=0)
        good = np.flatnonzero(~bad) if bad.any() else slice(None)
        pixels = np.arange(y.shape[1])[good]
        parts = []
        maps = self._maps(block)
        if self.rescale:
            maps = (self._scaled(block, y, bad, *maps), maps[1])
        found = self._run(self._whole, y[:, good], maps, pixels, block)
        parts.append((found.read, pixels[found.pixel], found.amplitude, found.z))
        rest = np.union1d(np.flatnonzero(bad), pixels[found.unsearched])
        if rest.size:
            parts.extend(self._masked(y, block, maps, rest))
        frames, pix, amp, z = (np.concatenate(a) for a in zip(*parts, strict=True))
        return frames, pix, amp, z

    def _with_prior(self, search, y, sigma, gain, pixels, block):
        """The search of ramps ``y`` (the band's flat ``pixels``, their reads usable for
        ``search``), each set of `event_rows` rows with its prior (`set_priors`), searched
        with the slope free where a set has none: a `~spherex_reduce.reduce.steps.jumps.
        search.Found` of their indices among ``y``'s columns."""
        ncols = block.data.shape[-1]
        n = y.shape[1]
        sigma, gain = (np.broadcast_to(np.asarray(v, np.float64), (n,)) for v in (sigma, gain))
        expected = self.expected.rows(block.index, self.context.order, self.context.schedule)
        expected = np.broadcast_to(np.ravel(expected), (block.data[0].size,))[pixels]
        sets = (np.asarray(block.index) // self.event_rows)[pixels // ncols]
        p = self.params
        parts, unsearched = [], []
        for one in np.unique(sets):
            at = np.flatnonzero(sets == one)
            for cols, prior in set_priors(search, y[:, _run_of(at)], sigma[at], gain[at],
                                          expected[at]):
                sel = at[cols]
                take = _run_of(sel)
                found = search.find(y[:, take], threshold=p["threshold"], sigma=sigma[take],
                                    gain=gain[take], max_jumps=p["max_jumps"], prior=prior)
                searched = sel.size - found.unsearched.size  # (those searched on)
                free = searched if prior is None else found.free
                self._tally.counts[0] += searched - free
                self._tally.counts[1] += free
                parts.append((sel[found.pixel], found.read, found.amplitude, found.z))
                unsearched.append(sel[found.unsearched])
        out = Found.of(parts)
        out.unsearched = np.concatenate(unsearched) if unsearched else np.zeros(0, np.int64)
        return out

    def _scaled(self, block, y, bad, read_noise, gain):
        """The read noise given for the pixels of a band (flat), scaled on each set of
        `event_rows` rows by the set's ramps' own scatter (`StepSearch.scatter`): measured
        on its pixels with every read usable or, when too few (a read left out for every
        pixel: a read event), on those with the set's most common usable reads."""
        nf, ncols = block.nframes, block.data.shape[-1]
        out = np.array(np.broadcast_to(read_noise, (y.shape[1],)), np.float64)
        gain = np.broadcast_to(gain, (y.shape[1],))
        sets = np.asarray(block.index) // self.event_rows
        for one in np.unique(sets):
            rows = np.flatnonzero(sets == one)
            pix = set_pixels = (rows[:, None] * ncols + np.arange(ncols)).ravel()
            whole = pix[~bad[pix]]
            search, members = self._whole, whole
            if whole.size * (nf - 2) < SCALE_DOF and pix.size > whole.size:
                # every k-th ramp, as `StepSearch.scatter` takes them: no copy of the set
                pix = pix[::max(1, -(-pix.size * (nf - 2) // SCALE_SAMPLE))]
                flags = None if block.dq is None else block.dq.reshape(nf, -1)[:, pix]
                usable, _ = usable_reads(y[:, pix], flags, self.params["saturation"])
                _, inverse, counts = np.unique(np.packbits(usable, axis=0).T, axis=0,
                                               return_inverse=True, return_counts=True)
                common = inverse.ravel() == np.argmax(counts)
                members, mask = pix[common], usable[:, np.argmax(common)]
                if mask.sum() < self.least:
                    continue
                search = self._search(mask)
                sub = y[:, members][mask]
            else:
                every = max(1, -(-members.size * (nf - 2) // SCALE_SAMPLE))
                members = members[::every]
                # every pixel of the set usable and its rows together in the band (not so
                # in readout order): a view of every k-th ramp, no gather
                together = whole.size == pix.size and pix[-1] - pix[0] + 1 == pix.size
                sub = y[:, pix[0]:pix[-1] + 1:every] if together else y[:, members]
            ratio = search.scatter(sub, out[members], gain[members])
            if ratio is None or not ratio > 0:
                continue
            factor = float(np.sqrt(ratio))
            out[set_pixels] *= factor
            with self._lock:
                self._scales[int(one)] = (factor, set_pixels.size)
        return out

    def _run(self, search, y, maps, pixels, block):
        """The search of ramps ``y`` (the band's flat ``pixels``, their reads usable for
        ``search``), with ``expected_rate``'s prior when given."""
        sigma, gain = (v if v is None or np.ndim(v) == 0 else v[pixels] for v in maps)
        if self.expected is not None:
            return self._with_prior(search, y, sigma, gain, pixels, block)
        return search.find(y, threshold=self.params["threshold"], sigma=sigma, gain=gain,
                           max_jumps=self.params["max_jumps"])

    def _masked(self, y, block, maps, pixels):
        """The jumps of ``pixels`` with unusable reads, searched on their usable reads (those
        `fit_ramp` would fit)."""
        sub = y[:, pixels]
        flags = None if block.dq is None else block.dq.reshape(sub.shape[0], -1)[:, pixels]
        usable, _ = usable_reads(sub, flags, self.params["saturation"])
        keys = np.packbits(usable, axis=0).T.copy()
        _, first, inverse = np.unique(keys.view(f"V{keys.shape[1]}").ravel(),
                                      return_index=True, return_inverse=True)
        out = []
        for g, col in enumerate(first):
            mask = usable[:, col]
            idx = np.flatnonzero(mask)
            if idx.size < self.least:
                continue
            members = np.flatnonzero(inverse == g)
            found = self._run(self._search(mask), sub[idx][:, members], maps,
                              pixels[members], block)
            out.append((idx[found.read], pixels[members][found.pixel], found.amplitude,
                        found.z))
        return out

    # -- the kernel ----------------------------------------------------------------------
    def prepare(self, side, exposure=None):
        """With ``neighbours``, ``radius`` or ``large_events``: every flag of the exposure
        (searched whole)."""
        if not self.needs_exposure:
            return None
        source = MemorySource(exposure)
        rows = max(1, SEARCH_PIXELS // self.context.geometry.ncols)
        parts, events, quiet = [], [], []
        starts = range(0, source.nrows, rows)
        nthreads = min(len(starts), RunOptions(threads=self.context.threads).thread_count())

        def search(lo):  # each set of rows on its own (its events, its prior): any thread
            block = source.read(lo, min(source.nrows, lo + rows))
            return block, self.find(block)

        for block, ((frames, pix, amp, z), flags, left_out) in in_threads(
                starts, search, nthreads, name="spherex-reduce-jumps"):
            ncols = block.data.shape[-1]
            parts.append((frames, block.index[pix // ncols], pix % ncols, amp, z))
            if flags is not None:
                f, r = np.nonzero(flags[..., 0])
                events.append((f, block.index[r], flags[f, r, 0]))
            if left_out is not None and left_out[0].size:
                f, p = left_out
                quiet.append((f, block.index[p // ncols], p % ncols))
        frames, index, cols, amp, z = (np.concatenate(a) for a in zip(*parts, strict=True))
        saturated = _saturating(exposure, self.params) if self.params["large_events"] else None
        around = _around(self.context, self.params, frames, index, cols, amp, z, saturated)
        flags = [np.concatenate(a) for a in zip((frames, index, cols), around, strict=True)]
        events = [np.concatenate(a) for a in zip(*events, strict=True)] if events else None
        quiet = [np.concatenate(a) for a in zip(*quiet, strict=True)] if quiet else None
        return _Flags(*flags, found=frames.size, around=around[0].size, events=events,
                      left_out=quiet)

    def apply(self, coefficients, block):
        if coefficients is None:
            (frames, pix, _, _), events, left_out = self.find(block)
            ncols = block.data.shape[-1]
            rows, cols = pix // ncols, pix % ncols
            if left_out is not None:
                left_out = (left_out[0], left_out[1] // ncols, left_out[1] % ncols)
            with self._lock:
                self._found += frames.size
        else:
            frames, rows, cols = coefficients.within(block.index)
            events = coefficients.events_within(block.index, block.nframes)
            left_out = coefficients.left_out_within(block.index)
        if events is not None:
            block = block.with_flags(events)
        if left_out is not None and left_out[0].size:
            block = block.with_flags(np.uint32(dq.DO_NOT_USE), at=left_out)
        if not frames.size:
            return block
        return block.with_flags(np.uint32(dq.JUMP), at=(frames, rows, cols))

    def apply_side(self, coefficients, side):
        """The reference reads are left as they are (they collect no charge)."""
        return side

    def record(self, coefficients):
        found = self._found if coefficients is None else coefficients.found
        cards = [("NJUMPS", found, "jumps flagged (reads where the charge stepped)")]
        if coefficients is not None:
            cards.append(("NJUMPNB", coefficients.around, "reads flagged around jumps"))
        if self.params["telegraph"]:
            cards.append(("NTELEGR", self._telegraph, "telegraph pixels (flips left out)"))
        if self.expected is not None:
            on, free = (int(v) for v in np.sum(list(self._prior_counts.values()) or [[0, 0]],
                                               axis=0))
            cards += [("NEXPRATE", on, "ramps searched against their expected_rate"),
                      ("NEXPFREE", free, "ramps searched with the slope free instead")]
        if self._scales:
            factor, pixels = np.array(list(self._scales.values())).T
            cards += [("RNSCALE", round(float(factor @ pixels / pixels.sum()), 4),
                       "read noise given x this (ramps' own scatter)"),
                      ("RNSCLMIN", round(float(factor.min()), 4), "smallest over row sets"),
                      ("RNSCLMAX", round(float(factor.max()), 4), "largest over row sets")]
        events = sorted(self._events.items())
        if events:
            cards.append(("NRDEVENT", len(events), "reads off for most pixels (read events)"))
        header = self.context.header
        dropped = 0 if header is None else int(header.get("NDROPRD", 0) or 0)
        for i, ((read, kind), (jumps, expected, pixels, offset)) in enumerate(events[:99]):
            offset /= pixels
            cards.append((f"RDEVT{i + 1}", f"read {read}: {kind}, {jumps}/{pixels} px, "
                          f"{offset:+.4g}", "read event"))
            warnings.warn(event_message(read, kind, jumps, expected, pixels, offset, dropped),
                          JumpWarning, stacklevel=2)
        return Record(cards=cards)


def _saturating(exposure, params):
    """``(frames, index, cols)`` of the reads at which pixels saturated (flagged
    `~spherex_reduce.core.dq.SATURATED`, or above ``saturation``) after a usable read."""
    level = params["saturation"]
    data = exposure.data.data
    before = None
    out = []
    for f in range(data.shape[0]):
        now = np.zeros(data.shape[1:], bool)
        if exposure.dq is not None:
            now |= (exposure.dq[f] & np.uint32(dq.SATURATED)) != 0
        if level is not None:
            now |= data[f] > level
        if before is not None:
            i, c = np.nonzero(now & ~before)
            out.append((np.full(i.size, f, np.int64), i, c))
            now |= before
        before = now
    if not out:
        return (np.zeros(0, np.int64),) * 3
    return tuple(np.concatenate(a) for a in zip(*out, strict=True))


def _without_bends(block, bent, times):
    """A copy of ``block`` (3 reads) whose ramps on each set of rows in ``bent`` have the
    set's median bend taken out: ``v . y`` with ``v`` orthogonal to the line (a read off
    for every pixel adds the same to every ramp's), so the line's slope and intercept stay
    and the search measures each ramp's bend from the set's; a cosmic ray at the read where
    the array bent is found again."""
    v = np.array([times[2] - times[1], times[0] - times[2], times[1] - times[0]], np.float64)
    data = np.array(block.data, np.float64)
    for rows in bent:
        y = data[:, rows]
        with warnings.catch_warnings():  # (a set of NaN ramps: nothing to take out)
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(np.einsum("f,frc->rc", v, y))
        if np.isfinite(median):
            data[:, rows] = y - (median / (v @ v)) * v[:, None, None]
    return block.replace(data=data, owned=block.owned | {"data"})


def _without_events(block, flags, times):
    """A copy of ``block`` as the search sees it after its read events (``flags``, uint32
    ``(frames, rows, 1)``): ``DO_NOT_USE`` or-ed into its DQ on the reads that are off,
    and each pixel's own least-squares step (a line plus the steps, on its other reads)
    taken out of its reads from where the array stepped (``JUMP``), so that the search
    finds neither again, nor their echoes at the reads next to them."""
    old = np.zeros(block.data.shape, np.uint32) if block.dq is None else block.dq
    out = block.replace(dq=old | (flags & np.uint32(dq.DO_NOT_USE)), owned=frozenset({"dq"}))
    steps = flags[..., 0] & np.uint32(dq.JUMP)
    rows = np.flatnonzero(steps.any(axis=0))
    if not rows.size:
        return out
    data = np.array(block.data, np.float32)
    for pattern in np.unique(flags[:, rows, 0], axis=1).T:  # rows with the same events
        at = rows[(flags[:, rows, 0] == pattern[:, None]).all(axis=0)]
        use = (pattern & np.uint32(dq.DO_NOT_USE)) == 0
        cols = [np.ones(times.size), times] + [
            (np.arange(times.size) >= k).astype(np.float64)
            for k in np.flatnonzero(pattern & np.uint32(dq.JUMP))]
        x = np.column_stack(cols)
        y = data[:, at].reshape(times.size, -1).astype(np.float64)
        coef = np.linalg.lstsq(x[use], y[use], rcond=None)[0]
        y -= x[:, 2:] @ coef[2:]
        data[:, at] = y.reshape(times.size, at.size, -1)
    return out.replace(data=data, owned=frozenset({"data", "dq"}))


def _read_offset(block, rows, flags, read, times):
    """The median over the pixels of ``rows`` of how far ``read`` sits from the line of
    their other usable reads (least squares; data unit): the offset of a read that is
    off, measured on every pixel, not only on those whose step was found."""
    y = block.data[:, rows].reshape(block.nframes, -1).astype(np.float64)
    others = (flags[:, rows[0], 0] & np.uint32(dq.DO_NOT_USE)) == 0
    x = np.column_stack([np.ones(others.sum()), times[others]])
    coef = np.linalg.lstsq(x, y[others], rcond=None)[0]
    return float(np.nanmedian(y[read] - coef[0] - coef[1] * times[read]))


def _too_few(nframes, estimate):
    """Why ``nframes`` reads are not searched, said once as a warning too (a skipped step
    is otherwise only a status keyword): with the read noise estimated, how to search."""
    if estimate and LEAST_READS <= nframes < LEAST_READS_ESTIMATED:
        text = (f"{nframes} reads: too few to estimate each ramp's read noise "
                f"({LEAST_READS_ESTIMATED} needed), so "
                "no jumps are searched; give detect_jumps.read_noise (a number in the data "
                f"unit, or a read-noise map as a FITS image) to search {nframes} reads")
    else:
        text = (f"{nframes} reads: too few to search for jumps ({LEAST_READS} needed with "
                f"detect_jumps.read_noise, {LEAST_READS_ESTIMATED} without)")
    warnings.warn(f"detect_jumps: {text}; the step is skipped", JumpWarning, stacklevel=3)
    return text


def _check_expected_rate(given):
    """Refuse an ``expected_rate`` that is not a map (a file or a 2-D array): one number
    would be each set's median slope, the bulk's."""
    if given is not None and not isinstance(given, str) and np.ndim(given) != 2:
        raise ConfigError(
            "detect_jumps.expected_rate: a map of each pixel's rate (e.g. the master "
            "dark's FITS file, or a 2-D array of the stored image), not "
            + ("one number: one rate for all is the bulk's slope, and warm pixels "
               "would be flagged as steps" if np.ndim(given) == 0 else
               f"an array of shape {np.shape(given)}"))


def _run_of(index):
    """``index`` (increasing) as a slice when it is one run of consecutive columns (a
    view, no copy), else itself."""
    return (slice(int(index[0]), int(index[-1]) + 1)
            if index.size and index[-1] - index[0] + 1 == index.size else index)


class _Flags:
    """Every JUMP flag of an exposure: ``frame``, ``index`` (row axis), ``col``; and its
    read events' flags, ``events``: ``(frame, index, flag)`` for every pixel of the row,
    or None."""

    def __init__(self, frame, index, col, found, around, events=None, left_out=None):
        self.frame, self.index, self.col = frame, index, col
        self.found, self.around, self.events = found, around, events
        self.left_out = left_out  # (frame, index, col) of the telegraph pixels' reads

    def left_out_within(self, index):
        """``(frames, rows, cols)`` of the telegraph pixels' reads left out on the rows
        ``index`` of a band, or None."""
        if self.left_out is None:
            return None
        frame, rows, (col,) = _on_rows(index, self.left_out[1], self.left_out[0],
                                       self.left_out[2])
        return frame, rows, col

    def within(self, index):
        """``(frames, rows, cols)`` of the flags on the rows ``index`` of a band."""
        frame, rows, (col,) = _on_rows(index, self.index, self.frame, self.col)
        return frame, rows, col

    def events_within(self, index, nframes):
        """The read events' flags of the rows ``index`` of a band, uint32 ``(nframes,
        rows, 1)``, or None."""
        if self.events is None:
            return None
        frame, rows, (flag,) = _on_rows(index, self.events[1], self.events[0],
                                        self.events[2])
        if not frame.size:
            return None
        out = np.zeros((nframes, len(index), 1), np.uint32)
        np.bitwise_or.at(out, (frame, rows, 0), flag.astype(np.uint32))
        return out


def _on_rows(index, where, frame, *values):
    """``frame``, the band row and ``values`` of the entries at rows ``where`` that the
    band of rows ``index`` holds."""
    index = np.asarray(index)
    order = np.argsort(index, kind="stable")
    pos = np.searchsorted(index[order], where)
    pos = np.minimum(pos, index.size - 1)
    inside = index[order][pos] == where
    return frame[inside], order[pos[inside]], [v[inside] for v in values]


#: candidate pixels around jumps handled at once (bounds the memory of a large radius)
AROUND_CHUNK = 1 << 20


def _reach(params, nrows, ncols):
    """``(dr, dcs, which)`` per row offset: the column offsets ``dcs`` flagged at row offset
    ``dr`` around a jump of the stored image (``nrows x ncols``); ``which`` 0 for the
    neighbours, 1 for the radius.  A radius beyond the image reaches no further than its
    far corner: the rows and columns are bounded by its size, whatever the radius."""
    out = []
    if params["neighbours"]:
        out += [(-1, np.zeros(1, np.int64), 0), (1, np.zeros(1, np.int64), 0),
                (0, np.array([-1, 1], np.int64), 0)]
    r = float(params["radius"])
    if r > 0:
        n = int(min(np.floor(r), nrows - 1))
        for dr in range(-n, n + 1):
            w = int(min(np.floor(np.sqrt(r * r - dr * dr)), ncols - 1))  # r * r may be inf
            dcs = np.arange(-w, w + 1, dtype=np.int64)
            out.append((dr, dcs[dcs != 0] if dr == 0 else dcs, 1))
    return out


def _around(context, params, frames, index, cols, amp, z, saturated=None):
    """``(frames, index, cols)`` of the reads flagged around the jumps, each once: the
    neighbours and pixels within the radius on the stored image (physical rows and columns,
    across the seams of quadrants), at the jump's frame and, for a pixel read earlier in the
    frame than the jump's pixel, the next frame (the charge may have come after its read),
    for one read later the frame before.  With ``large_events``, the halos of large
    events around the jumps and the reads that saturated (``saturated``: ``(frames,
    index, cols)``), each core a set of them touching at one read."""
    s = context.schedule
    g = s.geometry
    layout = g.layout
    readout = context.order == "readout"
    rows = s.rows[index] if readout else index
    big = np.stack([np.abs(z) >= params["neighbours_above"], amp >= params["radius_above"]])
    reach = _reach(params, layout.nrows, layout.ncols)
    empty = np.zeros(0, np.int64)
    if (not reach or not big.any()) and not params["large_events"]:
        return empty, empty, empty
    srow, scol = layout.stored_coordinates(rows, cols)  # the jumps on the stored image
    # when each physical row is first read within a frame, and the reads of each row
    never = np.iinfo(np.int64).max
    first = np.full(g.nrows, never)
    np.minimum.at(first, s.rows, np.arange(s.n_reads))
    samples = s.pixel_samples()  # when each pixel is read within the frame
    hit = np.zeros((s.nframes, g.nrows, g.ncols), bool)  # each read flagged once
    if params["large_events"]:
        sf, si, sc = saturated
        sr, sc = layout.stored_coordinates(s.rows[si] if readout else si, sc)
        f, r, c = large_event_halos(np.concatenate([frames, sf]), np.concatenate([srow, sr]),
                                    np.concatenate([scol, sc]), (layout.nrows, layout.ncols),
                                    s.nframes, area=params["large_event_area"],
                                    expand=params["large_event_expand"],
                                    reads=params["large_event_reads"])
        fr, fc = layout.frame_coordinates(r, c)
        read = first[fr] < never
        hit[f[read], fr[read], fc[read]] = True
    for dr, dcs, which in reach:
        if not dcs.size:  # (no column within reach: an image one column wide)
            continue
        chosen = np.flatnonzero(big[which])
        step = max(1, AROUND_CHUNK // dcs.size)
        for lo in range(0, chosen.size, step):
            sel = chosen[lo:lo + step]
            r = np.repeat(srow[sel] + dr, dcs.size)
            c = (scol[sel][:, None] + dcs).ravel()
            jump = np.repeat(sel, dcs.size)
            ok = (r >= 0) & (r < layout.nrows) & (c >= 0) & (c < layout.ncols)
            fr, fc = layout.frame_coordinates(r[ok], c[ok])
            jump = jump[ok]
            read = first[fr] < never
            fr, fc, jump = fr[read], fc[read], jump[read]
            earlier = samples[first[fr], fc] < samples[first[rows[jump]], cols[jump]]
            f = frames[jump]
            hit[f, fr, fc] = True
            hit[np.clip(f + np.where(earlier, 1, -1), 0, s.nframes - 1), fr, fc] = True
    f, r, c = np.nonzero(hit)
    if not readout:
        return f, r, c
    # every read of those physical rows
    order = np.argsort(s.rows, kind="stable")
    lo = np.searchsorted(s.rows[order], r, "left")
    hi = np.searchsorted(s.rows[order], r, "right")
    count = hi - lo
    take = np.repeat(lo, count) + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count,
                                                                        count))
    return np.repeat(f, count), order[take], np.repeat(c, count)


class DetectJumpsStep(Step):
    """Flag the reads where a pixel's charge stepped (`~spherex_reduce.detect_jumps`)."""

    name, keyword = "detect_jumps", "S_JUMP"
    parameters = (
        Parameter("threshold", 4.0, (float,), "max |z| of a step (sigma) that is a jump",
                  minimum=0, exclusive_minimum=True),
        Parameter("read_noise", None, (*MAP_TYPES, type(None)), "read noise per read (data "
                  "unit): a number, a FITS image or an array; null: from each ramp"),
        Parameter("gain", 1.0, MAP_TYPES, "electrons per data unit (shot noise): a number, "
                  "a FITS image or an array"),
        Parameter("saturation", None, OPTIONAL_NUMBER, "reads above this level (data unit) "
                  "and every later read are not searched"),
        Parameter("max_jumps", 10, (int,), "jumps searched for in each ramp", minimum=1),
        Parameter("neighbours", False, (bool,), "also flag the 4 neighbours of large jumps"),
        Parameter("neighbours_above", 10.0, (float,), "smallest |z| (sigma) of a jump whose "
                  "neighbours are flagged", minimum=0),
        Parameter("radius", 0.0, (float,), "flag pixels within this distance (pixels) of "
                  "very large jumps; 0: none", minimum=0),
        Parameter("radius_above", 1e4, (float,), "smallest amplitude (data unit) of a jump "
                  "flagged with radius", minimum=0),
        Parameter("large_events", False, (bool,), "flag the halos of large events "
                  "(snowballs, showers) around cores of touching jumps, over several reads"),
        Parameter("large_event_area", 5, (int,), "fewest touching jumps at one read that "
                  "are a large event's core (pixels)", minimum=1),
        Parameter("large_event_expand", 2.0, (float,), "a large event's halo radius over "
                  "its core's", minimum=1, maximum=100),
        Parameter("large_event_reads", 1, (int,), "reads after a large event's also "
                  "flagged in its halo", minimum=0),
        Parameter("read_events", True, (bool,), "find reads off for most pixels (a first "
                  "read, a frame glitch): left out of every fit, not counted as jumps"),
        Parameter("telegraph", True, (bool,), "steps down and back up (or up and back "
                  "down) are a telegraph pixel's flips, not jumps: its rarer level's reads "
                  "are left out of its fit"),
        Parameter("positive_only", False, (bool,), "flag only the steps up (charge "
                  "added, as by cosmic rays); the steps down are fitted through"),
        Parameter("scale_read_noise", True, (bool,), "scale the read noise given to the "
                  "ramps' own scatter (each set of rows), so the false alarms stay as stated"),
        Parameter("expected_rate", None, (*MAP_TYPES, type(None)), "the rate each pixel "
                  "is expected to hold (data unit / s; a FITS image, e.g. the master "
                  "dark): steps are tested against a line with that slope's prior, "
                  "so mid-ramp steps are found at half the amplitude (needs read_noise); "
                  "null: the slope free", quiet_default=True),
    )

    def validate(self, params, path=None):
        """The parameters checked (`~spherex_reduce.reduce.step.Step.validate`), and
        ``expected_rate`` a map, when the pipeline is made rather than run."""
        out = super().validate(params, path)
        _check_expected_rate(out["expected_rate"])
        return out

    def kernel(self, context, **params):
        return JumpKernel(context, **params)


@hookimpl
def register_steps():
    return [DetectJumpsStep]
