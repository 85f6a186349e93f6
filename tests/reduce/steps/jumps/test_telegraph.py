"""Telegraph pixels told from cosmic rays: alternating steps that come back to the same
level (a joint least-squares fit written here decides, not the search's amplitudes)."""

import numpy as np
import pytest

from spherex_reduce.reduce.steps.jumps.telegraph import telegraph_pixels

T = np.arange(40) * 2.0


def _ramps(rng, m):
    return 500 + 0.05 * T[:, None] + rng.normal(0, 4, (40, m))


def test_a_pixel_that_flips_and_returns_is_telegraph_and_its_rare_level_left_out():
    """Pixel 0 is 30 low at reads 10-17 and 26-31 (14 of 40 reads): its 4 flips are not
    jumps and those 14 reads are left out; pixel 1's cosmic ray (at 20) stays a jump."""
    rng = np.random.default_rng(0)
    y = _ramps(rng, 2)
    y[10:18, 0] -= 30
    y[26:32, 0] -= 30
    y[20:, 1] += 200
    flips, (reads, pixels) = telegraph_pixels([0, 0, 0, 0, 1], [10, 18, 26, 32, 20],
                                              [-30, 30, -30, 30, 200], y, T)
    assert flips.tolist() == [True] * 4 + [False]
    assert set(pixels.tolist()) == {0}
    assert reads.tolist() == list(range(10, 18)) + list(range(26, 32))


def test_the_majority_level_is_kept_even_when_the_pixel_starts_in_the_other():
    """Up at 5, down at 35: 30 reads in the upper level, 10 in the first: the first
    level's reads (0-4 and 35-39) are left out."""
    rng = np.random.default_rng(1)
    y = _ramps(rng, 1)
    y[5:35, 0] += 50
    flips, (reads, _) = telegraph_pixels([0, 0], [5, 35], [50, -50], y, T)
    assert flips.all()
    assert reads.tolist() == [0, 1, 2, 3, 4, 35, 36, 37, 38, 39]


@pytest.mark.parametrize("second", [-120.0, 60.0])
def test_steps_that_do_not_come_back_are_not_a_telegraph(second):
    """A cosmic ray of +200 then a step of -120 (the level does not come back: 8 sigma of
    their sum's error off) or two steps up: jumps, not flips."""
    rng = np.random.default_rng(2)
    y = _ramps(rng, 1)
    y[12:, 0] += 200
    y[30:, 0] += second
    flips, (reads, _) = telegraph_pixels([0, 0], [12, 30], [200, second], y, T)
    assert not flips.any() and reads.size == 0


def test_reads_not_usable_are_not_fitted_nor_counted():
    """Read 3 is off by 1e4 and not usable: the fit leaves it out (else the flips would not
    cancel) and the levels count the usable reads only."""
    rng = np.random.default_rng(3)
    y = _ramps(rng, 1)
    y[3, 0] += 1e4
    y[20:30, 0] -= 25
    usable = np.ones((40, 1), bool)
    usable[3] = False
    flips, (reads, _) = telegraph_pixels([0, 0], [20, 30], [-25, 25], y, T, usable)
    assert flips.all() and reads.tolist() == list(range(20, 30))
