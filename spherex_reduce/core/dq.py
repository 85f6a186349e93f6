"""Data-quality flag bits (the ``DQ`` extension), combined with bitwise OR.

Flags are `DQ_TYPE` (uint32) end to end: in memory, in every step, and in the
files we write (stored as int32, the same 32 bits, so that FITS needs no
``BZERO`` and the extension can be memory-mapped).

Most bits say why a pixel (or a read) must not be used.  Three only inform:

- `JUMP` on a read marks the read at which the pixel's charge stepped (a
  cosmic ray); ``fit_ramp`` fits the segments on either side, and on the slope
  image `JUMP` says the slope was fitted around a jump: it is valid;
- `SATURATED` on a read means the read (and every later read of that ramp) is
  not used; on a slope it says saturation cut the ramp short: the slope of
  the reads before it is valid unless `FEW_READS` is also set;
- `REFERENCE` marks a reference pixel: its value is valid but it is not sky.

And `NO_REFERENCE` on a read says its channel had no reference pixels to
correct it with: the read is used (the channel is left uncorrected, never
NaN), and the slope carries the flag, which masks it on the image.

So a read is usable when its flags have no bit but `JUMP`, `REFERENCE` and
`NO_REFERENCE` (`read_usable`), and a pixel of an image when it has no bit but
the `INFORMATIONAL` ones (`image_usable`); ``data.mask`` of an
`~spherex_reduce.Exposure` follows that rule.

The table of bits, with what each means on an image, is in the docs' FITS page.
"""

import numpy as np

__all__ = ["DO_NOT_USE", "FEW_READS", "HOT", "INFORMATIONAL", "JUMP", "NOT_READ",
           "NO_REFERENCE", "REFERENCE", "SATURATED", "describe", "image_usable", "read_usable"]

DQ_TYPE = np.uint32  # the type of every flag array

DO_NOT_USE = 1  #: masked by the caller, an input flag or an earlier step
SATURATED = 2  #: read above the saturation level; on a slope: saturation cut the ramp
HOT = 4  #: clipped as an outlier by ``sigma_clip``
NO_REFERENCE = 8  #: the channel had no usable reference pixels; left uncorrected
FEW_READS = 16  #: fewer than two usable reads; slope is NaN
NOT_READ = 32  #: the row was never read in this schedule (value NaN)
JUMP = 64  #: a jump (cosmic ray) at this read; on a slope: fitted around jumps
REFERENCE = 128  #: a reference pixel (valid, but not sky)

#: Bits that inform without masking a pixel of an image.
INFORMATIONAL = JUMP | SATURATED | REFERENCE
#: Bits that do not stop a read from being used (the others, SATURATED included, do):
#: NO_REFERENCE leaves the read uncorrected, not unusable.
READ_INFORMATIONAL = JUMP | REFERENCE | NO_REFERENCE

_NAMES = {
    DO_NOT_USE: "DO_NOT_USE",
    SATURATED: "SATURATED",
    HOT: "HOT",
    NO_REFERENCE: "NO_REFERENCE",
    FEW_READS: "FEW_READS",
    NOT_READ: "NOT_READ",
    JUMP: "JUMP",
    REFERENCE: "REFERENCE",
}


def describe(value):
    """Names of the bits set in a DQ value (bits we do not define as ``'BIT<n>'``).

    Examples
    --------
    >>> from spherex_reduce import dq
    >>> dq.describe(dq.HOT | dq.FEW_READS)
    ['HOT', 'FEW_READS']
    >>> dq.describe(dq.JUMP | 2**19)
    ['JUMP', 'BIT19']
    """
    value = int(value)
    names = [name for bit, name in _NAMES.items() if value & bit]
    return names + [f"BIT{b}" for b in range(32) if value & (1 << b) and (1 << b) not in _NAMES]


def image_usable(flags):
    """Whether pixels of an image with ``flags`` may be used (no bit but `INFORMATIONAL`).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import dq
    >>> dq.image_usable(np.array([0, dq.JUMP, dq.JUMP | dq.FEW_READS], dq.DQ_TYPE)).tolist()
    [True, True, False]
    """
    return (np.asarray(flags) & ~np.uint32(INFORMATIONAL)) == 0


def read_usable(flags):
    """Whether reads with ``flags`` may be fitted (no bit but `JUMP`, `REFERENCE` and
    `NO_REFERENCE`).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import dq
    >>> dq.read_usable(np.array([0, dq.JUMP, dq.SATURATED], dq.DQ_TYPE)).tolist()
    [True, True, False]
    """
    return (np.asarray(flags) & ~np.uint32(READ_INFORMATIONAL)) == 0
