"""An exclusive lock on a directory, held while a file shared by several processes is updated.

A batch's summary table is read, merged and rewritten by every batch writing
into its directory; `locked_directory` makes those read-merge-write steps one
at a time.  The lock is `fcntl.flock` on the directory itself, so it leaves
no file behind and is released by the kernel when its holder dies (even by
``SIGKILL``): a killed batch never leaves a stale lock.  Where a file system
refuses locks on directories (e.g. some network file systems), a lock file
``.lock`` in the directory is locked instead (`fcntl.lockf`, which network
file systems pass on to the server) and left there; so it is on Windows,
which has no ``fcntl`` (`msvcrt.locking`).
"""

import contextlib
import errno
import os
import time
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None

__all__ = ["LOCK_FILE", "locked_directory"]

#: The lock file used where the directory itself cannot be locked.
LOCK_FILE = ".lock"
#: What `fcntl.flock` fails with on a directory it cannot lock.
_NO_DIRECTORY_LOCKS = frozenset(getattr(errno, n) for n in (
    "EBADF", "EINVAL", "ENOLCK", "EOPNOTSUPP", "ENOTSUP") if hasattr(errno, n))


@contextlib.contextmanager
def locked_directory(path):
    """Hold an exclusive lock on the directory ``path`` (waiting for it) for a ``with`` block.

    Parameters
    ----------
    path : str or path-like
        An existing directory.

    Examples
    --------
    >>> import tempfile
    >>> from spherex_reduce.io.lock import locked_directory
    >>> d = tempfile.mkdtemp()
    >>> with locked_directory(d):
    ...     pass  # read, merge and rewrite a file of d, one process at a time
    """
    if fcntl is None:
        with _locked_file(Path(path) / LOCK_FILE):
            yield
        return
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as exc:
            if exc.errno not in _NO_DIRECTORY_LOCKS:
                raise
            with _locked_file(Path(path) / LOCK_FILE):
                yield
            return
        yield
    finally:
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def _locked_file(path):
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if fcntl is not None:
            fcntl.lockf(fd, fcntl.LOCK_EX)
            yield
        else:
            import msvcrt

            _lock_windows(fd, msvcrt)
            try:
                yield
            finally:
                os.lseek(fd, 0, os.SEEK_SET)
                msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
    finally:
        os.close(fd)  # releases the lock


def _lock_windows(fd, msvcrt):
    while True:  # LK_LOCK tries for 10 s, then raises: wait as flock does
        try:
            msvcrt.locking(fd, msvcrt.LK_LOCK, 1)
            return
        except OSError as exc:
            if exc.errno != errno.EDEADLOCK:
                raise
            time.sleep(0.1)
