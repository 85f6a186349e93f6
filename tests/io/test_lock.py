"""`locked_directory`: one holder at a time, across processes; a killed holder frees it."""

import signal
import subprocess
import sys
import time

from spherex_reduce.io.lock import locked_directory

HOLD = ("import sys, time\n"
        "from spherex_reduce.io.lock import locked_directory\n"
        "with locked_directory(sys.argv[1]):\n"
        "    print('held', flush=True)\n"
        "    time.sleep(float(sys.argv[2]))\n")


def _holder(d, seconds):
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(d), str(seconds)],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def test_a_second_holder_waits_for_the_first(tmp_path):
    p = _holder(tmp_path, 0.6)
    t0 = time.monotonic()
    with locked_directory(tmp_path):
        waited = time.monotonic() - t0
    p.communicate()
    assert waited > 0.3  # the first held it 0.6 s
    assert list(tmp_path.iterdir()) == []  # no lock file left


def test_a_killed_holder_leaves_no_stale_lock(tmp_path):
    p = _holder(tmp_path, 60)
    p.send_signal(signal.SIGKILL)
    p.communicate()
    t0 = time.monotonic()
    with locked_directory(tmp_path):
        assert time.monotonic() - t0 < 5


HOLD_FILE = ("import errno, fcntl, sys, time\n"
             "from spherex_reduce.io import lock\n"
             "def refuse(fd, op):\n"
             "    raise OSError(errno.EINVAL, 'no locks on directories here')\n"
             "fcntl.flock = refuse\n"
             "with lock.locked_directory(sys.argv[1]):\n"
             "    print('held', flush=True)\n"
             "    time.sleep(float(sys.argv[2]))\n")


def test_where_a_directory_cannot_be_locked_a_lock_file_is(tmp_path, monkeypatch):
    """A file system refusing flock on directories (EINVAL): the .lock file is locked
    instead, and still one holder at a time across processes."""
    import errno
    import fcntl

    p = subprocess.Popen([sys.executable, "-c", HOLD_FILE, str(tmp_path), "0.6"],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"

    def refuse(fd, op):
        raise OSError(errno.EINVAL, "no locks on directories here")

    monkeypatch.setattr(fcntl, "flock", refuse)
    t0 = time.monotonic()
    with locked_directory(tmp_path):
        waited = time.monotonic() - t0
    p.communicate()
    assert waited > 0.3 and [f.name for f in tmp_path.iterdir()] == [".lock"]
