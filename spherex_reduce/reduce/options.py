"""How a reduction runs, apart from what it computes: threads and progress bars.

`RunOptions` is made once, where a run starts (`~spherex_reduce.Pipeline.run`
builds it from its ``progress`` and ``threads`` arguments, a step run alone
from its ``threads``), and is handed on to the passes and the executor.  The
numbers never depend on it.
"""

import os
from dataclasses import dataclass

__all__ = ["RunOptions", "default_threads"]


def default_threads():
    """Threads used when none are asked for: the cores available, at most 4.

    Examples
    --------
    >>> from spherex_reduce.reduce.options import default_threads
    >>> 1 <= default_threads() <= 4
    True
    """
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(4, n))


@dataclass(frozen=True)
class RunOptions:
    """How a reduction runs: bands corrected at once, progress bars shown.

    Attributes
    ----------
    threads : int or None
        Bands corrected at once (None: `default_threads`).
    progress : bool
        Show progress bars (steps, and rows of a pass) on a terminal.

    Examples
    --------
    >>> from spherex_reduce.reduce.options import RunOptions
    >>> RunOptions(threads=3).thread_count(), RunOptions(threads=0).thread_count()
    (3, 1)
    """

    threads: int | None = None
    progress: bool = False

    def thread_count(self):
        """The threads a pass runs on: `threads` (at least 1), else `default_threads`."""
        return default_threads() if self.threads is None else max(1, int(self.threads))
