"""Groups of reads in the simulator: every read simulated, each group's reads averaged.

A schedule whose stored frames are groups of reads (``frames_per_group`` and
``group_gap``, or ``groups``) is simulated read by read on `read_schedule`,
the same readout with every read stored; `average_groups` then stores each
group's mean, as the electronics do, and discards the reads between groups.
"""

import numpy as np

from ..core.errors import ConfigError

__all__ = ["average_groups", "read_schedule"]


def read_schedule(schedule):
    """The schedule of every read of ``schedule``'s exposure (itself without groups).

    A schedule with ``read_times`` (reads at uneven times) is refused
    (`~spherex_reduce.core.errors.ConfigError`).

    Examples
    --------
    >>> from spherex_reduce.io.examples import tiny_schedule
    >>> from spherex_reduce.simulation.grouping import read_schedule
    >>> s = tiny_schedule().replace(nframes=2, groups=[[0, 1], [3, 4, 5]])
    >>> read_schedule(s).nframes, read_schedule(s).frame_time == s.frame_time
    (6, np.True_)
    """
    if schedule.read_times is not None:  # never simulated as if even
        raise ConfigError("readout.read_times: the simulator reads the array every "
                          "frame_time; reads at given times are not simulated: leave "
                          "read_times out")
    if schedule.frames_read == schedule.nframes:  # one read per stored frame, none skipped
        return schedule
    return schedule.replace(nframes=schedule.frames_read, frames_per_group=1, group_gap=0,
                            groups=None)


def average_groups(frames, schedule):
    """The stored frames of ``schedule`` from its reads.

    Parameters
    ----------
    frames : iterable of (`numpy.ndarray`, `numpy.ndarray` or None)
        ``(pixels, phantom)`` of every read of `read_schedule`, in time order.
    schedule : `~spherex_reduce.ReadoutSchedule`

    Yields
    ------
    pixels, phantom
        Each group's mean (accumulated in float64, returned in the reads'
        dtype), ``nframes`` of them; reads in no group are discarded.
    """
    if schedule.frames_read == schedule.nframes:
        yield from frames
        return
    used = np.zeros(schedule.frames_read, bool)
    last = np.zeros(schedule.frames_read, bool)  # the last read of a group
    for reads in schedule.group_reads:
        used[reads] = True
        last[reads[-1]] = True
    sums, n = None, 0
    for k, (pixels, phantom) in enumerate(frames):
        if not used[k]:
            continue
        if sums is None:
            sums = [None if a is None else np.zeros(a.shape) for a in (pixels, phantom)]
            dtype = pixels.dtype
        for total, a in zip(sums, (pixels, phantom), strict=True):
            if a is not None:
                total += a
        n += 1
        if last[k]:
            yield tuple(None if t is None else (t / n).astype(dtype) for t in sums)
            sums, n = None, 0
