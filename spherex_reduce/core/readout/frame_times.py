"""When the stored frames of a ramp were read: every frame time, in groups, or at given times.

`StoredFrameTimes` gives a `~spherex_reduce.ReadoutSchedule` the times a
ramp fit needs (`~StoredFrameTimes.frame_starts`,
`~StoredFrameTimes.read_noise_factors`, `~StoredFrameTimes.shot_covariance`).
Most electronics read the array every frame time, so a
`~spherex_reduce.ReadoutSchedule` places stored frame ``k`` at ``k`` frame
times (or at its group's mean read, `spherex_reduce.core.readout.groups`).  HST's
WFC3/IR reads at the times of a sample sequence (``RAPID``, ``SPARS10`` ...),
stored as the ``SAMPTIME`` of each read: ``0, 2.93, 12.93, 22.93 ...`` s, not
a multiple of one frame time.  The schedule's ``read_times`` carry such times
exactly (seconds from the first read's start, one per stored frame, each
stored frame one read of the array); the ramp fit then uses them instead of
even spacing.  This module checks them and writes them as FITS text
(keyword ``RDTIMES``) and back.

Examples
--------
>>> from spherex_reduce.core.readout.frame_times import format_read_times, parse_read_times
>>> format_read_times((0.0, 2.932, 12.933))
'0.0,2.932,12.933'
>>> parse_read_times("0.0,2.932,12.933")
[0.0, 2.932, 12.933]
"""

import itertools
import math

import numpy as np
from astropy import units as u

from .groups import group_covariance, group_means

#: The latest read time accepted (s, ~32 years): a fit squares the times, which
#: must stay far from float64 overflow (1e300 s gave every slope 0).
MAX_READ_TIME = 1e9

__all__ = ["StoredFrameTimes", "check_read_times", "describe_read_times", "format_read_times",
           "parse_read_times"]


class StoredFrameTimes:
    """The times of a schedule's stored frames (a base of `~spherex_reduce.ReadoutSchedule`,
    which sets ``nframes``, ``frame_time``, ``read_times`` and ``_reads``, the reads of
    each group or None)."""

    @property
    def integration_time(self):
        """From the first read's start to the last read's end: `frames_read` times the frame
        time (``nframes`` times it without groups); with ``read_times``, the last time
        less the first, plus one frame time."""
        if self.read_times is not None:
            return (self.read_times[-1] - self.read_times[0]) * u.s + self.frame_time
        return self.frames_read * self.frame_time

    @property
    def group_reads(self):
        """The reads (0-based frames of the exposure) of each stored frame: ``nframes``
        int arrays, ``[[0], [1], ...]`` without groups."""
        return list(np.arange(self.nframes)[:, None] if self._reads is None else self._reads)

    @property
    def frames_read(self):
        """Frames read over the exposure, discarded ones included: the last read + 1."""
        return self.nframes if self._reads is None else int(self._reads[-1][-1]) + 1

    @property
    def frame_starts(self):
        """Start time of every stored frame (a group's mean read, or its ``read_times``
        entry), ``(nframes,)``, in s."""
        if self.read_times is not None:
            return np.array(self.read_times, dtype=np.float64) * u.s
        if self._reads is None:
            return np.arange(self.nframes) * self.frame_time
        return group_means(self._reads) * self.frame_time

    @property
    def read_noise_factors(self):
        """Read-noise variance of every stored frame in units of one read's, ``(nframes,)``:
        1 / the reads of its group."""
        return (np.ones(self.nframes) if self._reads is None
                else 1.0 / np.array([r.size for r in self._reads], dtype=np.float64))

    def shot_covariance(self):
        """Covariance (s) of the charge of stored frames ``g`` and ``h`` per unit rate,
        ``(nframes, nframes)``: the mean over their reads of ``min(t_a, t_b) - t_first``
        (`~spherex_reduce.core.readout.groups.group_covariance`)."""
        if self._reads is None:
            t = self.frame_starts.to_value(u.s)
            return np.minimum.outer(t, t) - t[0]
        return group_covariance(self._reads) * self.frame_time.to_value(u.s)


def check_read_times(times, nframes, grouped, read_duration):
    """Explicit read times checked: a tuple of float (s), or None if ``times`` is None.

    Parameters
    ----------
    times : sequence of float or None
        The time (s) of every stored frame's read, in time order.
    nframes : int
        The stored frames the list must describe.
    grouped : bool
        Whether the schedule also averages frames into groups (then refused:
        explicit times are those of single reads).
    read_duration : float
        Seconds one read of the array lasts (its rows, without the frame
        overhead): consecutive reads must be at least that far apart.

    Raises
    ------
    ValueError
        One line naming the first entry at fault.

    Examples
    --------
    >>> from spherex_reduce.core.readout.frame_times import check_read_times
    >>> check_read_times([0, 2.932, 12.933], 3, False, 2.6)
    (0.0, 2.932, 12.933)
    >>> check_read_times([0, 2.9, 2.9], 3, False, 2.6)
    Traceback (most recent call last):
    ...
    ValueError: read_times[2] = 2.9 s is 0 s after read_times[1]: ... at least 2.6 s apart ...
    """
    if times is None:
        return None
    if isinstance(times, (str, bytes)) or not isinstance(times, (list, tuple, np.ndarray)):
        raise ValueError(f"read_times must be a list of times (s), one per frame, got {times!r}")
    if grouped:
        raise ValueError("give read_times or groups (frames_per_group, group_gap), not both: "
                         "read times are those of single reads of the array")
    out = []
    for k, t in enumerate(times):
        number = isinstance(t, (int, float, np.integer, np.floating)) and not isinstance(
            t, (bool, np.bool_))
        if not number or not math.isfinite(t) or not 0 <= t <= MAX_READ_TIME:
            raise ValueError(f"read_times[{k}] must be a time from 0 to {MAX_READ_TIME:g} s, "
                             f"got {t!r}")
        out.append(float(t))
    if len(out) != nframes:
        raise ValueError(f"read_times lists {len(out)} times but nframes is {nframes}: one time "
                         "per stored frame")
    for k, (a, b) in enumerate(itertools.pairwise(out), start=1):
        if b - a < read_duration * (1 - 1e-9):
            raise ValueError(f"read_times[{k}] = {b:.6g} s is {b - a:.6g} s after "
                             f"read_times[{k - 1}]: reads must be in time order, at least "
                             f"{read_duration:.6g} s apart (the time to read the array once)")
    return tuple(out)


def describe_read_times(times):
    """The read times for a schedule's summary: ``''`` when frames are evenly spaced.

    Examples
    --------
    >>> from spherex_reduce.core.readout.frame_times import describe_read_times
    >>> describe_read_times((0.0, 2.932, 12.933))
    ', read at 0 ... 12.933 s (3 times given)'
    """
    if times is None:
        return ""
    return f", read at {times[0]:.6g} ... {times[-1]:.6g} s ({len(times)} times given)"


def format_read_times(times):
    """The times as one line of text, ``,`` between them (keyword ``RDTIMES``); exact: each
    float is written as the shortest text that reads back the same."""
    return ",".join(repr(float(t)) for t in times)


def parse_read_times(text):
    """The times of a `format_read_times` text, as a list of float (not yet checked).

    Raises
    ------
    ValueError
        Text that is not numbers separated by ``,``.
    """
    try:
        return [float(item) for item in str(text).split(",")]
    except ValueError:
        raise ValueError(f"read_times: expected times (s) like '0,2.932,12.933', got "
                         f"{str(text)[:60]!r}") from None
