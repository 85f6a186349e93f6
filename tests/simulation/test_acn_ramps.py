"""The ramps route splits the pixels' fast noise by column parity, as ACN asks.

With alternating-column noise the even and odd columns of a channel see two
independent realisations of a component.  The ramps route drew the pixels'
fast tier (above ``f_B / 2``) as one stream per channel, so for 1/f noise with
ACN its band power was 1.40x that of the exact slopes route (whose covariance
of the samples read is split by parity at every frequency) and mid-k bins up to
1.86x (z up to 32 with 200 realisations each).  Both routes now draw the same
statistics: the least-squares slope image of the ramps against the exact route's,
bin by bin and in band power; so does the tiered slopes route, which draws
the fast tier with the same code.
"""

import numpy as np
import pytest

from spherex_reduce.analysis.spectrum import band_power, power_spectrum
from spherex_reduce.io.config import schedule_from_config
from spherex_reduce.simulation import NoiseComponent
from spherex_reduce.simulation.engine import NoiseEngine

NREAL = 150
BINS = 8


def _schedule(phantom_reads, row_overhead, frame_overhead=None):
    return schedule_from_config(
        {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
        {"skip": 4, "ref_reads": 8, "ref_mode": "distributed", "phantom_reads": phantom_reads,
         "row_overhead": row_overhead, "frame_overhead": frame_overhead, "nframes": 10})


def _image(schedule, slopes):
    """Slopes in physical row order: each row the mean of its reads (brute force)."""
    g = schedule.geometry
    img = np.zeros((g.nrows, g.ncols))
    n = np.zeros(g.nrows)
    np.add.at(img, schedule.rows, np.asarray(slopes, dtype=float))
    np.add.at(n, schedule.rows, 1)
    return img / n[:, None]


def _spectra(schedule, comps, route, seeds):
    """Per-bin P(k) ``(realisations, bins)`` and band powers of the route's slope images."""
    powers, bands = [], []
    for seed in seeds:
        eng = NoiseEngine(schedule, comps, seed=seed, dtype=np.float64,
                          slope_route="exact" if route == "exact" else "tiered")
        if route in ("exact", "tiered"):
            slopes = eng.slopes()[0]
        else:  # the uniform least-squares fit of the ramps, frame by frame
            slopes = sum(w * pix for w, (pix, _) in zip(eng.frame_weights(), eng.frames(),
                                                         strict=True))
        img = _image(schedule, slopes)
        powers.append(np.asarray(power_spectrum(img, bins=BINS)["power"], dtype=float))
        bands.append(float(band_power(img, kmin=0.2, kmax=1.0).value))
    return np.array(powers), np.array(bands)


def _z(a, b):
    return (a.mean(0) - b.mean(0)) / np.hypot(a.std(0, ddof=1), b.std(0, ddof=1)) \
        * np.sqrt(len(a))


@pytest.mark.parametrize("phantom_reads, row_overhead", [
    (4, 4),  # even row_samples and frames, c even: each parity drawn at half rate
    (3, 5),  # the same with c odd: the parities swap sample indices
    (3, 4),  # odd row_samples: both parities drawn at full rate
])
def test_ramps_route_splits_fast_noise_by_column_parity(phantom_reads, row_overhead):
    s = _schedule(phantom_reads, row_overhead)
    assert s.row_samples == phantom_reads + 16 + row_overhead
    comps = [NoiseComponent("one_over_f", beta=8.4e-3, scope="channel", visibility="both",
                            acn=True)]
    _assert_routes_agree(s, comps, "ramps")


def _assert_routes_agree(schedule, comps, route, nreal=NREAL):
    p_route, b_route = _spectra(schedule, comps, route, range(nreal))
    p_exact, b_exact = _spectra(schedule, comps, "exact", range(nreal, 2 * nreal))
    assert np.all(np.abs(_z(p_route, p_exact)) < 3)
    assert abs(_z(b_route, b_exact)) < 3


def test_tiered_slopes_of_one_frame_blocks_split_fast_noise_by_column_parity():
    """Frames longer than the fast tier's correlation (as at full size): the slope image's
    fast part is one frame-length stream per channel and parity, drawn by the same code.

    Before the split: band power 1.27x the exact route's, bins up to z = 37 (600
    realisations each).  The per-bin P(k) of one image is far from Gaussian at
    low k; 400 realisations (cheap here) keep its sampling error well inside 3
    standard errors.
    """
    s = _schedule(4, 4, frame_overhead=30000)
    comps = [NoiseComponent("one_over_f", beta=8.4e-3, scope="channel", visibility="pixels",
                            acn=True),
             NoiseComponent("white", alpha=1e-6, scope="channel", acn=True)]
    assert NoiseEngine(s, comps).block == 1
    _assert_routes_agree(s, comps, "tiered", nreal=400)
