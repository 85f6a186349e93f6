"""Reading and writing files: FITS exposures and atomic outputs.

`open_input` is the one entry point for inputs of every layout (a raw file
read in bands, a 4-D file of integrations, one file per read, an exposure in
memory): it gives the sources the executor reads.  `read` and `write` handle
a whole exposure in the layout of `spherex_reduce.io.layout`; `write_frames`
writes raw ramps as they are made and `FrameReader` reads them a frame at a
time; `read_ccddata` reads a reduced image as astropy's ``CCDData`` (also
``CCDData.read(path, format='spherex_reduce')`` once imported); `open_checked`
opens any FITS file after the checks `read` makes (structure, checksums,
header cards), `foreign_dq_bits` chooses which bits of
a ``DQ`` written by other software mask a pixel, `atomic_output` is how
every output of the package is written, and `locked_directory` makes the
updates of a file that several processes share one at a time.
"""

import lazy_loader as lazy

__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "atomic": ["atomic_output"],
    "readers.fits_read": ["CheckedFITS", "checksum_policy", "integration_count", "is_raw_ramp_file",
                          "open_checked"],
    "readers.read_exposure": ["read"],
    "readers.ccddata": ["read_ccddata"],
    "fits_write": ["write", "write_frames"],
    "readers.flags": ["current_dq_bits", "foreign_dq_bits"],
    "readers.frames": ["FrameReader"],
    "lock": ["locked_directory"],
    "sources": ["open_input"],
})
