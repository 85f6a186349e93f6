"""Reads at given times (``read_times``): checked, written to FITS and back, used by the fit."""

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.core.errors import FormatError

TIMES = [0.0, 2.932, 12.933, 22.934]


def _schedule(**readout):
    g = DetectorGeometry(8, 8, 2, ref_border=0, pixel_rate=1e5)
    values = {"skip": 1, "ref_mode": "none", "phantom_reads": 0, "row_overhead": 0,
              "frame_time": 2.932, "nframes": len(TIMES), "read_times": TIMES, **readout}
    return ReadoutSchedule(g, **values)


def test_frame_starts_and_shot_covariance_are_the_times():
    s = _schedule()
    t = np.array(TIMES)
    assert s.frame_starts.to_value("s").tolist() == TIMES
    np.testing.assert_array_equal(s.shot_covariance(), np.minimum.outer(t, t))
    assert s.read_noise_factors.tolist() == [1.0] * 4
    assert s.integration_time.to_value("s") == pytest.approx(22.934 + 2.932)
    assert s.summary().endswith(", read at 0 ... 22.934 s (4 times given)")


def test_header_round_trip_is_exact():
    times = [0.0, 2.932291, 12.9332874, 22.93412345678901]
    s = _schedule(read_times=times)
    again = ReadoutSchedule.from_header(s.to_header())
    assert again.read_times == tuple(times) and again == s


@pytest.mark.parametrize("readout, message", [
    ({"read_times": [0.0, 2.932, 12.933]}, "read_times lists 3 times but nframes is 4"),
    ({"read_times": [0.0, 12.933, 2.932, 22.934]},
     r"read_times\[2\] = 2.932 s is -10.001 s after read_times\[1\]: reads must be in time "
     "order"),
    ({"read_times": [0.0, 0.0001, 12.933, 22.934]},
     r"read_times\[1\] = 0.0001 s is 0.0001 s after read_times\[0\]: .* at least 0.00032 s"),
    ({"read_times": [0.0, float("nan"), 1.0, 2.0]}, r"read_times\[1\] must be a time from 0"),
    ({"read_times": [-1.0, 2.0, 4.0, 6.0]}, r"read_times\[0\] must be a time from 0 to 1e\+09 s"),
    ({"read_times": [0.0, 1.0, 2.0, 1e300]}, r"read_times\[3\] must be a time from 0 to 1e\+09 s"),
    ({"groups": [[0], [1], [2], [4]]}, "give read_times or groups"),
    ({"read_times": "0,1,2,3"}, "read_times must be a list of times"),
], ids=["count", "order", "too-close", "nan", "negative", "huge", "with-groups", "text"])
def test_bad_read_times_are_refused_naming_the_entry(readout, message):
    with pytest.raises(ValueError, match=message):
        _schedule(**readout)


def test_a_bad_rdtimes_keyword_is_a_format_error():
    h = _schedule().to_header()
    h["RDTIMES"] = "0,2.9,x"
    with pytest.raises(FormatError, match="keyword RDTIMES: read_times: expected times"):
        ReadoutSchedule.from_header(h)
