"""Names given by a user (files, configs) as text a FITS header card can hold.

A header card holds printable ASCII only; a file may be called ``dàrk.fits``,
``brüit.ecsv`` or have a newline in its name.  Every place that records such a
name in a header (``HISTORY`` lines, a step's parameter cards, ``DARKFILE``,
the text metadata of a table ...) passes it through `header_text`, which
escapes what a card cannot hold as Python's ``unicode_escape`` codec does
(``\\xe0``, ``\\n``, ``\\u2075``, and a backslash as ``\\\\``): printable
ASCII without a backslash is kept as it is, and `name_from_header` gives the
name back exactly.
"""

import codecs
import os

__all__ = ["header_text", "name_from_header"]


def header_text(name):
    """``name`` as printable ASCII for a FITS header card; reversible by `name_from_header`.

    Parameters
    ----------
    name : str or path-like
        A file name or other text given by a user.

    Returns
    -------
    str
        The text with every character outside printable ASCII, and the
        backslash, escaped (``unicode_escape``).

    Examples
    --------
    >>> from spherex_reduce.io.header_text import header_text, name_from_header
    >>> header_text("dàrk.fits"), header_text("a\\nb.yaml"), header_text("raw.fits")
    ('d\\\\xe0rk.fits', 'a\\\\nb.yaml', 'raw.fits')
    >>> name_from_header(header_text("brüit.ecsv")) == "brüit.ecsv"
    True
    """
    text = os.fspath(name) if isinstance(name, os.PathLike) else str(name)
    # surrogates (undecodable bytes of a file name) are escaped too, as \udcXX
    return text.encode("unicode_escape").decode("ascii")


def name_from_header(text):
    """The name `header_text` escaped, as it was given.

    Parameters
    ----------
    text : str
        Text written by `header_text` (a card's value, or the part of a
        ``HISTORY`` line that names a file).

    Returns
    -------
    str

    Examples
    --------
    >>> from spherex_reduce.io.header_text import name_from_header
    >>> name_from_header("d\\\\xe0rk.fits")
    'dàrk.fits'
    """
    return codecs.decode(text, "unicode_escape")
