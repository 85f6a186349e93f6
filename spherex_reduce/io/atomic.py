"""Write a file atomically: a temporary file in the target directory, renamed into place.

Used by every writer of the package (FITS, tables, plots), so that an
interrupted or failed write never leaves a partial output, nor replaces an
existing file that was not meant to be replaced.
"""

import contextlib
import errno
import glob
import hashlib
import os
import socket
import tempfile
import threading
from pathlib import Path

__all__ = ["atomic_output"]

#: What ``link`` fails with on a file system without hard links (e.g. FAT, some FUSE mounts).
_NO_LINKS = frozenset(getattr(errno, n) for n in ("EPERM", "EOPNOTSUPP", "ENOTSUP", "EMLINK",
                                                   "ENOSYS", "EXDEV", "EINVAL")  # EINVAL: FAT
                      if hasattr(errno, n))


#: Temporary paths of the outputs this process is writing: each removed by its
#: `atomic_output.__exit__`, or by `atomic_output.remove_unfinished` where an interrupt
#: (SIGINT, or SIGTERM raised as an exception) arrived where no ``finally`` of the write
#: could run: as ``__exit__`` is entered, before its first statement.
_UNFINISHED = set()
_UNFINISHED_LOCK = threading.Lock()


class atomic_output:
    """Context manager giving a temporary path that is renamed to ``path`` on success.

    Refuses to start if ``path`` exists and ``overwrite`` is False, or names a
    directory, so nothing is computed only to be thrown away.  On error
    (including an interrupt) the temporary file is removed and an existing
    ``path`` is left untouched.  Without ``overwrite``, a file that takes the
    name while the output is written (another process's) is never replaced:
    the write ends in `FileExistsError`.  The temporary file, ``.NAME.HOST-PID.XXXX.tmp``
    in the target directory, carries a tag of the writer's host and its process
    id: temporary files for ``path`` left by a process of this host that no
    longer runs (killed outright) are removed when the next write of ``path``
    starts; those of other hosts (a shared file system) are never touched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_output(out) as tmp:
    ...     _ = tmp.write_text("done")
    >>> out.read_text()
    'done'
    """

    def __init__(self, path, overwrite=False):
        text = os.fspath(path)
        self.path = Path(path)
        self.overwrite = overwrite
        if text.endswith(("/", os.sep)) or self.path.is_dir():
            raise IsADirectoryError(f"{text} names a directory; give a file name to write")
        if self.path.exists() and not overwrite:
            raise FileExistsError(  # astropy's words, and the option of the command line
                f"File {self.path} already exists. If you mean to replace it then use the "
                'argument "overwrite=True" (on the command line: --overwrite).')
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"output directory {self.path.parent} does not exist")

    #: Tag of this host in temporary names: a process id means something only here.
    HOST = hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]

    @classmethod
    def remove_unfinished(cls):
        """Remove the temporary files of the writes this process started and did not end
        (the command line calls it when interrupted; a clean-up: never raises).

        Examples
        --------
        >>> import tempfile, pathlib
        >>> from spherex_reduce.io.atomic import atomic_output
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
        >>> tmp = atomic_output(out).__enter__()  # a write an interrupt cut short
        >>> _ = tmp.write_text("half")
        >>> atomic_output.remove_unfinished()
        >>> tmp.exists(), out.exists()
        (False, False)
        """
        with _UNFINISHED_LOCK:
            paths = list(_UNFINISHED)
            _UNFINISHED.clear()
        for path in paths:
            with contextlib.suppress(OSError):
                os.unlink(path)

    def _remove_stale(self):
        prefix = f".{self.path.name}.{self.HOST}-"
        for old in self.path.parent.glob(f"{glob.escape(prefix)}*.tmp"):
            parts = old.name[len(prefix):-len(".tmp")].split(".")
            if len(parts) != 2 or not parts[0].isdigit() or int(parts[0]) == os.getpid():
                continue  # not ours (e.g. of an output "NAME.1"), or this process's
            if os.name == "nt":  # os.kill(pid, 0) would end that process there
                continue
            try:
                os.kill(int(parts[0]), 0)
            except ProcessLookupError:  # its writer is gone
                with contextlib.suppress(OSError):  # a clean-up: never a reason to fail
                    old.unlink()
            except (OSError, OverflowError):  # alive but not ours, or not a pid
                pass

    def __enter__(self):
        self._remove_stale()
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.{self.HOST}-{os.getpid()}.",
                                       suffix=".tmp", dir=self.path.parent)
        except OSError as exc:  # e.g. a read-only file system: say which output
            exc.filename = str(self.path)
            raise
        with _UNFINISHED_LOCK:
            _UNFINISHED.add(tmp)
        os.close(fd)
        os.unlink(tmp)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                if self.overwrite:
                    os.replace(self.tmp, self.path)
                else:
                    self._rename_no_clobber()
        finally:
            self.tmp.unlink(missing_ok=True)
            with _UNFINISHED_LOCK:
                _UNFINISHED.discard(str(self.tmp))
        if isinstance(exc, OSError) and exc.errno is not None and (
                exc.filename is None or os.fspath(exc.filename) == str(self.tmp)):
            exc.filename = str(self.path)  # e.g. a full disk: say which output
        return False

    def _rename_no_clobber(self):
        """Give the temporary file its name unless a file took the name meanwhile.

        A hard link is made and fails if the name exists (atomic even between
        processes: two writers of one output never replace each other's file);
        the temporary name is removed by `__exit__`.  Where the file system has
        no hard links, the name is checked and the file renamed.
        """
        appeared = f"{self.path} appeared while writing; not overwriting it"
        try:
            os.link(self.tmp, self.path)
        except FileExistsError:
            raise FileExistsError(appeared) from None
        except OSError as exc:
            if exc.errno not in _NO_LINKS:
                raise
            if self.path.exists():
                raise FileExistsError(appeared) from None
            os.replace(self.tmp, self.path)
