"""Small example inputs made by code (nothing large is stored in the repository)."""

import numpy as np

from ..core.exposure import Exposure
from .config import schedule_from_config

__all__ = ["example_raw_exposure", "tiny_schedule"]


def tiny_schedule(nframes=6, skip=4, ref_reads=8, phantom_reads=2):
    """A 64 x 64 array read by 4 channels: quick to reduce, still chopped.

    Examples
    --------
    >>> from spherex_reduce.io.examples import tiny_schedule
    >>> tiny_schedule().summary()[:44]
    '64x64 array, 4 channels of 16 columns, S=4, '
    """
    return schedule_from_config(
        {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
        {"skip": skip, "ref_reads": ref_reads, "phantom_reads": phantom_reads,
         "nframes": nframes, "frame_overhead": 100},
    )


def example_raw_exposure(schedule=None, seed=0, read_noise=10.0, drift=3.0, flux=50.0):
    """A raw exposure (readout order, electrons) with easily recognised content.

    Built from plain random numbers, not from the noise model: each pixel
    integrates ``flux`` (e/s) of a diagonal gradient pattern on its active
    rows, every sample gets white noise of ``read_noise`` electrons, and each
    channel drifts as a random walk of ``drift`` electrons per row read, which
    the phantom reads see too.  Useful to exercise the format and the steps.

    Parameters
    ----------
    schedule : `ReadoutSchedule`, optional
        Defaults to :func:`tiny_schedule`.
    seed : int
        Seed of `numpy.random.default_rng`.

    Returns
    -------
    `Exposure`
        Ramps ``(frames, reads, columns)`` in float32, with phantom reads.
    """
    schedule = schedule or tiny_schedule()
    rng = np.random.default_rng(seed)
    g = schedule.geometry
    nf, nr = schedule.nframes, schedule.n_reads
    rows = schedule.rows
    yy, xx = np.meshgrid(rows, np.arange(g.ncols), indexing="ij")
    pattern = 1.0 + 0.5 * np.sin(2 * np.pi * (yy + xx) / 32.0)
    pattern[schedule.is_reference] = 0.0
    pattern[:, g.reference_column_mask()] = 0.0
    t = schedule.frame_starts.value[:, None, None] + schedule.pixel_times().value[None]
    walk = np.cumsum(rng.normal(0, drift, (nf * nr, g.nchannels)), axis=0).reshape(nf, nr, -1)
    data = flux * pattern[None] * t + rng.normal(0, read_noise, (nf, nr, g.ncols))
    data += np.repeat(walk, g.channel_width, axis=2)
    phantom = None
    if schedule.phantom_reads:
        phantom = walk + rng.normal(0, read_noise / np.sqrt(schedule.phantom_reads), walk.shape)
        phantom = phantom.astype(np.float32)
    return Exposure.from_arrays(data.astype(np.float32), schedule, phantom=phantom)
