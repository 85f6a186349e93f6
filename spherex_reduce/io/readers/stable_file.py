"""Explicit reads of a file that must not change while it is read (no memory map).

A memory-mapped file that is truncated while it is read kills the process
with ``SIGBUS`` when a page past the new end is touched: no message, no
cleanup.  The readers therefore read pixels with ``pread`` into arrays of
their own: `pread_into` fills a buffer and names the file if it ends first,
and `StableFile` checks before every read that the file is still the one
that was opened and checked (its size and modification time), so a file
changed under a reader ends in one `~spherex_reduce.core.errors.FormatError`.
"""

import os

import numpy as np

from ...core.errors import FormatError

__all__ = ["StableFile", "pread_into"]


def pread_into(fd, buf, pos, short):
    """Fill ``buf`` with the bytes of file ``fd`` from ``pos`` (``pread``: no file position
    moves, several threads may read at once); ``short`` is the error if the file ends first."""
    if buf.size == 0:  # nothing to read (e.g. REFPIX of a window without reference rows)
        return buf
    view = memoryview(buf).cast("B")
    done = 0
    while done < view.nbytes:
        if hasattr(os, "preadv"):
            got = os.preadv(fd, [view[done:]], pos + done)
        else:  # (Windows) one reader at a time: seek, then read
            os.lseek(fd, pos + done, os.SEEK_SET)
            chunk = os.read(fd, view.nbytes - done)
            got = len(chunk)
            view[done:done + got] = chunk
        if got <= 0:
            raise FormatError(short)
        done += got
    return buf


class StableFile:
    """A file open for explicit reads, refused as soon as it is not what it was when opened.

    Parameters
    ----------
    path : str or `pathlib.Path`
        The file (its checks, e.g. checksums, are the opener's: this only
        makes sure the bytes read later are still those checked).

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from spherex_reduce.io.readers.stable_file import StableFile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "f.bin"
    >>> _ = path.write_bytes(np.arange(4, dtype=">i2").tobytes())
    >>> with StableFile(path) as f:
    ...     print(f.read(2, ">i2", (3,)).tolist())
    ...     with open(path, "r+b") as g:
    ...         _ = g.truncate(4)
    ...     try:
    ...         f.read(2, ">i2", (3,))
    ...     except ValueError as exc:
    ...         print(str(exc).split(": ")[0].rsplit("/", 1)[-1])
    [1, 2, 3]
    f.bin changed while it was read (8 bytes when opened, now 4)
    """

    def __init__(self, path):
        self.path = path
        self._fd = os.open(path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
        self._stamp = self._state()

    def _state(self):
        st = os.fstat(self._fd)
        return st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev

    def check(self):
        """Raise `~spherex_reduce.core.errors.FormatError` if the file changed since it was
        opened (size, modification time)."""
        now = self._state()
        if now != self._stamp:
            what = (f"{self._stamp[0]} bytes when opened, now {now[0]}" if now[0] != self._stamp[0]
                    else "modified since it was opened and checked")
            raise FormatError(f"{self.path} changed while it was read ({what}): read it once it "
                              "is complete and no longer written")

    def read(self, offset, dtype, shape, what="the data"):
        """``shape`` values of ``dtype`` (as stored) from byte ``offset``, in a new array,
        after `check`."""
        self.check()
        return pread_into(self._fd, np.empty(shape, dtype), offset,
                          f"{self.path}: the file ends inside {what}")

    def close(self):
        """Close the file."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
