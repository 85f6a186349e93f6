"""Words in messages and summaries (a core module: it imports nothing of the package)."""

__all__ = ["plural"]


def plural(count, noun, nouns=None):
    """``count`` and ``noun``, in the plural unless ``count`` is one.

    Parameters
    ----------
    count : int
    noun : str
        The singular.
    nouns : str, optional
        The plural, if not ``noun + "s"``.

    Examples
    --------
    >>> from spherex_reduce.core._text import plural
    >>> plural(1, "channel"), plural(32, "channel"), plural(2, "realisation")
    ('1 channel', '32 channels', '2 realisations')
    """
    return f"{count} {noun if count == 1 else (nouns or noun + 's')}"
