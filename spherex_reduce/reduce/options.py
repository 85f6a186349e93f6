"""How a reduction runs, apart from what it computes: threads and progress bars.

`RunOptions` is made once, where a run starts (`~spherex_reduce.Pipeline.run`
builds it from its ``progress`` and ``threads`` arguments, a step run alone
from its ``threads``), and is handed on to the passes and the executor.  The
numbers never depend on it.
"""

import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

__all__ = ["RunOptions", "default_threads", "in_threads"]


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


def in_threads(items, work, nthreads, *, read=None, name="spherex-reduce"):
    """``work(item)`` of every item, on up to ``nthreads`` threads, yielded in order.

    With ``read``, ``work(item, read(item))``: ``read`` is called here, in the
    calling thread and in order (a reader need not be thread-safe), the next item
    read while up to ``nthreads`` are worked on, so at most ``nthreads + 1`` items'
    reads are held.  Without it every item is queued at once.  One thread, or one
    item: all in the calling thread.  A failure (in ``work``, in ``read`` or in the
    caller between two results) cancels the items not started.

    Examples
    --------
    >>> from spherex_reduce.reduce.options import in_threads
    >>> list(in_threads(range(5), lambda i: i * i, 2))
    [0, 1, 4, 9, 16]
    >>> list(in_threads("abc", lambda c, v: c + v, 2, read=str.upper))
    ['aA', 'bB', 'cC']
    """
    items = list(items)

    def run(item):
        return work(item) if read is None else work(item, read(item))

    if nthreads <= 1 or len(items) <= 1:
        for item in items:
            yield run(item)
        return
    pending = deque()
    with ThreadPoolExecutor(nthreads, thread_name_prefix=name) as pool:
        try:
            for item in items:
                pending.append(pool.submit(work, item) if read is None
                               else pool.submit(work, item, read(item)))
                while read is not None and len(pending) > nthreads:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        except BaseException:  # (also the caller's, or Ctrl-C): the others are not started
            for future in pending:
                future.cancel()
            raise
