"""The values most recently used, kept for the next call that needs them (thread-safe).

A search forecasts hundreds of readouts that share tables (a timing's lag table, the
light rows' functional, the column phases); `RecentlyUsed` keeps the latest of them,
bounded by a count or by their bytes, and gives the same object back for the same key.

Examples
--------
>>> from spherex_reduce.core.recently_used import RecentlyUsed
>>> kept = RecentlyUsed(2)
>>> a = kept.get("a", lambda: [1])
>>> kept.get("a", lambda: [2]) is a, kept.get("b", lambda: [3]), kept.get("c", lambda: [4])
(True, [3], [4])
>>> kept.get("a", lambda: [5])  # the oldest was let go
[5]
"""

import threading
from collections import OrderedDict

__all__ = ["RecentlyUsed"]

_MISSING = object()


class RecentlyUsed:
    """Values by key, the least recently used let go beyond ``limit``.

    Parameters
    ----------
    limit : int
        How many values are kept, or (with ``size``) how much of them.
    size : callable, optional
        The size of a value (e.g. its bytes) counted against ``limit``; by
        default each value counts 1.  The newest value is kept even when it
        alone is larger.
    """

    def __init__(self, limit, size=None):
        self._limit = limit
        self._size = size or (lambda value: 1)
        self._values = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key, make):
        """The value kept for ``key``, else ``make()`` (called outside the lock), kept."""
        with self._lock:
            value = self._values.pop(key, _MISSING)  # a value may be None
            if value is not _MISSING:
                self._values[key] = value
                return value
        value = make()
        with self._lock:
            self._values[key] = value
            while len(self._values) > 1 and sum(
                    self._size(v) for v in self._values.values()) > self._limit:
                self._values.popitem(last=False)
        return value
