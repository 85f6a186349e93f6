"""The layout of an exposure file: extension names and units.

Extension names:

``PRIMARY``
    No data; the readout keywords (`ReadoutSchedule.to_header`), ``BUNIT``,
    ``ORDER`` (``READOUT`` or ``PHYSICAL``) and the provenance of every step.
``SCI``
    Pixels: ramps ``(frames, reads, columns)`` or a 2-D image, in the order
    ``ORDER`` says.
``ERR``, ``DQ``
    Standard deviation and data-quality flags (`spherex_reduce.dq`), if any.
``PHANTOM``
    Phantom values, ``(frames, reads, channels)`` or ``(reads, channels)``.
``READOUT``
    One row per read of a frame: ``row kind start time``; cross-checked
    against the header keywords on read.
``REFPIX``, ``REFPHANT``, ``REFDQ``, ``REFREADS``
    Reference reads kept aside by ``unchop`` (pixels, phantoms, flags, and a
    table ``read row time``).

Any other table extension holds a table recorded by a step (e.g. ``REFOFFS``).
"""

from astropy import units as u

_RESERVED = {"PRIMARY", "SCI", "ERR", "DQ", "PHANTOM", "READOUT", "REFPIX", "REFPHANT", "REFDQ",
             "REFREADS"}


def _unit_str(unit):
    """Units in astropy's generic format ('electron / s'): 'electron' is not a FITS unit."""
    return "" if unit == u.one else unit.to_string()

