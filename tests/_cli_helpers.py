"""Helpers the command-line tests share: run the CLI in process, hash a file, one-line errors."""

import hashlib

from spherex_reduce.cli import main


def run(*args):
    """``spherex-reduce ARGS`` in this process; its exit status."""
    return main([str(a) for a in args])


def digest(path):
    """SHA-256 of a file's bytes (to show an input was not changed)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line_error(capsys, *words):
    """The captured stderr, checked to be one line, no traceback, naming every word."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and all(w in err for w in words), err
    return err
