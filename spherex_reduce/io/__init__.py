"""Reading and writing files: FITS exposures and atomic outputs.

`read` and `write` handle a whole exposure in the layout of
`spherex_reduce.io.layout`; `write_frames` writes raw ramps as they are made
and `FrameReader` reads them a frame at a time; `open_checked` opens any FITS
file after the checks `read` makes (structure, checksums, header cards),
`foreign_dq_bits` chooses which bits of a ``DQ`` written by other software
mask a pixel, and `atomic_output` is how every output of the package is written.
"""

from .atomic import atomic_output
from .fits_read import (
    CheckedFITS,
    checksum_policy,
    integration_count,
    is_raw_ramp_file,
    open_checked,
    read,
)
from .fits_write import write, write_frames
from .flags import current_dq_bits, foreign_dq_bits
from .frames import FrameReader

__all__ = ["CheckedFITS", "FrameReader", "atomic_output", "checksum_policy", "current_dq_bits",
           "foreign_dq_bits", "integration_count", "is_raw_ramp_file", "open_checked", "read",
           "write", "write_frames"]
