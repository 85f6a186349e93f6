"""The simulator refuses a window of a larger array in one line: its reads are spread
over the full readout, which the noise engine's tiers (reads every row_samples) do not
model."""

import pytest

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.core.window import Window
from spherex_reduce.simulation import NoiseEngine


def test_the_noise_engine_refuses_a_window():
    full = DetectorGeometry(64, 64, 4, ref_border=4)
    s = ReadoutSchedule(Window(0, 0, full).geometry(16, 16), skip=1, ref_mode="none",
                        nframes=3, frame_time=0.05)
    with pytest.raises(ValueError, match=r"^the simulator does not simulate a window") as info:
        NoiseEngine(s, [], 0)
    assert "\n" not in str(info.value)
