"""Large events (snowballs, showers): their halo flagged around the core, over several reads."""

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, detect_jumps, dq, fit_ramp
from spherex_reduce.reduce.steps.jumps.showers import large_event_halos

NF, DT, RN = 30, 1.5, 10.0
CENTRE = (20.3, 21.6)
CORE, HALO = 2.5, 4.5  # pixels: the core's charge and its halo's reach
READ = 12  # the event's read


def schedule(n=40, skip=1):
    return ReadoutSchedule(DetectorGeometry(n, n, 1, ref_border=0), skip=skip, ref_reads=0,
                           ref_mode="none", phantom_reads=0, nframes=NF, frame_time=DT)


def snowball(s, seed=3, halo_step=8.0):
    """Dark ramps with a snowball at ``READ``: 3e4 e in the core, ``halo_step`` e in each of
    the event's read and the next over the halo (below the pixels' own threshold)."""
    rng = np.random.default_rng(seed)
    g = s.geometry
    r, c = np.indices((g.nrows, g.ncols))
    d = np.hypot(r - CENTRE[0], c - CENTRE[1])
    cube = 1e3 + rng.normal(0, RN, (NF, g.nrows, g.ncols))
    cube[READ:, d <= CORE] += 3e4
    halo = (d > CORE) & (d <= HALO)
    cube[READ:, halo] += halo_step
    cube[READ + 1:, halo] += halo_step
    return cube.astype(np.float32), d


def disc(jumps, shape, expand):
    """The halo the rule gives, computed here: the core's centroid, its radius the larger of
    the disc of its area and its farthest jump, times ``expand``."""
    rows, cols = jumps[:, 0], jumps[:, 1]
    r0, c0 = rows.mean(), cols.mean()
    radius = expand * max(np.sqrt(len(rows) / np.pi),
                          np.hypot(rows - r0, cols - c0).max())
    r, c = np.indices(shape)
    return np.hypot(r - r0, c - c0) <= radius


def test_the_halo_is_the_expanded_core_at_the_event_and_the_next_read():
    s = schedule()
    cube, d = snowball(s)
    e = Exposure.from_arrays(cube, s)
    plain = detect_jumps(e, read_noise=RN, threshold=5.0)
    core = np.argwhere(plain.dq[READ] & dq.JUMP)
    assert len(core) == int((d <= CORE).sum())  # every core pixel, nothing else
    out = detect_jumps(e, read_noise=RN, threshold=5.0, large_events=True)
    want = disc(core, d.shape, 2.0)
    for f in range(NF):
        got = (out.dq[f] & dq.JUMP) != 0
        if f in (READ, READ + 1):
            np.testing.assert_array_equal(got, want)
        else:
            assert not got.any()
    assert want[(d > CORE) & (d <= HALO)].all()  # the halo is inside
    assert out.header["NJUMPNB"] == 2 * want.sum()


def test_the_halo_leaves_the_slopes_unbiased():
    """Over 12 snowballs, the halo pixels' slopes are biased by the halo's 16 e without the
    flags (a closed form: the least-squares weights of the reads after the event), and
    unbiased with them."""
    s = schedule()
    t = (np.arange(NF) + 0.5) * DT
    w = (t - t.mean()) / ((t - t.mean()) ** 2).sum()
    expected_bias = 8.0 * (w[READ:].sum() + w[READ + 1:].sum())
    plain, flagged = [], []
    for seed in range(12):
        cube, d = snowball(s, seed)
        halo = (d > CORE) & (d <= HALO)
        e = Exposure.from_arrays(cube, s)
        for out, acc in ((detect_jumps(e, read_noise=RN, threshold=5.0), plain),
                         (detect_jumps(e, read_noise=RN, threshold=5.0, large_events=True),
                          flagged)):
            slope = fit_ramp(out, read_noise=RN).data
            acc.append(np.asarray(slope)[halo])
    plain, flagged = np.concatenate(plain), np.concatenate(flagged)
    err = plain.std() / np.sqrt(plain.size)
    assert abs(plain.mean() - expected_bias) < 4 * err
    assert expected_bias > 10 * err
    assert abs(flagged.mean()) < 4 * flagged.std() / np.sqrt(flagged.size)


def test_small_clusters_are_not_large_events():
    # four touching jumps (a cosmic ray and its interpixel neighbours) stay as they are
    f, _, _ = large_event_halos([5, 5, 5, 5], [10, 11, 10, 9], [10, 10, 11, 10], (32, 32), 20)
    assert f.size == 0
    # five in a row at one read are one core; the same five over two reads are not
    f, r, _ = large_event_halos([5] * 5, [10] * 5, range(10, 15), (32, 32), 20, reads=0)
    assert set(f.tolist()) == {5} and (r.min(), r.max()) == (6, 14)  # radius 2 * 2 = 4
    f, _, _ = large_event_halos([5, 6, 5, 6, 5], [10] * 5, range(10, 15), (32, 32), 20)
    assert f.size == 0


def test_the_halo_stops_at_the_array_and_the_last_read():
    f, r, c = large_event_halos([19] * 9, np.repeat([0, 1, 2], 3), np.tile([0, 1, 2], 3),
                                (8, 8), 20, expand=3.0, reads=4)
    assert set(f.tolist()) == {19}
    assert r.min() == 0 and c.min() == 0 and r.max() < 8 and c.max() < 8


@pytest.mark.parametrize("expand", [0.5, 1e3])
def test_an_expansion_out_of_range_is_one_line(expand):
    s = schedule(16)
    e = Exposure.from_arrays(np.zeros((NF, 16, 16), np.float32), s)
    with pytest.raises(Exception, match="large_event_expand") as err:
        detect_jumps(e, read_noise=RN, large_events=True, large_event_expand=expand)
    assert "\n" not in str(err.value)


def test_a_saturated_core_in_readout_order_flags_its_halo_on_physical_rows():
    """A core that saturates at the event's read (no jump is seen in it: its later reads
    are saturated) is a core too; with rows read out of order (row chopping), the halo is
    a disc of physical rows, flagged on every read of them."""
    s = schedule(32, skip=4)
    cube, d = snowball(schedule(32), seed=5)  # physical rows
    rows = s.rows  # physical row of every read
    readout = cube[:, rows]  # the same pixels in readout order
    sat = np.zeros(readout.shape, np.uint32)
    sat[READ:, d[rows] <= CORE] = dq.SATURATED
    e = Exposure.from_arrays(readout, s, mask=sat)
    out = detect_jumps(e, read_noise=RN, threshold=5.0, large_events=True)
    core = np.argwhere(d <= CORE)  # the saturated pixels, on physical rows
    want = disc(core, d.shape, 2.0)
    for f in range(NF):
        got = (out.dq[f] & dq.JUMP) != 0
        np.testing.assert_array_equal(got, want[rows] if f in (READ, READ + 1)
                                      else np.zeros_like(got))
