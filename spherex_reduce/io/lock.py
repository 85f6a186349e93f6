"""An exclusive lock on a directory, held while a file shared by several processes is updated.

A batch's summary table is read, merged and rewritten by every batch writing
into its directory; `locked_directory` makes those read-merge-write steps one
at a time.  The lock is `fcntl.flock` on the directory itself, so it leaves
no file behind and is released by the kernel when its holder dies (even by
``SIGKILL``): a killed batch never leaves a stale lock.  Where a file system
refuses locks on directories (e.g. some network file systems), a lock file
``.lock`` in the directory is locked instead (`fcntl.lockf`, which network
file systems pass on to the server) and left there.
"""

import contextlib
import errno
import fcntl
import os
from pathlib import Path

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
        fcntl.lockf(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)
