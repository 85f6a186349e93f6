"""Data-quality flag bits (the ``DQ`` extension), combined with bitwise OR.

Any non-zero value means the pixel is masked.  The bits say why.
"""

__all__ = ["DO_NOT_USE", "FEW_READS", "HOT", "NOT_READ", "NO_REFERENCE", "SATURATED", "describe"]

DO_NOT_USE = 1  #: masked by the caller or an earlier step
SATURATED = 2  #: at least one read above the saturation level
HOT = 4  #: clipped as an outlier by ``sigma_clip``
NO_REFERENCE = 8  #: the channel had no usable reference pixels; left uncorrected
FEW_READS = 16  #: fewer than two usable reads; slope is NaN
NOT_READ = 32  #: the row was never read in this schedule (value NaN)

_NAMES = {
    DO_NOT_USE: "DO_NOT_USE",
    SATURATED: "SATURATED",
    HOT: "HOT",
    NO_REFERENCE: "NO_REFERENCE",
    FEW_READS: "FEW_READS",
    NOT_READ: "NOT_READ",
}


def describe(value):
    """Names of the bits set in a DQ value.

    Examples
    --------
    >>> from spherex_reduce import dq
    >>> dq.describe(dq.HOT | dq.FEW_READS)
    ['HOT', 'FEW_READS']
    """
    return [name for bit, name in _NAMES.items() if int(value) & bit]
