"""Helpers of ``test_input_probe.py``: run the command line in a capped child process.

Every case runs ``spherex-reduce`` in its own process with an address-space limit
(`resource.RLIMIT_AS`), its own session (so a hang is killed with everything it
started) and a timeout.  Starting a fresh interpreter costs 1-3 s of imports per
case on a busy machine, so by default a *fork server* is used: one interpreter
imports the package (and the modules its commands load) once, then forks a
child per case that sets the limit,
changes directory, redirects stdin/stdout/stderr and calls
``spherex_reduce.cli.main`` exactly as ``python -m spherex_reduce.cli`` does
(``sys.exit(main())``, exit handlers run).  Set ``SPHEREX_PROBE_SPAWN=1`` to run
every case as ``python -m spherex_reduce.cli ...`` instead (slower; the two must
agree).

The module also has the byte-level tools the cases use to damage files: cut a
file inside an HDU, flip a byte in an HDU's data, rewrite raw header cards.
"""

import hashlib
import json
import os
import resource
import select
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from astropy.io import fits

#: Address-space limit of every case (bytes).
MEMORY_LIMIT = 2 * 1024**3
#: Seconds a case may take before it counts as a hang (small inputs take < 5 s).
TIMEOUT = 40.0

_ZYGOTE = r'''
import atexit, json, os, resource, signal, sys, time, traceback
import importlib
import numpy, yaml, astropy.io.fits, astropy.table, astropy.units
import spherex_reduce.cli
spherex_reduce.cli.build_parser()  # imports every command's module
for name in ("spherex_reduce.simulation", "spherex_reduce.analysis",
             "spherex_reduce.analysis.figures.demo", "spherex_reduce.analysis.sweep",
             "spherex_reduce.analysis.figures.reproduce", "spherex_reduce.analysis.figures.plots",
             "matplotlib.pyplot", "ccdproc", "scipy.signal", "scipy.optimize"):
    try:  # only to save time in every case; the cases import what they use anyway
        importlib.import_module(name)
    except ImportError:
        pass
print("ready", flush=True)

def child(req):
    os.setsid()
    signal.signal(signal.SIGINT, signal.default_int_handler)
    os.chdir(req["cwd"])
    fd = os.open(os.devnull, os.O_RDONLY)
    os.dup2(fd, 0)
    for target, name in ((1, "stdout"), (2, "stderr")):
        fd = os.open(req[name], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(fd, target)
        os.close(fd)
    resource.setrlimit(resource.RLIMIT_AS, (req["memory"], req["memory"]))
    sys.argv = ["spherex-reduce", *req["argv"]]
    code = 0
    try:
        try:
            code = spherex_reduce.cli.main(req["argv"])
        finally:
            atexit._run_exitfuncs()
    except SystemExit as exc:
        code = exc.code
    except BaseException:
        traceback.print_exc()
        code = 1
    if code is None:
        code = 0
    elif not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code & 0xFF)

for line in sys.stdin:
    req = json.loads(line)
    sys.stdout.flush()
    sys.stderr.flush()
    start = time.monotonic()
    pid = os.fork()
    if pid == 0:
        try:
            child(req)
        finally:
            os._exit(70)
    timed_out = False
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() - start > req["timeout"]:
            timed_out = True
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            _, status = os.waitpid(pid, 0)
            break
        time.sleep(0.005)
    try:  # whatever the case started in its session (e.g. dask workers)
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    print(json.dumps({"rc": os.waitstatus_to_exitcode(status), "timed_out": timed_out,
                      "seconds": time.monotonic() - start}), flush=True)
'''


@dataclass
class Result:
    """What one run of the command line did."""

    argv: list
    rc: int
    stdout: str
    stderr: str
    seconds: float
    timed_out: bool

    def describe(self):
        return (f"spherex-reduce {' '.join(self.argv)}\n  exit {self.rc}"
                f"{' (TIMED OUT)' if self.timed_out else ''} after {self.seconds:.1f} s\n"
                f"  stderr: {self.stderr[-2000:]!r}\n  stdout: {self.stdout[-500:]!r}")


def child_env():
    """The environment of the command: this interpreter's, the tested package first."""
    import spherex_reduce

    root = str(Path(spherex_reduce.__file__).resolve().parent.parent)
    env = dict(os.environ, MPLBACKEND="Agg")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    return env


class Runner:
    """Run ``spherex-reduce ARGV`` in a capped child process (see the module docstring)."""

    def __init__(self, spawn=None):
        self.spawn = os.environ.get("SPHEREX_PROBE_SPAWN") == "1" if spawn is None else spawn
        self.env = child_env()
        self._zygote = None

    def _start(self):
        self._zygote = subprocess.Popen([sys.executable, "-c", _ZYGOTE], env=self.env,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True, bufsize=1)
        if self._zygote.stdout.readline().strip() != "ready":
            raise RuntimeError("the fork server did not start")

    def close(self):
        if self._zygote is not None:
            self._zygote.stdin.close()
            try:
                self._zygote.wait(10)
            except subprocess.TimeoutExpired:
                self._zygote.kill()
                self._zygote.wait()
            self._zygote.stdout.close()
            self._zygote = None

    def run(self, argv, cwd, timeout=TIMEOUT, memory=MEMORY_LIMIT):
        """Run the command in ``cwd``; returns a `Result`."""
        argv = [str(a) for a in argv]
        cwd = Path(cwd)
        out, err = cwd.parent / f"{cwd.name}.stdout", cwd.parent / f"{cwd.name}.stderr"
        if self.spawn:
            rc, seconds, timed_out = self._run_spawn(argv, cwd, out, err, timeout, memory)
        else:
            rc, seconds, timed_out = self._run_fork(argv, cwd, out, err, timeout, memory)
        return Result(argv, rc, out.read_text(errors="replace"), err.read_text(errors="replace"),
                      seconds, timed_out)

    def _run_fork(self, argv, cwd, out, err, timeout, memory):
        if self._zygote is None or self._zygote.poll() is not None:
            self._start()
        req = {"argv": argv, "cwd": str(cwd), "stdout": str(out), "stderr": str(err),
               "timeout": timeout, "memory": memory}
        self._zygote.stdin.write(json.dumps(req) + "\n")
        self._zygote.stdin.flush()
        ready, _, _ = select.select([self._zygote.stdout], [], [], timeout + 60)
        line = self._zygote.stdout.readline() if ready else ""
        if not line:
            self._zygote.kill()
            self._zygote.wait()
            self._zygote.stdin.close()
            self._zygote.stdout.close()
            self._zygote = None
            raise RuntimeError("the fork server stopped answering")
        reply = json.loads(line)
        return reply["rc"], reply["seconds"], reply["timed_out"]

    def _run_spawn(self, argv, cwd, out, err, timeout, memory):
        def limit():
            resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

        start = time.monotonic()
        with open(out, "wb") as fo, open(err, "wb") as fe:
            proc = subprocess.Popen([sys.executable, "-m", "spherex_reduce.cli", *argv],
                                    cwd=cwd, env=self.env, stdin=subprocess.DEVNULL, stdout=fo,
                                    stderr=fe, preexec_fn=limit, start_new_session=True)
            try:
                proc.wait(timeout)
                timed_out = False
            except subprocess.TimeoutExpired:
                timed_out = True
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            proc.wait()
        return proc.returncode, time.monotonic() - start, timed_out


# -- the state of a directory ------------------------------------------------------------------

def snapshot(directory):
    """``{relative path: sha256 of the bytes (or 'dir' / 'link->target')}`` of everything."""
    state = {}
    directory = Path(directory)
    for p in sorted(directory.rglob("*")):
        rel = str(p.relative_to(directory))
        if p.is_symlink():
            state[rel] = f"link->{os.readlink(p)}"
        elif p.is_dir():
            state[rel] = "dir"
        else:
            state[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return state


# -- damaging FITS files -------------------------------------------------------------------------

def hdu_spans(path):
    """``[(name, header start, data start, data bytes)]`` of every HDU of a FITS file."""
    with fits.open(path, lazy_load_hdus=False) as hdul:
        spans = []
        for i, hdu in enumerate(hdul):
            info = hdul.fileinfo(i)
            spans.append((hdu.name, info["hdrLoc"], info["datLoc"], info["datSpan"]))
    return spans


def span(path, name):
    for item in hdu_spans(path):
        if item[0] == name:
            return item
    raise KeyError(name)


def cut(path, nbytes):
    """Truncate ``path`` to its first ``nbytes`` bytes."""
    data = Path(path).read_bytes()
    Path(path).write_bytes(data[:nbytes])


def flip_byte(path, offset, mask=0x01):
    """XOR one byte of ``path`` with ``mask``."""
    data = bytearray(Path(path).read_bytes())
    data[offset] ^= mask
    Path(path).write_bytes(bytes(data))


def edit_cards(path, hdu, cards, drop_checksums=True):
    """Rewrite header cards of HDU ``hdu`` (a name) as raw text, in place.

    ``cards`` maps a keyword to the text after ``= `` (written verbatim, so values
    astropy would never write, such as ``1E999`` or ``NAN``, are possible) or to
    None to blank the card out.  ``CHECKSUM``/``DATASUM`` of that HDU are blanked
    too (a header edit is not a checksum failure), unless ``drop_checksums`` is
    False.
    """
    _, start, data_start, _ = span(path, hdu)
    raw = bytearray(Path(path).read_bytes())
    todo = dict(cards)
    if drop_checksums:
        todo.setdefault("CHECKSUM", None)
        todo.setdefault("DATASUM", None)
    found = set()
    for pos in range(start, data_start, 80):
        key = raw[pos:pos + 8].decode("ascii").strip()
        if key in todo:
            value = todo[key]
            if value is None:
                card = ""
            elif value.startswith("'"):  # strings start in column 11
                card = f"{key:<8}= {value}"
            else:  # other values end in column 30
                card = f"{key:<8}= {value:>20}"
            raw[pos:pos + 80] = card.ljust(80).encode("ascii")
            found.add(key)
    missing = set(cards) - found
    if missing:
        raise KeyError(f"no card {sorted(missing)} in {hdu}")
    Path(path).write_bytes(bytes(raw))
