"""The cells of a results table as plain Python values, for keys and metadata.

A sweep (`spherex_reduce.analysis.sweep`) and its forecast
(`spherex_reduce.analysis.forecast.sweep`) key their rows by the JSON text of
their grid values, and record the grid in the table's metadata: both need a
table cell (a numpy scalar, bytes) as the plain value it was in the YAML.
"""

import numpy as np

__all__ = ["plain_value"]


def plain_value(value):
    """A table cell as a plain Python value: numpy scalars unwrapped, bytes decoded.

    Parameters
    ----------
    value : object
        A cell of an `~astropy.table.Table` row, or any value.

    Returns
    -------
    object
        ``value.item()`` for a numpy scalar, text for bytes, else ``value`` itself.

    Examples
    --------
    >>> import json
    >>> import numpy as np
    >>> from spherex_reduce.analysis.table_cells import plain_value
    >>> json.dumps([plain_value(np.int64(3)), plain_value(b"acn"), plain_value([1, 2])])
    '[3, "acn", [1, 2]]'
    """
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode()
    return value
