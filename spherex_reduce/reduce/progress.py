"""Long runs (a comparison's realisations, a sweep's cells): expected duration and progress.

`run_tasks` runs them (in this process, or on dask) with a `Progress`, which
counts the tasks as they finish.  When the first one is done it prints the
expected duration of the whole run on stdout, as the command's other
messages (``about 8 h 10 min for 10000 realisations (2.9 s each)``): the time
until then (starting a cluster included) plus the remaining rounds of tasks at
the first task's own duration.  A progress bar (tqdm) is shown on stderr only
when stderr is a terminal.  So stderr holds only warnings and, for a run that
fails (even after its estimate), the one error line.
Both are off with ``enabled=False`` (the command line's ``-q``).
"""

import contextlib
import logging
import math
import sys
import time
import warnings

from ..core._text import plural

__all__ = ["Progress", "format_duration", "run_tasks", "task_notes", "terminal_bar"]


class _NoBar:
    """What a progress bar offers, doing nothing (tqdm is not even imported)."""

    def update(self, n=1):
        pass

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def terminal_bar(enabled=True, stream=None, **kwargs):
    """A tqdm progress bar, shown only when ``enabled`` and ``stream`` is a terminal.

    Every bar of the package is made here, so none writes its cursor codes
    into a log or a file that stderr was redirected to.

    Parameters
    ----------
    enabled : bool
        False (the command line's ``-q``): no bar.
    stream : file, optional
        Where the bar goes (default `sys.stderr`).
    **kwargs
        For `tqdm.tqdm` (``total``, ``desc``, ``iterable`` ...).

    Returns
    -------
    `tqdm.tqdm`, or an object with its ``update``, ``close`` and ``with``
    that does nothing; given an ``iterable`` and no bar, the iterable itself.

    Examples
    --------
    >>> import io
    >>> from spherex_reduce.reduce.progress import terminal_bar
    >>> log = io.StringIO()  # not a terminal: no bar, nothing written
    >>> with terminal_bar(True, log, total=3) as bar:
    ...     bar.update(3)
    >>> log.getvalue(), list(terminal_bar(True, log, iterable=[1, 2]))
    ('', [1, 2])
    """
    stream = sys.stderr if stream is None else stream
    if not (enabled and getattr(stream, "isatty", lambda: False)()):
        return kwargs["iterable"] if "iterable" in kwargs else _NoBar()
    from tqdm import tqdm

    return tqdm(file=stream, **kwargs)


def format_duration(seconds):
    """A duration for people: ``'8 h 10 min'``, ``'3 min 5 s'``, ``'12 s'``, ``'0.4 s'``.

    Parameters
    ----------
    seconds : float
        The duration (s).

    Returns
    -------
    str

    Examples
    --------
    >>> from spherex_reduce.reduce.progress import format_duration
    >>> format_duration(29400), format_duration(185), format_duration(12.3), format_duration(0.42)
    ('8 h 10 min', '3 min 5 s', '12 s', '0.4 s')
    >>> format_duration(3 * 86400 + 7200)
    '3 d 2 h'
    """
    if not math.isfinite(seconds):
        return "forever"
    if seconds < 10:
        return f"{seconds:.1f} s"
    s = round(seconds)
    for big, small, name_big, name_small in ((86400, 3600, "d", "h"), (3600, 60, "h", "min"),
                                             (60, 1, "min", "s")):
        if s >= big:
            whole, rest = divmod(s, big)
            part = rest // small
            return f"{whole} {name_big}" + (f" {part} {name_small}" if part else "")
    return f"{s} s"


class Progress:
    """The expected duration of a run of ``total`` tasks, and a progress bar.

    Parameters
    ----------
    total : int
        Tasks in the run.
    noun : str
        What a task is, singular (``'realisation'``, ``'cell'``).
    enabled : bool
        Print the expected duration and show the bar (on a terminal).
    parallel : int or None
        Tasks run at once (workers); None: unknown (the duration is then that
        of running them one at a time, an upper bound).
    stream : file, optional
        Where to print the expected duration (default `sys.stdout`).
    bar_stream : file, optional
        Where the bar goes if it is a terminal (default `sys.stderr`).
    until : str, optional
        When the run may stop before ``total`` (the message then says "up
        to" and gives this).
    warmup : int
        Tasks whose one-off work (a table the later ones reuse) would mislead
        the estimate: it is made when the next one is done, from that one's
        duration.

    Examples
    --------
    >>> import io
    >>> from spherex_reduce.reduce.progress import Progress
    >>> out = io.StringIO()
    >>> with Progress(10, "realisation", True, parallel=1, stream=out) as p:
    ...     p.done()
    >>> out.getvalue().startswith("about ") and "for 10 realisations (" in out.getvalue()
    True
    """

    def __init__(self, total, noun, enabled, parallel=1, stream=None, bar_stream=None,
                 until=None, warmup=0):
        self.total, self.noun, self.enabled = int(total), noun, bool(enabled)
        self.until, self.warmup = until, int(warmup)
        self.parallel = parallel
        self.stream = sys.stdout if stream is None else stream
        self.start = time.perf_counter()
        self.count = 0
        self._timed, self._last = 0, self.start
        #: the expected duration of the whole run (s), once the first task is done
        self.expected = None
        self._bar = terminal_bar(self.enabled, bar_stream, total=self.total, desc=f"{noun}s")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._bar.close()

    def done(self, seconds=None):
        """One task finished, in ``seconds`` of its own (None: since the previous one); the
        first one after the warm-up times the run (printed when enabled)."""
        self.count += 1
        self._timed += 1
        now = time.perf_counter()
        if self._timed == self.warmup + 1:
            self._announce(now - self.start, now - self._last if seconds is None else seconds)
        self._last = now
        self._bar.update(1)

    def skip(self):
        """One task that did not run (refused at once): counted, never timing the run."""
        self.count += 1
        self._last = time.perf_counter()
        self._bar.update(1)

    @staticmethod
    def parallel_of(scheduler, workers):
        """Tasks run at once on ``scheduler`` (as `~spherex_reduce.analysis.sweep.run_sweep`
        takes it): 1 for ``'serial'``, the workers of a new LocalCluster (default 2) or
        of a `distributed.Client`'s cluster, None (unknown) for a scheduler's address."""
        if scheduler == "serial":
            return 1
        if scheduler is None:
            return workers or 2
        try:  # a Client: its workers' threads now
            threads = sum(scheduler.nthreads().values())
        except Exception:  # an address, or a cluster that does not answer: unknown
            return None
        return threads or None

    def _announce(self, elapsed, each):
        at_once = self.parallel or 1
        left = math.ceil(self.total / at_once) - math.ceil(self.count / at_once)
        self.expected = elapsed + each * left
        if not self.enabled or self.total < 2:
            return
        how = f"{format_duration(each)} each"
        if self.parallel is None:
            how += ", one at a time"
        elif self.parallel > 1:
            how += f", {self.parallel} at a time"
        if self.until:
            print(f"up to about {format_duration(self.expected)} for up to "
                  f"{plural(self.total, self.noun)} ({how}; {self.until})", file=self.stream,
                  flush=True)
            return
        print(f"about {format_duration(self.expected)} for {plural(self.total, self.noun)} "
              f"({how})", file=self.stream, flush=True)


class _Timed:
    """``function`` returning ``(seconds, result)``: a task that times itself (picklable)."""

    def __init__(self, function):
        self.function = function

    def __call__(self, task):
        t0 = time.perf_counter()
        result = self.function(task)
        return time.perf_counter() - t0, result


def run_tasks(function, tasks, scheduler, workers, collect, failed, *, noun, progress):
    """Run ``function`` on every task, in this process or on dask, with a `Progress`.

    Parameters
    ----------
    function : callable
        ``function(task) -> result``, picklable for dask.
    tasks : list
    scheduler, workers
        ``'serial'`` (in this process, in order), or as
        `~spherex_reduce.reduce.scheduler.map_on_dask`.
    collect : callable
        ``collect(task, result)``, in this process, as each task finishes.
    failed : callable
        ``failed(task, exception) -> result`` for a task whose dask worker died.
    noun : str
        What a task is (``'realisation'``), for the expected duration.
    progress : bool
        Print the expected duration and show a bar on a terminal.

    Returns
    -------
    `Progress`
        Its ``expected`` duration (s) and ``count`` of tasks done.

    Examples
    --------
    >>> from spherex_reduce.reduce.progress import run_tasks
    >>> out = []
    >>> p = run_tasks(abs, [-1, -2], "serial", None, lambda t, r: out.append(r), None,
    ...               noun="number", progress=False)
    >>> out, p.count
    ([1, 2], 2)
    """
    timed = _Timed(function)
    with Progress(len(tasks), noun, progress, Progress.parallel_of(scheduler, workers)) as bar:
        if scheduler == "serial":
            for task in tasks:
                seconds, result = timed(task)
                collect(task, result)
                bar.done(seconds)
        elif tasks:
            def done(task, out):
                seconds, result = out
                collect(task, result)
                bar.done(seconds)

            from .scheduler import map_on_dask

            map_on_dask(timed, tasks, scheduler, workers, done,
                        lambda task, exc: (None, failed(task, exc)))
    return bar


@contextlib.contextmanager
def task_notes():
    """Collect, as one-line texts, the warnings issued and logged (at WARNING or above) by
    the package while one task runs (a batch's file, a comparison's realisation).

    On a dask worker they would go to the worker's stderr, unlabelled and
    before any error; the task returns them with its result, and the command
    shows them once, naming what they came from, when it knows the run
    succeeded.

    Examples
    --------
    >>> import warnings
    >>> from spherex_reduce.reduce.progress import task_notes
    >>> with task_notes() as notes:
    ...     warnings.warn("channel 3 has no reference pixels")
    >>> notes
    ['channel 3 has no reference pixels']
    """
    notes = []

    class Collect(logging.Handler):
        def emit(self, record):
            notes.append(" ".join(record.getMessage().split()))

    logger = logging.getLogger("spherex_reduce")
    handler = Collect(logging.WARNING)
    propagate, logger.propagate = logger.propagate, False
    logger.addHandler(handler)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield notes
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate
        for w in caught:
            text = " ".join(str(w.message).split())
            if text not in notes:
                notes.append(text)
