"""What this machine can hold: size checks made before anything is allocated.

Sizes come from untrusted places (FITS headers, YAML scenes, command-line
numbers).  A value such as ``NROWS = 1e15`` must be refused with a clear error
before numpy is asked for the memory, not after the operating system kills the
process.  :func:`check_size` is the one place that decides.

The budget is the smaller of the memory the kernel reports as available
(``MemAvailable``; the physical memory where that is unknown) and the process's
address-space limit (``RLIMIT_AS`` / ``RLIMIT_DATA``), if one is set.
"""

import math
import os

from .errors import ResourceError

__all__ = ["MAX_WORKERS", "check_count", "check_size", "memory_budget"]

#: Most worker processes an embedded dask LocalCluster may start.
MAX_WORKERS = 256

try:  # not on every platform
    import resource
except ImportError:  # pragma: no cover
    resource = None


def _available_bytes():
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:") and int(line.split()[1]) > 0:
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 2**63


def memory_budget():
    """Bytes this process may still allocate, as far as the system says.

    Returns
    -------
    int
        The smaller of available memory and the soft address-space or data
        limit of the process (bytes).

    Examples
    --------
    >>> from spherex_reduce.core.limits import memory_budget
    >>> memory_budget() > 0
    True
    """
    budget = _available_bytes()
    if resource is not None:
        for name in ("RLIMIT_AS", "RLIMIT_DATA"):
            limit = getattr(resource, name, None)
            if limit is None:
                continue
            soft, _ = resource.getrlimit(limit)
            if soft != resource.RLIM_INFINITY and soft > 0:
                budget = min(budget, soft)
    return int(budget)


def _fmt(nbytes):
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= size:
            return f"{nbytes / size:.3g} {unit}"
    return f"{nbytes:.0f} bytes"


def check_size(nbytes, what, fraction=1.0):
    """Refuse work that needs more memory than this machine can hold.

    Parameters
    ----------
    nbytes : int or float
        Bytes the work will allocate at once (an estimate is fine; it may be
        astronomically large or not finite, e.g. computed from header values).
    what : str
        What needs the memory, for the message (e.g. ``"a 1e15 x 2048 image"``).
    fraction : float, optional
        Share of the budget the work may take (default: all of it).

    Raises
    ------
    ResourceError
        If ``nbytes`` is not finite or exceeds ``fraction`` of `memory_budget`.
        It is a `SpherexReduceError`: the command line prints one line and
        exits with code 2.

    Examples
    --------
    >>> from spherex_reduce.core.limits import check_size
    >>> check_size(8 * 64 * 64, "a 64 x 64 float64 image")
    >>> check_size(8e18, "an 8 EB cube")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ResourceError: an 8 EB cube needs 8e+06 TB of memory; ...
    """
    nbytes = float(nbytes)
    budget = memory_budget() * fraction
    if not math.isfinite(nbytes) or nbytes > budget:
        need = _fmt(nbytes) if math.isfinite(nbytes) else "unbounded"
        raise ResourceError(f"{what} needs {need} of memory; this machine can hold {_fmt(budget)}")


def check_count(value, what, maximum):
    """Refuse a count (bins, realisations, workers, ...) outside ``1 .. maximum``.

    Parameters
    ----------
    value : int or float
        The count as given by the user.
    what : str
        Its name in the message (e.g. ``"--nbins"``).
    maximum : int
        The largest count that does useful work in bounded time.

    Returns
    -------
    int
        ``value`` as an integer.

    Raises
    ------
    ResourceError
        If ``value`` is not a whole number in ``1 .. maximum``.

    Examples
    --------
    >>> from spherex_reduce.core.limits import check_count
    >>> check_count(10, "--nbins", 10_000)
    10
    >>> check_count(1e8, "--nbins", 10_000)
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ResourceError: --nbins must be a whole number from 1 to ...
    """
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value != int(value) or not 1 <= value <= maximum:
        raise ResourceError(f"{what} must be a whole number from 1 to {maximum}, got {value!r}")
    return int(value)
