"""Groups of averaged reads: times and covariances against numpy brute force, round trips
through YAML and FITS, refusals, and the schedule without groups exactly as before."""

import numpy as np
import pytest
import yaml
from astropy import units as u
from astropy.io import fits

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, read, write
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError, FormatError
from spherex_reduce.io.config import load_yaml, schedule_from_config
from spherex_reduce.io.input import InputOptions

GEOMETRY = DetectorGeometry(16, 16, 2, ref_border=2)
BASE = {"skip": 3, "ref_reads": 2, "phantom_reads": 0, "frame_time": 0.25}
ROMAN = [[0], [1, 2], [3, 4, 5, 6], [7, 8, 9, 10, 11, 12, 13, 14]]
HOLES = [[2], [3, 5], [9, 10, 11], [12]]  # a first read skipped, a read inside a group too

#: (readout keys, reads of each group written out by hand)
CASES = {
    "jwst-4-gap-2": ({"nframes": 5, "frames_per_group": 4, "group_gap": 2},
                     [[6 * g + k for k in range(4)] for g in range(5)]),
    "jwst-2-no-gap": ({"nframes": 4, "frames_per_group": 2},
                      [[0, 1], [2, 3], [4, 5], [6, 7]]),
    "jwst-1-gap-3": ({"nframes": 3, "group_gap": 3}, [[0], [4], [8]]),
    "roman": ({"nframes": 4, "groups": ROMAN}, ROMAN),
    "holes": ({"nframes": 4, "groups": HOLES}, HOLES),
}


def schedule(**readout):
    return ReadoutSchedule(GEOMETRY, **{**BASE, **readout})


def brute(reads, frame_time):
    """Mean read time, read-noise factor and charge covariance per unit rate, read by read."""
    t = np.arange(max(r[-1] for r in reads) + 1) * frame_time  # every read of the exposure
    first = t[reads[0][0]]
    means = np.array([np.mean(t[r]) for r in reads])
    cov = np.array([[np.mean([min(t[a], t[b]) - first for a in g for b in h]) for h in reads]
                    for g in reads])
    return means, np.array([1 / len(r) for r in reads]), cov


@pytest.mark.parametrize("name", CASES)
def test_times_and_covariance_match_a_read_by_read_computation(name):
    readout, reads = CASES[name]
    s = schedule(**readout)
    means, factors, cov = brute(reads, 0.25)
    assert [r.tolist() for r in s.group_reads] == reads
    assert s.frames_read == reads[-1][-1] + 1
    assert s.integration_time.to_value(u.s) == pytest.approx((reads[-1][-1] + 1) * 0.25)
    np.testing.assert_allclose(s.frame_starts.to_value(u.s), means, rtol=1e-14)
    np.testing.assert_allclose(s.read_noise_factors, factors, rtol=1e-14)
    np.testing.assert_allclose(s.shot_covariance(), cov, rtol=1e-13, atol=1e-15)


def test_covariance_is_that_of_simulated_poisson_groups():
    """Averaged Poisson counts drawn read by read: their covariance is rate x the matrix."""
    s = schedule(nframes=4, groups=HOLES)
    rng = np.random.default_rng(3)
    rate, n = 40.0, 200_000  # e/s, ramps
    steps = rng.poisson(rate * 0.25, size=(n, 12))  # charge arriving between reads 0..12
    charge = np.concatenate([np.zeros((n, 1)), np.cumsum(steps, axis=1)], axis=1)
    charge -= charge[:, [HOLES[0][0]]]  # counted from the first read
    groups = np.stack([charge[:, r].mean(axis=1) for r in HOLES], axis=1)
    np.testing.assert_allclose(np.cov(groups.T), rate * s.shot_covariance(), rtol=0.02,
                               atol=0.05)


def test_a_schedule_without_groups_is_todays():
    s = schedule(nframes=7)
    t = np.arange(7) * s.frame_time
    assert np.array_equal(s.frame_starts.value, t.value) and s.frame_starts.unit == u.s
    assert np.array_equal(s.read_noise_factors, np.ones(7))
    tv = t.to_value(u.s)
    assert np.array_equal(s.shot_covariance(), np.minimum.outer(tv, tv) - tv[0])
    assert [r.tolist() for r in s.group_reads] == [[k] for k in range(7)]
    assert s.frames_read == 7 and s.integration_time == 7 * s.frame_time
    h = s.to_header()
    assert not {"NFRGRP", "NFRGAP", "GRPREADS"} & set(h)
    assert s.summary().endswith(f"N=7, {7 * 0.25:.6g} s")
    stated = schedule(nframes=7, frames_per_group=1, group_gap=0)
    assert stated == s and list(stated.to_header().items()) == list(h.items())


def test_the_pattern_and_its_explicit_list_give_the_same_fit_inputs():
    readout, reads = CASES["jwst-4-gap-2"]
    a, b = schedule(**readout), schedule(nframes=5, groups=reads)
    assert a != b  # stated differently, recorded differently
    for x, y in [(a.frame_starts, b.frame_starts), (a.read_noise_factors, b.read_noise_factors),
                 (a.shot_covariance(), b.shot_covariance())]:
        assert np.array_equal(x, y)


@pytest.mark.parametrize("name", CASES)
def test_yaml_round_trip(name):
    s = schedule(**CASES[name][0])
    text = yaml.safe_dump({"geometry": s.geometry.to_dict(), "readout": s.to_dict()})
    config, _ = load_yaml(text, "scene")
    again = schedule_from_config(config["geometry"], config["readout"])
    assert again == s and np.array_equal(again.frame_starts, s.frame_starts)


@pytest.mark.parametrize("name", [*CASES, "roman-long"])
def test_fits_round_trip(name, tmp_path):
    if name == "roman-long":  # a GRPREADS longer than one card
        reads = [list(range(k * (k - 1) // 2, k * (k + 1) // 2)) for k in range(1, 40)]
        s = schedule(nframes=len(reads), groups=reads)
    else:
        s = schedule(**CASES[name][0])
    data = np.arange(s.nframes * 14 * 16, dtype="f4").reshape(s.nframes, 14, 16)
    path = write(Exposure.from_arrays(data, s, unit=u.electron), tmp_path / "g.fits")
    with fits.open(path) as hdul:
        h = hdul[0].header
        assert ("GRPREADS" in h) == ("groups" in CASES.get(name, ({"groups": 0},))[0])
        assert ("NFRGRP" in h) == (s.frames_per_group != 1)
        assert ("NFRGAP" in h) == (s.group_gap != 0)
    e = read(path)
    assert e.schedule == s
    assert [r.tolist() for r in e.schedule.group_reads] == [r.tolist() for r in s.group_reads]
    assert np.array_equal(e.data.data, data)


@pytest.mark.parametrize("readout, message", [
    ({"nframes": 2, "groups": [[0, 1], [1, 2]]},
     "groups[1] starts at read 1, not after read 1 that ends groups[0]: groups must not "
     "overlap and must be in time order"),
    ({"nframes": 2, "groups": [[3], [1]]}, "groups[1] starts at read 1, not after read 3"),
    ({"nframes": 2, "groups": [[0], [3, 2]]},
     "groups[1] must list strictly increasing reads, got [3, 2]"),
    ({"nframes": 2, "groups": [[0], [2, 2]]}, "strictly increasing reads, got [2, 2]"),
    ({"nframes": 1, "groups": []}, "groups must be a non-empty list of lists"),
    ({"nframes": 2, "groups": [[0], []]}, "groups[1] must be a non-empty list of read indices"),
    ({"nframes": 2, "groups": [[0], 1]}, "groups[1] must be a non-empty list of read indices"),
    ({"nframes": 2, "groups": [[-1], [0]]}, "groups[0][0] must be a read index, an integer >= 0"),
    ({"nframes": 2, "groups": [[0], [1.5]]}, "groups[1][0] must be a read index"),
    ({"nframes": 2, "groups": [[0], [True]]}, "groups[1][0] must be a read index"),
    ({"nframes": 2, "groups": [[0], [2**40]]}, "a schedule can count"),
    ({"nframes": 2, "groups": [[0], [2**70]]},
     "groups[1][0] = 1180591620717411303424 is out of range: an exposure has fewer than 2**53"),
    ({"nframes": 3, "groups": [[0], [1]]},
     "groups lists 2 groups but nframes is 3: nframes is the number of groups"),
    ({"nframes": 2, "groups": [[0], [1]], "frames_per_group": 2},
     "give groups or frames_per_group/group_gap, not both (frames_per_group=2, group_gap=0)"),
    ({"nframes": 2, "groups": [[0], [1]], "group_gap": 1}, "not both"),
    ({"frames_per_group": 0}, "readout.frames_per_group: must be >= 1, got 0"),
    ({"group_gap": -1}, "readout.group_gap: must be >= 0, got -1"),
    ({"groups": "0;1-2"}, "readout.groups: expected list or null, got '0;1-2'"),
])
def test_bad_groups_are_refused_in_one_line(readout, message):
    with pytest.raises(ConfigError) as info:
        schedule_from_config(GEOMETRY.to_dict(), {**BASE, **readout})
    assert message in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("text, message", [
    ("0;1-x", "keyword GRPREADS: groups: expected reads like '0;1-2;3,5'"),
    ("0;3-1", "keyword GRPREADS: groups: the range '3-1' in '0;3-1' runs backwards"),
    ("0;;3", "keyword GRPREADS: groups: expected reads like"),
    ("0;0-2", "groups[1] starts at read 0, not after read 0"),
    ("0;1-100000000000", "groups: more than 16777216 reads listed in '0;1-100000000000'"),
])
def test_a_bad_header_list_is_refused(text, message):
    h = schedule(nframes=2, groups=[[0], [1, 2]]).to_header()
    h["GRPREADS"] = text
    with pytest.raises(FormatError, match=None) as info:
        ReadoutSchedule.from_header(h)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_command_line_groups(capsys):
    geometry = ["--nrows", "16", "--ncols", "16", "--nchannels", "2", "--ref-border", "2"]
    assert main(["readout", *geometry, "--nframes", "3", "--groups", "0;1-2;4-6"]) == 0
    assert capsys.readouterr().out.strip().endswith(  # 7 frames read
        "frame time 0.0252 s, N=3, 0.1764 s, groups 0;1-2;4-6")
    assert main(["readout", *geometry, "--groups", "0;2-1"]) == 2
    assert "argument --groups: groups: the range '2-1'" in capsys.readouterr().err


@pytest.mark.parametrize("readout", [{"groups": ROMAN}, {"frames_per_group": 3,
                                                         "group_gap": 1}])
def test_dropped_first_groups(readout, tmp_path):
    """``drop_first_reads`` drops stored frames (groups); the rest keep their reads."""
    s = schedule(nframes=4, **readout)
    data = np.arange(4 * 14 * 16, dtype="f4").reshape(4, 14, 16)
    path = write(Exposure.from_arrays(data, s, unit=u.electron), tmp_path / "g.fits")
    options = InputOptions.from_config({"drop_first_reads": 1})
    e = read(path, input=options, **readout)
    assert np.array_equal(e.data.data, data[1:])
    kept = [r.tolist() for r in s.group_reads[1:]]
    if "groups" in readout:  # the same reads: times differ by nothing
        assert [r.tolist() for r in e.schedule.group_reads] == kept
        np.testing.assert_allclose(e.schedule.frame_starts, s.frame_starts[1:], rtol=1e-14)
    else:  # the pattern restarts at read 0: times differ by one constant
        shift = s.frame_starts[1] - e.schedule.frame_starts[0]
        np.testing.assert_allclose(e.schedule.frame_starts + shift, s.frame_starts[1:])
    # written again after dropping, and read with the same config (full groups list)
    again = read(write(e, tmp_path / "dropped.fits"), input=options, **readout)
    assert again.schedule == e.schedule
