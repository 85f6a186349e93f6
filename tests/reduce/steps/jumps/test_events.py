"""The read-event rule of detect_jumps: its false alarms on binomial counts, the smallest
count it takes against scipy's binomial tail, and how it names the read that is off."""

import numpy as np
import pytest
from scipy.stats import binom

from spherex_reduce.reduce.steps.jumps.events import (
    ALPHA,
    BIG_STEP_FRACTION,
    BIG_STEP_MARGIN,
    EDGE_FACTOR,
    GLITCH_BALANCE,
    MIN_FRACTION,
    event_message,
    excess_reads,
    find_read_events,
)


def _null_rates(k, base, edge):
    """Per-read jump rates of a search with no read off: ``base`` in the middle, ``edge``
    times it at the first and last reads (the step search's, measured at <= 2.5)."""
    p = np.full(k, base)
    p[[0, -1]] *= edge
    return p


@pytest.mark.parametrize("npixels, base", [(1600, 0.03), (131072, 0.003)])
@pytest.mark.parametrize("edge", [1.0, 2.5])
def test_false_alarms_at_most_alpha_when_no_read_is_off(npixels, base, edge):
    """Binomial counts at 55 reads whose rates differ by up to 2.5x (more than the step
    search's): the rule, run at alpha = 0.05 so that its alarms can be counted, finds an
    event in at most 5 % of 4000 sets (and none at its own alpha, 1e-6)."""
    rng = np.random.default_rng(int(npixels * base) + int(10 * edge))
    k = 55
    counts = rng.binomial(npixels, _null_rates(k, base, edge), (4000, k))
    alarms = np.mean([excess_reads(c, npixels, alpha=0.05)[0].any() for c in counts])
    assert alarms <= 0.05
    assert not any(excess_reads(c, npixels)[0].any() for c in counts[:500])


def test_smallest_count_taken_is_scipys_binomial_quantile():
    """The rule takes a read when P(X >= c) < ALPHA / K for X ~ Binomial(N, p0), p0 the
    other reads' rate (one count added) times EDGE_FACTOR: the smallest such c from scipy."""
    npixels, k = 40000, 20
    others = np.full(k - 1, 30)  # 30 pixels jump at each other read
    p0 = EDGE_FACTOR * (others.sum() + 1) / (npixels * (k - 1))
    c_min = int(binom.isf(ALPHA / k, npixels, p0)) + 1  # smallest c with sf(c - 1) < a / k
    while binom.sf(c_min - 2, npixels, p0) < ALPHA / k:
        c_min -= 1
    c_min = max(c_min, int(np.ceil(MIN_FRACTION * npixels)))
    for c, taken in ((c_min - 1, False), (c_min, True)):
        excess, expected = excess_reads(np.r_[c, others], npixels)
        assert excess.tolist() == [taken] + [False] * (k - 1)
        assert expected[0] == pytest.approx(npixels * p0, rel=1e-12)


def test_below_the_fraction_no_event_however_significant():
    """0.5 % of a million pixels at one read, against none at the others: significant, but
    not a read that is off for most pixels."""
    counts = np.r_[5000, np.zeros(30, int)]
    assert not excess_reads(counts, 10 ** 6)[0].any()
    assert excess_reads(np.r_[20000, np.zeros(30, int)], 10 ** 6)[0][0]


def _scatter(rng, n, nrows, ncols):
    pix = rng.choice(nrows * ncols, n, replace=False)
    return pix // ncols, pix % ncols


@pytest.mark.parametrize("reads, signs, expected", [
    ([1], [1], [(0, "first read")]),
    ([20, 21], [1, -1], [(20, "frame glitch")]),
    ([55], [-1], [(55, "last read")]),
    ([15], [1], [(15, "step")]),
    ([1, 2], [-1, 1], [(1, "frame glitch")]),
])
def test_the_read_that_is_off_is_named(reads, signs, expected):
    """Jumps at the same read(s) in 30 % of a 40 x 40 set, spread over it, and 6 cosmic
    rays: a first read low (steps up at read 1), a read 20 high (up at 20, down at 21), a
    last read low, the array stepping at 15, read 1 low."""
    rng = np.random.default_rng(len(reads) + reads[0])
    r, c, f, a = [], [], [], []
    rows, cols = _scatter(rng, 480, 40, 40)
    for read, sign in zip(reads, signs, strict=True):
        r.append(rows)
        c.append(cols)
        f.append(np.full(rows.size, read))
        a.append(sign * rng.uniform(15, 25, rows.size))
    r.append(rng.integers(0, 40, 6))
    c.append(rng.integers(0, 40, 6))
    f.append(rng.integers(1, 56, 6))
    a.append(rng.uniform(50, 500, 6))
    events = find_read_events(np.concatenate(f), np.concatenate(r), np.concatenate(c),
                              np.concatenate(a), nreads=56, nrows=40, ncols=40)
    assert [(e.read, e.kind) for e in events] == expected
    assert events[0].jumps == 480 and events[0].pixels == 1600


@pytest.mark.parametrize("echo, expected", [(60, (0, "first read")),
                                             (300, (1, "frame glitch"))])
def test_the_second_steps_of_pairs_are_not_a_glitch(echo, expected):
    """Read 0 low in a readout of groups of frames: 480 of 1600 pixels step up at read 1,
    and where the search took the step as a pair into and out of group 1 (60 of them) a
    small step down at read 2, significant too.  Those are the pairs' second steps: one
    event, the first read (it was named a frame glitch of read 1, left out instead of read
    0).  Counts within GLITCH_BALANCE (300 of 480) are a read 1 that is off."""
    rng = np.random.default_rng(3522)
    rows, cols = _scatter(rng, 480, 40, 40)
    f = np.r_[np.ones(480, int), np.full(echo, 2)]
    r, c = np.r_[rows, rows[:echo]], np.r_[cols, cols[:echo]]
    a = np.r_[rng.uniform(15, 25, 480), -rng.uniform(2, 8, echo)]
    events = find_read_events(f, r, c, a, nreads=56, nrows=40, ncols=40)
    assert echo / 480 < GLITCH_BALANCE or expected[1] == "frame glitch"
    assert [(e.read, e.kind) for e in events] == [expected]
    assert events[0].jumps == 480


def test_a_shower_is_local_not_a_read_event():
    """A shower hits an 8 x 8 patch (4 % of the pixels) at one read: many jumps at that
    read, but in 1 of the 16 cells of the set, not half of them."""
    rows, cols = np.divmod(np.arange(64), 8)
    events = find_read_events(np.full(64, 30), rows + 3, cols + 5, np.full(64, 300.0),
                              nreads=56, nrows=40, ncols=40)
    assert events == ()
    # the same count spread over the set is an event
    rng = np.random.default_rng(1)
    rows, cols = _scatter(rng, 64, 40, 40)
    events = find_read_events(np.full(64, 30), rows, cols, np.full(64, 300.0), nreads=56,
                              nrows=40, ncols=40)
    assert [(e.read, e.kind) for e in events] == [(30, "step")]


def test_the_message_is_one_line_naming_the_read_and_the_fix():
    text = event_message(0, "first read", 498, 0.7, 1600, -17.9, dropped_before=1)
    assert "\n" not in text and "read 0" in text and "drop_first_reads: 2" in text
    text = event_message(20, "frame glitch", 300, 2.0, 1600, 60.0)
    assert "read 20" in text and "DO_NOT_USE" in text


def test_many_large_steps_at_one_read_in_few_pixels_are_no_event():
    """10-30 e cosmic rays falling in 1.2 % of 65 536 pixels at one read (Roman's 8-frame
    resultant in the middle of the ramp, where a recipe puts its mid-ramp hits), z ~ 7 at
    a threshold of 4: the array stepping that much would have been found in nearly every
    pixel, so no event (every pixel was fitted in two segments around it: clean rms
    1.75 sigma0).  The same steps at z just over the threshold, as an offset of the whole
    set below it leaves them, remain an event."""
    rng = np.random.default_rng(3523)
    npix, side = 65536, 256
    n = int(0.012 * npix)
    rows, cols = _scatter(rng, n, side, side)
    reads = np.full(n, 6)
    amp = rng.uniform(10, 30, n)
    for z, expected in ((amp / 2.3, []), (rng.uniform(4.0, 5.0, n), [(6, "step")])):
        events = find_read_events(reads, rows, cols, amp, nreads=10, nrows=side, ncols=side,
                                  z=z, threshold=4.0)
        assert [(e.read, e.kind) for e in events] == expected
    assert find_read_events(reads, rows, cols, amp, nreads=10, nrows=side, ncols=side)
    assert BIG_STEP_MARGIN > 0 and BIG_STEP_FRACTION > 0.012


def test_a_read_off_in_many_outputs_stays_an_event_however_large():
    """A read 100 e high in 14 of 32 outputs (44 % of the pixels, z ~ 10, every cell of the
    set): more than a tenth of the pixels, so an event (the size rule is for steps in a
    few per cent), and ``z`` without ``threshold`` is refused."""
    side = 256
    cols = np.flatnonzero((np.arange(side) // 8) % 32 < 14)  # 14 outputs of 8 columns
    rows, cc = np.meshgrid(np.arange(side), cols, indexing="ij")
    rows, cc = rows.ravel(), cc.ravel()
    n = rows.size
    reads = np.r_[np.full(n, 10), np.full(n, 11)]
    amp = np.r_[np.full(n, 100.0), np.full(n, -100.0)]
    z = amp / 10.0
    events = find_read_events(reads, np.r_[rows, rows], np.r_[cc, cc], amp, nreads=30,
                              nrows=side, ncols=side, z=z, threshold=4.0)
    assert [(e.read, e.kind) for e in events] == [(10, "frame glitch")]
    with pytest.raises(ValueError, match="z and threshold"):
        find_read_events(reads, np.r_[rows, rows], np.r_[cc, cc], amp, nreads=30,
                         nrows=side, ncols=side, z=z)
