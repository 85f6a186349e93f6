import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

from spherex_reduce import DetectorGeometry, ReadoutSchedule


@pytest.fixture
def small_schedule():
    """A 32 x 16 array, 2 channels, chopped, distributed reference reads, phantoms."""
    return ReadoutSchedule(DetectorGeometry(32, 16, 2, ref_border=2), skip=5, ref_reads=6,
                           ref_mode="distributed", phantom_reads=3, row_overhead=2,
                           frame_overhead=50, nframes=4)
